//! Every integration test of `oilfilm-foreign` in one binary: one link and one optimised
//! build of the shared generics instead of one per file (the suite's build time).

mod map;
mod readers;
