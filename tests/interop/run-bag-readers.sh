#!/usr/bin/env bash
# Our rosbag2 MCAP bags against the readers users have (rosbags, mcap + mcap-ros2-support,
# from PyPI in .venv-bag), and a bag written by rosbags read by ours.
#
#   bash tests/interop/run-bag-readers.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
py=$(bash tests/interop/setup-bag-venv.sh)
work=$(mktemp -d "${TMPDIR:-/tmp}/oilfilm-bag-interop.XXXXXX")
trap 'rm -rf "$work"' EXIT
cargo build --quiet --profile test -p oilfilm-bag --examples
bin=target/debug/examples
"$bin/write_sim_rig" "$work/sim_rig" 2
OILFILM_BAG=$work/sim_rig OILFILM_EXPECTED=$work/sim_rig.expected.yaml OILFILM_READ_BAG=$(pwd)/$bin/read_bag \
  "$py" -m pytest -q -p no:cacheprovider --basetemp "$work/pytest" tests/interop/test_bag_readers.py
