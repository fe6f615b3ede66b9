//! The one error type of the diagnosis crate.

use thiserror::Error;

/// Everything that can go wrong in a diagnosis. Each variant names what it is about.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum DiagnosisError {
    /// A setting is out of range. `field` is its name.
    #[error("invalid parameter `{field}`: {reason}")]
    InvalidParameter { field: String, reason: String },

    /// The record cannot be diagnosed as given (missing channel, too short, NaN).
    #[error("bad input `{what}`: {reason}")]
    BadInput { what: String, reason: String },

    /// An identification-core error (conditioning, estimator) surfaced here.
    #[error(transparent)]
    Identification(#[from] oilfilm_identification::IdentificationError),

    /// A physics-core error (rig configuration, film model) surfaced here.
    #[error(transparent)]
    Physics(#[from] oilfilm_physics::PhysicsError),
}

impl DiagnosisError {
    pub fn invalid(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::InvalidParameter { field: field.into(), reason: reason.into() }
    }

    pub fn bad_input(what: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::BadInput { what: what.into(), reason: reason.into() }
    }
}
