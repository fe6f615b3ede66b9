#!/usr/bin/env bash
# Creates the Python environment of the foreign-record interop test from PyPI: the libraries
# labs write their records with (npTDMS for LabVIEW TDMS, scipy.io for MATLAB .mat, pandas
# for CSV) and pytest. Pure wheels, no ROS: separate from .venv-ros and .venv-bag.
# Idempotent and cached: a second run only checks the stamp of the package list.
#
#   .venv-foreign/    the venv
#
# Prints the venv's python on stdout; progress goes to stderr.
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
venv=$root/.venv-foreign
log() { echo "setup-foreign-venv: $*" >&2; }

# Pinned, so that what the test says these libraries write keeps holding.
packages=('npTDMS==1.13.0' 'numpy==2.4.6' 'scipy==1.17.1' 'pandas==3.1.1' 'pytest==9.2.0')

source tests/interop/pip-venv.sh
pip_venv "$venv" OILFILM_FOREIGN_PYTHON "${packages[@]}"
