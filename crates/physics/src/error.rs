//! The one error type of the physics crate.

use thiserror::Error;

/// Everything that can go wrong in the physics core. Every variant names what it is about
/// (a config field, a solver, a channel) so a user can act on the message.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum PhysicsError {
    /// A configuration value is out of its physical range. `field` is the dotted path
    /// (`bearing.clearance_m`).
    #[error("invalid configuration `{field}`: {reason}")]
    InvalidConfig { field: String, reason: String },

    /// A configuration file could not be parsed (unknown key, wrong type, syntax).
    #[error("cannot read rig configuration{origin}: {message}")]
    ConfigParse { origin: String, message: String },

    /// A number that must be finite was NaN or infinite.
    #[error("`{quantity}` is not finite ({value:?})")]
    NonFinite { quantity: String, value: f64 },

    /// The journal reached the bearing wall: eccentricity ratio >= 1.
    #[error("eccentricity ratio {eccentricity:.4} reached the bearing wall (must stay below 1) {context}")]
    EccentricityLimit { eccentricity: f64, context: String },

    /// An iterative solver did not converge.
    #[error("{solver} did not converge after {iterations} iterations (residual {residual:.3e}): {hint}")]
    NoConvergence { solver: String, iterations: usize, residual: f64, hint: String },

    /// A linear system was singular or not positive definite.
    #[error("{what}: matrix is singular or not positive definite at row {row}")]
    Singular { what: String, row: usize },

    /// A DAQ channel was asked for that the configuration does not have.
    #[error("unknown DAQ channel `{0}`")]
    UnknownChannel(String),
}

impl PhysicsError {
    /// Shorthand for [`PhysicsError::InvalidConfig`]. Numbers in `reason` are kept to a
    /// bounded width (see [`bounded_numbers`]), whatever format the check used.
    pub fn invalid(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::InvalidConfig { field: field.into(), reason: bounded_numbers(reason.into()) }
    }

    /// Returns `Err(NonFinite)` unless `value` is finite.
    pub fn check_finite(quantity: &str, value: f64) -> Result<f64, Self> {
        if value.is_finite() {
            Ok(value)
        } else {
            Err(Self::NonFinite { quantity: quantity.to_string(), value })
        }
    }
}

/// Longest run of digits (a decimal number's integer and fraction parts together) a message
/// keeps as it is; a longer one is rewritten in scientific notation. `{}` prints an `f64` of
/// 1e308 as 309 digits, and a rig file can hold any finite number.
const MAX_DIGITS: usize = 24;

/// `text` with every decimal number longer than [`MAX_DIGITS`] digits in scientific notation
/// (`1e308`), so a message stays readable whatever a file held.
pub fn bounded_numbers(text: String) -> String {
    let bytes = text.as_bytes();
    let mut out = String::with_capacity(text.len().min(4096));
    let mut i = 0;
    let mut changed = false;
    while i < bytes.len() {
        if bytes[i].is_ascii_digit() {
            let start = i;
            while i < bytes.len() && (bytes[i].is_ascii_digit() || (bytes[i] == b'.' && bytes.get(i + 1).is_some_and(u8::is_ascii_digit))) {
                i += 1;
            }
            let number = &text[start..i];
            match number.parse::<f64>() {
                Ok(x) if number.len() > MAX_DIGITS => {
                    out.push_str(&format!("{x:e}"));
                    changed = true;
                }
                _ => out.push_str(number),
            }
        } else {
            // Copy up to the next digit (on a character boundary: digits are ASCII).
            let next = bytes[i..].iter().position(u8::is_ascii_digit).map_or(bytes.len(), |p| i + p);
            out.push_str(&text[i..next]);
            i = next;
        }
    }
    if changed {
        out
    } else {
        text
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_numbers_in_messages_become_scientific() {
        let huge = format!("got [{}, {}] V", f64::MAX, -1e300);
        let m = PhysicsError::invalid("daq.channels[8].linear_range", huge).to_string();
        assert_eq!(m, "invalid configuration `daq.channels[8].linear_range`: got [1.7976931348623157e308, -1e300] V");
        assert_eq!(bounded_numbers(format!("got {}", 1e-300)), "got 1e-300");
        // Ordinary numbers, names with digits and non-ASCII text are left alone.
        let plain = "channels[12] at 5000 Hz, 0.114e-3 m, 25 °C, 123456789012345678901234".to_string();
        assert_eq!(bounded_numbers(plain.clone()), plain);
    }
}
