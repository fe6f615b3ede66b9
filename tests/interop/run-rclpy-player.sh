#!/usr/bin/env bash
# Our player seen from rclpy (test_rclpy_player.py): a bag of a short sim_rig run played by
# `oilfilm play`, received by an rclpy node with use_sim_time, whose clock follows our
# /clock (rosgraph_msgs/msg/Clock). Pass the binaries' directory as $1 (default target/debug).
set -euo pipefail
cd "$(dirname "$0")/../.."
bin_dir=${1:-target/debug}
[ -x "$bin_dir/oilfilm" ] || { echo "no oilfilm binary in $bin_dir (build it first)" >&2; exit 1; }
bash tests/interop/build-binaries.sh
work=$(mktemp -d "${TMPDIR:-/tmp}/oilfilm-rclpy-player.XXXXXX")
trap 'rm -rf "$work"' EXIT
target/debug/examples/write_sim_rig "$work/sim_rig" 2 >/dev/null
eval "$(bash tests/interop/setup-ros-venv.sh)"
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-$((170 + RANDOM % 40))}
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_LOCALHOST_ONLY=1
echo "ROS_DOMAIN_ID=$ROS_DOMAIN_ID (loopback only)"
# Not `exec`: the EXIT trap above must still run to remove $work.
status=0
timeout 120 "$OILFILM_ROS_PYTHON_BIN" tests/interop/test_rclpy_player.py "$(cd "$bin_dir" && pwd)" "$work/sim_rig" || status=$?
exit "$status"
