//! # oilfilm-diagnosis
//!
//! Given a measured record and the rig it came from, show where the linear oil-film model
//! (stiffness K and damping C, Zhou et al. 2004) and the measurement disagree, name the cause
//! from a fixed catalog, fit the extended model and measure what it gains on data it was not
//! fitted to. Pure library: no I/O, no clock; the CLI (`oilfilm diagnose`) reads the files.
//!
//! * [`show`]: the rig simulated with the measured forces next to the measured motion,
//!   identified against modelled coefficients, per-window trends and residual spectra.

pub mod error;
pub mod show;

pub use error::DiagnosisError;
pub use show::{show, Show, ShowConfig};
