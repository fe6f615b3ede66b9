//! Every integration test of `oilfilm-bag` in one binary: one link and one optimised
//! build of the shared generics instead of one per file (the suite's build time).

mod bag;
mod fuzz;
mod integrity;
mod recover;
mod reference_bag;
mod replay_equals_live;
#[path = "../../../tests/support/scratch.rs"]
mod scratch;
mod select;
#[path = "../examples/common/sim_rig.rs"]
mod sim_rig;
mod writer_records;
