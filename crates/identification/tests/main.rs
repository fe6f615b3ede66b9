//! Every integration test of `oilfilm-identification` in one binary: one link and one optimised
//! build of the shared generics instead of one per file (the suite's build time).

mod ascii;
mod campaign;
mod causal;
mod causal_block_path;
mod chain;
mod conditioning;
mod coverage;
mod estimator;
mod excitation;
// The fuzz loops' shared settings: `OILFILM_FUZZ_SEED`/`OILFILM_FUZZ_CASES` and a case's
// generator from its seed.
#[path = "../../../tests/support/fuzz.rs"]
mod fuzz;
mod identify_simulated;
#[path = "../../../tests/support/json_difference.rs"]
mod json_difference;
mod reference;
mod rv_vs_load_film;
mod same_bits_on_every_isa;
mod se_decimation;
mod simulated_rig;
mod skew;
mod stream;
mod volts_record;
