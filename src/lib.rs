//! What the `oilfilm` command and its benchmarks (`oilfilm-bench`, the `bench/` package)
//! share; the command's own code is in the binary (`main.rs`).

pub mod bags;
pub mod progress;
