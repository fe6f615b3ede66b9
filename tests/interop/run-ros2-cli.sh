#!/usr/bin/env bash
# Our live graph and `oilfilm play` through the real `ros2` command line (test_ros2_cli.py).
# Uses the system's `ros2` when ROS 2 is installed (ROS_DISTRO set and `ros2` on PATH);
# otherwise installs ros2cli into .venv-ros from the source tarballs in
# $OILFILM_ROS2CLI (default tests/data/ros2cli, a copy of ../shared/tools/ros2cli; see its README). Pass the binaries'
# directory as $1 (default target/debug).
set -euo pipefail
cd "$(dirname "$0")/../.."
bin_dir=${1:-target/debug}
[ -x "$bin_dir/oilfilm" ] && [ -x "$bin_dir/oilfilm-daq" ] || { echo "no oilfilm binaries in $bin_dir (build them first)" >&2; exit 1; }
system_ros2=
if [ -n "${ROS_DISTRO:-}" ] && command -v ros2 >/dev/null; then system_ros2=$(command -v ros2); fi
bash tests/interop/build-binaries.sh
work=$(mktemp -d "${TMPDIR:-/tmp}/oilfilm-ros2-cli.XXXXXX")
trap 'rm -rf "$work"' EXIT
target/debug/examples/write_sim_rig "$work/sim_rig" 6 >/dev/null
eval "$(bash tests/interop/setup-ros-venv.sh)"
if [ -z "$system_ros2" ]; then
  # The tarballs travel with the repository (tests/data/ros2cli, with their licences and
  # sources): CI runs on a clean clone that has nothing beside it.
  tools=${OILFILM_ROS2CLI:-$(pwd)/tests/data/ros2cli}
  [ -x "$(dirname "$OILFILM_ROS_PYTHON_BIN")/ros2" ] || bash "$tools/install.sh" "$(dirname "$(dirname "$OILFILM_ROS_PYTHON_BIN")")" >&2
  export PATH=$(dirname "$OILFILM_ROS_PYTHON_BIN"):$PATH
  export ROS_DISTRO=kilted
fi
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-$((170 + RANDOM % 40))}
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_LOCALHOST_ONLY=1
echo "ROS_DOMAIN_ID=$ROS_DOMAIN_ID (loopback only), ros2: $(command -v ros2)"
status=0
timeout 420 "$OILFILM_ROS_PYTHON_BIN" tests/interop/test_ros2_cli.py "$(cd "$bin_dir" && pwd)" "$work/sim_rig" || status=$?
ros2 daemon stop >/dev/null 2>&1 || true
exit "$status"
