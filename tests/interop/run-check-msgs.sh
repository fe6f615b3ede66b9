#!/usr/bin/env bash
# Builds the ROS env if needed, then serialises every oilfilm_msgs message with rclpy.
# Default: rewrites the golden fixtures tests/data/cdr/*.json; `--check`: compares.
set -euo pipefail
cd "$(dirname "$0")/../.."
eval "$(bash tests/interop/setup-ros-venv.sh)"
exec "$OILFILM_ROS_PYTHON_BIN" tests/interop/check_msgs.py "$@"
