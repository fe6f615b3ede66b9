#!/usr/bin/env bash
# Runs every test of oilfilm. This is the README's test command and what CI runs.
# It installs what it needs itself, so it works on a clean clone.
set -euo pipefail
cd "$(dirname "$0")/.."

echo "== toolchain"
cargo --version
rustc --version

echo "== build (tests are built optimised: see [profile.test] in Cargo.toml)"
cargo build --workspace --all-targets --profile test

echo "== Rust tests"
cargo test --workspace --profile test -- --nocapture 2>&1 | tee target/test-output.txt
grep -E "^test result:" target/test-output.txt | awk '
  { for (i = 1; i <= NF; i++) { if ($i ~ /passed;/) p += $(i-1); if ($i ~ /failed;/) f += $(i-1); if ($i ~ /ignored;/) s += $(i-1) } }
  END { printf "rust: %d passed, %d failed, %d skipped\n", p, f, s }'
