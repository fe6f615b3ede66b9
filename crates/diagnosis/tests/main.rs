//! Every integration test of `oilfilm-diagnosis` in one binary: one link and one optimised
//! build of the shared generics instead of one per file (the suite's build time).

mod common;
mod hidden_effects;
mod outside_records;
mod show;
