//! # oilfilm-physics: the functional core
//!
//! Journal-bearing oil film, the floating-housing test rig of Zhou et al. (2004) and its
//! multiplexed DAQ chain, as plain deterministic Rust: no ROS, no I/O, no clock. Time is
//! always passed in; random numbers come from a seeded ChaCha generator owned by the caller's
//! configuration, so the same seed gives the same record bit for bit.
//!
//! ## The frame (stated once, used everywhere)
//!
//! * `x` is horizontal, `y` is vertical **up**, `z` runs along the shaft axis.
//! * The journal spins counter-clockwise seen from `+z`: its surface moves from `+x` towards
//!   `+y`. Circumferential angles `theta` are measured from `+x` towards `+y`.
//! * Film kinematics are those of the **journal centre relative to the bearing centre**
//!   (`FilmState`); film forces are the forces the film exerts **on the journal**.
//! * Linear coefficients follow Lund's sign convention:
//!   `dF_on_journal = -(K dr + C dr' + M dr'')`, so a stable film has positive `Kxx`, `Cxx`.
//! * The rig's static load acts on the housing along `+y` (the bellows pull the housing up);
//!   the journal therefore sits low in the bearing and the *load on the journal* points along
//!   `-y`. Literature tables that put `x` along the load are converted at the edge
//!   ([`dimensionless::to_load_frame`]).
//! * All quantities are SI inside; where a unit is not obvious it is in the name
//!   (`clearance_m`, `omega_rad_s`).
//!
//! ## Modules
//! * [`film`]: the oil film (short-bearing closed form, finite-length Reynolds solver, force map).
//! * [`oil`]: viscosity-temperature laws.
//! * [`operating_point`]: static equilibrium and linear coefficients of any film.
//! * [`dimensionless`]: Sommerfeld number, Lund's and Zhou's dimensionless groups.
//! * [`rig`]: the floating housing, exciters, bellows, gravity, time integration.
//! * [`daq`]: probes, amplifiers, multiplexed 16-bit sampling, calibration.
//! * [`effects`]: injectable effects, each off by default and set by one magnitude.
//! * [`simulation`]: rig and DAQ stepped together into a seeded, reproducible record.
//! * [`validation`]: published coefficient tables and comparison against them.
//! * [`config`]: the typed rig configuration (TOML, `deny_unknown_fields`) and its validation.

pub mod config;
pub mod daq;
pub mod dimensionless;
pub mod effects;
pub mod error;
pub mod film;
pub mod geometry;
pub mod oil;
pub mod operating_point;
pub mod rig;
pub mod simulation;
pub mod validation;

pub use error::PhysicsError;

/// Result type of this crate.
pub type Result<T> = std::result::Result<T, PhysicsError>;
