//! # oilfilm-diagnosis
//!
//! Given a measured record and the rig it came from, show where the linear oil-film model
//! (stiffness K and damping C, Zhou et al. 2004) and the measurement disagree, name the cause
//! from a fixed catalog, fit the extended model and measure what it gains on data it was not
//! fitted to, and update the film model itself (clearance, viscosity, theory). Pure library:
//! no I/O, no clock; the CLI (`oilfilm diagnose`) reads the files.
//!
//! * [`evidence`]: the record conditioned once, post-filtered to the judging band, decimated,
//!   blocked and detrended; the force rows and the redundant sensors' rows.
//! * [`catalog`]: the named effects (corrections of the data, extensions of the film force)
//!   and the general extensions that show remaining structure; fitting a model.
//! * [`verdict`]: forward selection with held-out scoring, the named cause, its parameters and
//!   gain; the JSON contract of `oilfilm diagnose --json`.
//! * [`amplitude`]: whether the film's nonlinearity matters (Zhou's relative variation).
//! * [`model_update`]: the film model's clearance, viscosity and theory fitted to the record,
//!   and the updated simulation judged on held-out data.
//! * [`show`]: the rig simulated with the measured forces next to the measured motion,
//!   identified against modelled coefficients, per-window trends and residual spectra.

pub mod amplitude;
pub mod catalog;
pub mod error;
pub mod evidence;
pub mod least_squares;
pub mod model_update;
pub mod show;
pub mod statistics;
pub mod verdict;

pub use catalog::Cause;
pub use error::DiagnosisError;
pub use show::{show, Show, ShowConfig};
pub use verdict::{diagnose, diagnose_prepared, Diagnosis, DiagnosisOptions};
