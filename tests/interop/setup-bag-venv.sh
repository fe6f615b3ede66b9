#!/usr/bin/env bash
# Creates the Python environment of the bag interop tests from PyPI: the readers and writer
# our rosbag2 MCAP bags must work with (rosbags with rosbags-convert, mcap, mcap-ros2-support,
# pymcap-cli for `pymcap-cli doctor`) and pytest.
# Separate from .venv-ros because these are pure-Python wheels that need no ROS build.
# Idempotent and cached: a second run only checks the stamp of the package list.
#
#   .venv-bag/    the venv
#
# Prints the venv's python on stdout; progress goes to stderr.
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
venv=$root/.venv-bag
log() { echo "setup-bag-venv: $*" >&2; }

# Pinned so the facts in issue 5 (metadata.yaml version <= 9 for rosbags 0.11, ...) keep holding.
packages=(
  'rosbags==0.11.9' 'mcap==1.6.0' 'mcap-ros2-support==0.6.0' 'pymcap-cli==0.34.0' 'zstandard' 'lz4' 'pytest'
)

source tests/interop/pip-venv.sh
pip_venv "$venv" OILFILM_BAG_PYTHON "${packages[@]}"
