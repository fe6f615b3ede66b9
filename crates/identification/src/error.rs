//! The one error type of the identification crate.

use thiserror::Error;

/// Everything that can go wrong in identification. Each variant names what it is about.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum IdentificationError {
    /// A parameter (estimator, excitation, conditioning) is out of range. `field` is its name.
    #[error("invalid parameter `{field}`: {reason}")]
    InvalidParameter { field: String, reason: String },

    /// An excitation request violates a hard limit (force or band).
    #[error("excitation refused: {0}")]
    ExcitationLimit(String),

    /// A text record could not be read: names the file, line and column (1-based; column 0
    /// when the whole line is at fault).
    #[error("{file}:{line}:{column}: {message}")]
    Parse { file: String, line: usize, column: usize, message: String },

    /// Input data are unusable (length mismatch, NaN, non-monotonic time).
    #[error("bad input `{what}`: {reason}")]
    BadInput { what: String, reason: String },

    /// A physics-core error (calibration, configuration) surfaced here.
    #[error(transparent)]
    Physics(#[from] oilfilm_physics::PhysicsError),
}

impl IdentificationError {
    pub fn invalid(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::InvalidParameter { field: field.into(), reason: reason.into() }
    }
}
