//! Every integration test of `oilfilm-msgs` in one binary: one link and one optimised
//! build of the shared generics instead of one per file (the suite's build time).

mod definitions;
mod golden_cdr;
mod malformed;
mod type_hash;
