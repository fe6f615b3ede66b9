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
    #[error("`{quantity}` is not finite ({value})")]
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
    /// Shorthand for [`PhysicsError::InvalidConfig`].
    pub fn invalid(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::InvalidConfig { field: field.into(), reason: reason.into() }
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
