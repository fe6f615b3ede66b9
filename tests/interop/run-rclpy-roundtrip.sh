#!/usr/bin/env bash
# rclpy publishes every oilfilm_msgs message on loopback DDS and an rclpy subscriber
# checks it arrives equal. Builds the ROS env first if needed (setup-ros-venv.sh).
set -euo pipefail
cd "$(dirname "$0")/../.."
eval "$(bash tests/interop/setup-ros-venv.sh)"
# A random domain in 100..199 so parallel runs on one machine do not meet; loopback only.
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-$((170 + RANDOM % 40))}
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_LOCALHOST_ONLY=1
echo "ROS_DOMAIN_ID=$ROS_DOMAIN_ID (loopback only)"
exec timeout 60 "$OILFILM_ROS_PYTHON_BIN" tests/interop/test_rclpy_roundtrip.py
