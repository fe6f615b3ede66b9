#!/usr/bin/env bash
# The recorder killed for real, read by the tools users have: the sim exciter and DAQ publish
# on DDS, the `oilfilm-recorder` binary records them, gets SIGKILL mid-chunk, `oilfilm bag
# recover` repairs the bag, and rosbags (AnyReader) and mcap + mcap-ros2-support (from PyPI,
# in .venv-bag) read what our reader reads: every message of every complete chunk.
#
#   bash tests/interop/run-bag-crash.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
py=$(bash tests/interop/setup-bag-venv.sh)
work=$(mktemp -d "${TMPDIR:-/tmp}/oilfilm-bag-crash.XXXXXX")
trap 'rm -rf "$work"' EXIT
bash tests/interop/build-binaries.sh
OILFILM_BIN=$(pwd)/target/debug OILFILM_READ_BAG=$(pwd)/target/debug/examples/read_bag OILFILM_WORK=$work \
  "$py" -m pytest -q -p no:cacheprovider --basetemp "$work/pytest" tests/interop/test_bag_crash.py
