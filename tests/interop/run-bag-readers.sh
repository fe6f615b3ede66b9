#!/usr/bin/env bash
# Our rosbag2 MCAP bags against the readers and tools users have (rosbags with its
# AnyReader type-hash check and rosbags-convert, mcap + mcap-ros2-support, pymcap-cli doctor,
# from PyPI in .venv-bag), and bags written by rosbags read by ours and by `oilfilm identify`.
#
#   bash tests/interop/run-bag-readers.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
py=$(bash tests/interop/setup-bag-venv.sh)
work=$(mktemp -d "${TMPDIR:-/tmp}/oilfilm-bag-interop.XXXXXX")
trap 'rm -rf "$work"' EXIT
bash tests/interop/build-binaries.sh
bin=target/debug/examples
"$bin/write_sim_rig" "$work/sim_rig" 2
# The other chunk compressions and a bag split into several files, for pymcap-cli doctor.
"$bin/write_sim_rig" "$work/sim_rig_lz4" 2 lz4
"$bin/write_sim_rig" "$work/sim_rig_none" 2 none
"$bin/write_sim_rig" "$work/sim_rig_split" 2 zstd 0.7
OILFILM_BAG=$work/sim_rig OILFILM_EXPECTED=$work/sim_rig.expected.yaml OILFILM_READ_BAG=$(pwd)/$bin/read_bag \
OILFILM_BAGS=$work/sim_rig_lz4:$work/sim_rig_none:$work/sim_rig_split OILFILM_BIN=$(pwd)/target/debug/oilfilm \
  "$py" -m pytest -q -p no:cacheprovider --durations=5 --basetemp "$work/pytest" tests/interop/test_bag_readers.py tests/interop/test_bag_tools.py
