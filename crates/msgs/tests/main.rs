//! Every integration test of `oilfilm-msgs` in one binary: one link and one optimised
//! build of the shared generics instead of one per file (the suite's build time).

mod cdr_fuzz;
mod definitions;
#[path = "../../../tests/support/fuzz.rs"]
mod fuzz;
mod golden_cdr;
mod malformed;
mod type_hash;

/// The fuzz loops note the largest allocation of each case (`fuzz::largest_allocation`).
#[global_allocator]
static ALLOCATOR: fuzz::Counting = fuzz::Counting;
