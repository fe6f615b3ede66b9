#!/usr/bin/env bash
# The binaries and examples the interop tests run (target/debug, the test profile), built
# with the workspace's features, as `cargo test --workspace` builds them. tests/run-all.sh
# builds them once before it runs the Rust tests and these tests side by side, and sets
# OILFILM_BUILT=1 so that no script here takes cargo's lock while the Rust tests run.
set -euo pipefail
cd "$(dirname "$0")/../.."
if [ -z "${OILFILM_BUILT:-}" ]; then
  cargo build --quiet --profile test --workspace --bins --examples
fi
