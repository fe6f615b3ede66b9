//! Every integration test of `oilfilm-foreign` in one binary: one link and one optimised
//! build of the shared generics instead of one per file (the suite's build time).

#[path = "../../../tests/support/fuzz.rs"]
mod fuzz;
mod map;
mod readers;
mod records_fuzz;

/// The fuzz loops note the largest allocation of each case (`fuzz::largest_allocation`).
#[global_allocator]
static ALLOCATOR: fuzz::Counting = fuzz::Counting;
