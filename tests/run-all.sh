#!/usr/bin/env bash
# Runs every test of oilfilm. This is the README's test command and what CI runs.
# It installs what it needs itself (Python venv with rclpy and the rosidl pieces from PyPI),
# so it works on a clean clone.
set -euo pipefail
cd "$(dirname "$0")/.."

passed=0
failed=0

echo "== toolchain"
cargo --version
rustc --version

# A phase's wall time, printed as it ends, so a slow suite says where the time went.
phase_start=$SECONDS
phase() {
  echo "== time: $1 took $((SECONDS - phase_start)) s (total $SECONDS s)"
  phase_start=$SECONDS
}

mkdir -p target
# Each failed check's name, listed again above the final count: a log read from its end
# (a CI page) then says what failed without the whole output.
failed_names=target/failed-names.txt
: >"$failed_names"
# The Python venvs (pip downloads, rosidl's build of oilfilm_msgs) are set up while cargo
# builds: on a clean clone they are minutes of mostly waiting on the network. Each script is
# idempotent; the interop scripts below call them again and find them ready.
( bash tests/interop/setup-ros-venv.sh >target/setup-ros-venv.log 2>&1; echo "$?" >target/setup-ros-venv.status ) &
ros_venv_pid=$!
( bash tests/interop/setup-bag-venv.sh >target/setup-bag-venv.log 2>&1; echo "$?" >target/setup-bag-venv.status ) &
bag_venv_pid=$!
( bash tests/interop/setup-foreign-venv.sh >target/setup-foreign-venv.log 2>&1; echo "$?" >target/setup-foreign-venv.status ) &
foreign_venv_pid=$!

echo "== format (cargo fmt --all --check)"
set +e
cargo fmt --all --check >target/fmt-output.txt 2>&1
fmt_status=$?
set -e
if [ "$fmt_status" -eq 0 ]; then
  passed=$((passed + 1))
  echo "ok: cargo fmt --all --check"
else
  failed=$((failed + 1))
  echo "format: cargo fmt --all --check" >>"$failed_names"
  head -40 target/fmt-output.txt
  echo "FAILED: cargo fmt --all --check (run cargo fmt --all)"
fi
phase "format"

echo "== build, linted on the way (clippy-driver compiles our crates; optimised: see [profile.test] in Cargo.toml)"
# clippy-driver is rustc with clippy's lints: as cargo's RUSTC_WORKSPACE_WRAPPER it compiles
# the workspace's crates for real (the dependencies go to rustc) and lints them as it does,
# so the lint gate costs no second build of everything (`cargo clippy` checks every crate
# again, dependencies included). Any warning, clippy's or rustc's, fails the gate, as
# `cargo clippy --workspace --all-targets -- -D warnings` would; the tests still run.
# Exported, so every later cargo command (here and in the interop scripts) builds with the
# same compiler and finds the build fresh.
clippy_driver=$(rustup which clippy-driver 2>/dev/null || command -v clippy-driver || true)
if [ -z "$clippy_driver" ]; then
  rustup component add clippy >/dev/null 2>&1 || true
  clippy_driver=$(rustup which clippy-driver 2>/dev/null || true)
fi
if [ -n "$clippy_driver" ]; then
  export RUSTC_WORKSPACE_WRAPPER=$clippy_driver
else
  echo "no clippy-driver (rustup component add clippy failed): built with rustc alone"
fi
# A clean clone gains nothing from incremental caches, and they cost several GB of
# disk (a CI run once died of a full disk while linking). Set it to 1 to keep them.
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"
set +e
# The JSON on stdout lists the test executables the Rust tests below run; the diagnostics
# are rendered on stderr as in a plain build.
cargo test --workspace --profile test --no-run --message-format=json-render-diagnostics >target/build-artifacts.json 2>target/build-output.txt
build_status=$?
set -e
# What the build said beyond its progress lines: warnings, errors (none, when all is well).
{ grep -vE '^ *(Compiling|Executable|Finished|Blocking|Downloaded|Downloading|Updating|Locking|Adding) ' target/build-output.txt || true; } | tail -200
lint_count=$(grep -cE '^(warning|error)(\[[a-zA-Z0-9_:]+\])?: ' target/build-output.txt || true)
if [ -n "$clippy_driver" ] && [ "$lint_count" -eq 0 ] && [ "$build_status" -eq 0 ]; then
  passed=$((passed + 1))
  echo "ok: the workspace builds with no warning from rustc or clippy (cargo clippy --workspace --all-targets -- -D warnings)"
else
  failed=$((failed + 1))
  echo "lints: $lint_count warning or error line(s) from rustc or clippy" >>"$failed_names"
  echo "FAILED: lints: $lint_count warning or error line(s) from rustc or clippy above${clippy_driver:-, and clippy is not installed}"
