#!/usr/bin/env bash
# Our node graph live on DDS, seen, echoed, parameterised and driven from rclpy
# (test_rclpy_live.py). Needs the binaries of `cargo test --workspace --profile test`
# (target/debug) or of a release build: pass their directory as $1.
set -euo pipefail
cd "$(dirname "$0")/../.."
bin_dir=${1:-target/debug}
[ -x "$bin_dir/oilfilm" ] && [ -x "$bin_dir/oilfilm-daq" ] || { echo "no oilfilm binaries in $bin_dir (build them first)" >&2; exit 1; }
eval "$(bash tests/interop/setup-ros-venv.sh)"
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-$((170 + RANDOM % 40))}
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_LOCALHOST_ONLY=1
echo "ROS_DOMAIN_ID=$ROS_DOMAIN_ID (loopback only)"
exec timeout 300 "$OILFILM_ROS_PYTHON_BIN" tests/interop/test_rclpy_live.py "$(cd "$bin_dir" && pwd)"
