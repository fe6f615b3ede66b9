//! # oilfilm-diagnosis
//!
//! Given a measured record and the rig it came from, show where the linear oil-film model
//! (stiffness K and damping C, Zhou et al. 2004) and the measurement disagree, name the cause
//! from a fixed catalog, fit the extended model and measure what it gains on data it was not
//! fitted to. Pure library: no I/O, no clock; the CLI (`oilfilm diagnose`) reads the files.
//!
//! * [`evidence`]: the record conditioned, decimated, blocked and detrended for judging.
//! * [`catalog`]: the baseline K-C model and the seven candidate extensions.
//! * [`verdict`]: cross-validation, information criterion and significance; the named cause,
//!   its parameters, the gain; the JSON contract of `oilfilm diagnose --json`.
//! * [`show`]: the rig simulated with the measured forces next to the measured motion,
//!   identified against modelled coefficients, per-window trends and residual spectra.

pub mod catalog;
pub mod error;
pub mod evidence;
pub mod least_squares;
pub mod show;
pub mod statistics;
pub mod verdict;

pub use catalog::Cause;
pub use error::DiagnosisError;
pub use show::{show, Show, ShowConfig};
pub use verdict::{diagnose, Diagnosis, DiagnosisOptions};