fi
phase "build and lints"
if [ "$build_status" -ne 0 ]; then
  echo "FAILED: the build (cargo test --workspace --profile test --no-run); nothing else can run"
  echo
  echo "all: $passed passed, $((failed + 1)) failed, 0 skipped"
  exit 1
fi

# The Rust tests keep the CPU busy; the interop tests mostly wait (DDS discovery, real-time
# runs, Python start-up). So the Rust tests run in the background while the interop tests
# run below, each DDS test in a domain of its own range (Rust 1..170 and 220..232, interop
# 170..220), and their output is printed when both are done. Nothing below may take cargo's
# lock while they run: the interop scripts use the binaries built above.
# The test executables run in two lanes, as `cargo test` would run them one after another
# (from their package's directory, with `--nocapture`): the node tests, which wait on DDS
# and on node processes, beside all the others, which compute. `cargo test` cannot do that:
# a second cargo waits for the first's lock until its tests have run.
export OILFILM_BUILT=1
echo "== Rust tests (in the background; their output follows the interop tests)"
python3 - target/build-artifacts.json >target/test-executables.txt <<'PY'
import json, os, sys
for line in open(sys.argv[1]):
    if not line.startswith("{"):
        continue
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m["profile"]["test"] and m.get("executable"):
        package_dir = os.path.dirname(m["manifest_path"])
        lane = "dds" if os.path.basename(package_dir) == "nodes" else "compute"
        print(lane, package_dir, m["target"]["name"], m["executable"], sep="\t")
PY
# No executable listed would pass as no test failing: fail instead.
executables=$(wc -l <target/test-executables.txt)
if [ "$executables" -eq 0 ]; then
  failed=$((failed + 1))
  echo "FAILED: the build listed no test executable (target/build-artifacts.json)"
  echo "rust: the build listed no test executable" >>"$failed_names"
fi
# One lane: every executable of `$1` in turn, output to target/test-output-$1.txt; a binary
# that exits non-zero without a test report (a crash) is counted in target/test-crashes-$1.
run_lane() {
  local lane=$1 out=target/test-output-$1.txt crashes=0
  : >"$out"
  while IFS=$'\t' read -r l dir name exe; do
    [ "$l" = "$lane" ] || continue
    echo "     Running $name ($exe)" >>"$out"
    local before
    before=$(grep -c '^test result:' "$out" || true)
    if ! (cd "$dir" && "$exe" --nocapture) >>"$out" 2>&1; then
      if [ "$(grep -c '^test result:' "$out" || true)" -eq "$before" ]; then
        crashes=$((crashes + 1))
        echo "CRASHED: $name ($exe) ended without a test report" >>"$out"
      fi
    fi
  done <target/test-executables.txt
  echo "$crashes" >"target/test-crashes-$lane"
}
rust_started=$SECONDS
rm -f target/test-crashes-* target/test-seconds
(
  run_lane dds &
  run_lane compute
  wait
  echo "$((SECONDS - rust_started))" >target/test-seconds
) &
rust_pid=$!

echo "== ROS 2 interop (rclpy and rosidl from PyPI, in .venv-ros)"
wait "$ros_venv_pid" "$bag_venv_pid" "$foreign_venv_pid" || true
for v in ros bag foreign; do
  if [ "$(cat target/setup-$v-venv.status 2>/dev/null)" != 0 ]; then
    echo "setting up .venv-$v failed; its log:"
    tail -40 "target/setup-$v-venv.log"
  fi
done
phase "waiting for the Python venvs"
# One interop check: its verdict and time, and `ok` or `failed` appended to the file
# `$interop_counts` names (so that a group run in the background is counted too).
interop() {
  local name=$1 t0=$SECONDS
  shift
  echo "-- $name"
  if "$@"; then
    echo "ok: $name ($((SECONDS - t0)) s)"
    echo ok >>"$interop_counts"
  else
    echo "FAILED: $name ($((SECONDS - t0)) s)"
    echo failed >>"$interop_counts"
    echo "interop: ${name:0:150}" >>"$failed_names"
  fi
}

