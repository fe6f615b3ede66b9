//! Every integration test of `oilfilm-physics` in one binary: one link and one optimised
//! build of the shared generics instead of one per file (the suite's build time).

mod config;
mod config_fuzz;
mod daq;
mod effects_observable;
mod film_cross_check;
mod film_map;
mod film_relaxation;
mod lund_validation;
mod oil;
mod rig;
mod short_bearing;
mod simulation;
