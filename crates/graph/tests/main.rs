//! Every integration test of `oilfilm-graph` in one binary: one link and one optimised
//! build of the shared generics instead of one per file (the suite's build time).

mod common;
mod daq_sources;
mod exciter_limits;
mod exciter_transitions;
mod foreign_source;
#[path = "../../../tests/support/fuzz.rs"]
mod fuzz;
mod graph_equals_batch;
mod launch_files;
mod lines_fuzz;
mod params_files;
mod sim_rig_graph;
mod yaml_fuzz;

/// The fuzz loops note the largest allocation of each case (`fuzz::largest_allocation`).
#[global_allocator]
static ALLOCATOR: fuzz::Counting = fuzz::Counting;