# The checks of files (bags, other tools' records) need no DDS but the bag-crash check's
# two publishers, in domains 210..220 of their own; they run in the background, beside the
# later ROS 2 checks (domains 170..210), and their output is printed after them. They start
# after the live-graph and launch checks, whose timing (discovery, a ramp's last setpoints
# before a node exits) is the most sensitive to a loaded machine.
rm -f target/interop-*.counts target/interop-files.done
files_group() {
  interop_counts=target/interop-files.counts
  files_started=$SECONDS
  echo "== rosbag2 MCAP bag interop (rosbags, mcap, mcap-ros2-support, pymcap-cli from PyPI, in .venv-bag)"
  interop "rosbags (type hashes checked) and mcap-ros2-support decode our bags (also a killed one after our recovery); pymcap-cli doctor finds no error; rosbags-convert round-trips via sqlite3; our reader and oilfilm identify read rosbags' bags" bash tests/interop/run-bag-readers.sh
  interop "the recorder binary SIGKILLed mid-chunk: after oilfilm bag recover, rosbags and mcap-ros2-support read exactly our reader's messages, every complete chunk's" bash tests/interop/run-bag-crash.sh
  echo "== Records from other tools (npTDMS, scipy, pandas from PyPI, in .venv-foreign)"
  interop "TDMS (npTDMS: several groups and segments; interleaved, read back by npTDMS), a .mat struct (scipy.io.savemat) and a CSV with a units row (pandas) import and identify to the ASCII record's coefficients bit for bit; a comma-decimal CSV is refused, nothing written" bash tests/interop/run-foreign-files.sh
  echo "== time: the bag and record interop took $((SECONDS - files_started)) s, beside the ROS 2 interop"
  touch target/interop-files.done
}

interop_counts=target/interop-ros.counts
interop "oilfilm_msgs builds with rosidl; rclpy serialises every message as the golden CDR fixtures say" bash tests/interop/run-check-msgs.sh --check
interop "rclpy publishes and receives every oilfilm_msgs message over DDS (loopback)" bash tests/interop/run-rclpy-roundtrip.sh
# The binaries `cargo test` just built (target/debug, optimised by [profile.test]).
interop "rclpy sees, echoes, parameterises and drives our live node graph; it stops cleanly on SIGINT" bash tests/interop/run-rclpy-live.sh target/debug
interop "oilfilm launch as a process tree: a run without an estimate exits non-zero naming the silent node; SIGKILL of the launcher stops its nodes, the exciter ramping to zero" bash tests/interop/run-launch-lifecycle.sh target/debug
( files_group ) >target/interop-files.log 2>&1 &
files_pid=$!
interop "the real ros2 command line (ros2cli on the rclpy wheels) against the live graph and oilfilm play: node/topic/service list, topic info -v, echo --once, hz, param list/describe/get/set, refusals on /rosout, the player named" bash tests/interop/run-ros2-cli.sh target/debug
interop "oilfilm play seen from rclpy: /clock is rosgraph_msgs/Clock on the bag's log time and a use_sim_time node follows it; every message arrives with its recorded stamp" bash tests/interop/run-rclpy-player.sh target/debug
phase "ROS 2 interop"

wait "$files_pid" || true
cat target/interop-files.log
phase "waiting for the bag and record interop"
passed=$((passed + $(cat target/interop-*.counts 2>/dev/null | grep -c '^ok$' || true)))
failed=$((failed + $(cat target/interop-*.counts 2>/dev/null | grep -c '^failed$' || true)))
# A background group that did not reach its end (killed, or the shell failed in it) fails,
# whatever its checks reported before.
if [ ! -e target/interop-files.done ]; then
  failed=$((failed + 1))
  echo "FAILED: the bag and record interop did not run to its end (its log above)"
  echo "interop: the bag and record interop did not run to its end" >>"$failed_names"
fi

echo "== Rust tests (their output)"
wait "$rust_pid" || true
cat target/test-output-compute.txt target/test-output-dds.txt >target/test-output.txt
cat target/test-output.txt
crashes=$(($(cat target/test-crashes-compute 2>/dev/null || echo 1) + $(cat target/test-crashes-dds 2>/dev/null || echo 1)))
read -r rp rf rs < <(grep -E "^test result:" target/test-output.txt | awk '
  { for (i = 1; i <= NF; i++) { if ($i ~ /passed;/) p += $(i-1); if ($i ~ /failed;/) f += $(i-1); if ($i ~ /ignored;/) s += $(i-1) } }
  END { printf "%d %d %d\n", p, f, s }')
passed=$((passed + rp))
failed=$((failed + rf))
# A crash counts as a failure even if no test reported one.
failed=$((failed + crashes))
echo "== time: the Rust tests took $(cat target/test-seconds 2>/dev/null || echo '?') s, beside the interop tests (total $SECONDS s)"
{ grep -E '^test .* \.\.\. FAILED$' target/test-output.txt | sed -E 's/^test (.*) \.\.\. FAILED$/rust: \1/' || true; } >>"$failed_names"
{ grep '^CRASHED: ' target/test-output.txt | sed 's/^CRASHED: /rust: crashed: /' || true; } >>"$failed_names"
echo
if [ -s "$failed_names" ]; then
  echo "failed:"
  sed 's/^/  /' "$failed_names"
fi
echo "all: $passed passed, $failed failed, $rs skipped"
[ "$failed" -eq 0 ]
