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

python_ok() {
  "$1" -c 'import sys; sys.exit(0 if sys.version_info[:2] >= (3, 10) else 1)' 2>/dev/null
}

want=$(printf '%s\n' "${packages[@]}" | sha256sum | cut -d' ' -f1)
stamp=$venv/.oilfilm-packages.sha256
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ] || [ ! -x "$venv/bin/python" ]; then
  if [ ! -x "$venv/bin/python" ] || ! python_ok "$venv/bin/python"; then
    py=
    for c in ${OILFILM_FOREIGN_PYTHON:-} python3 python3.13 python3.12 python3.11 python3.10; do
      if command -v "$c" >/dev/null 2>&1 && python_ok "$(command -v "$c")"; then py=$(command -v "$c"); break; fi
    done
    [ -n "$py" ] || { log "no Python >= 3.10 found (set OILFILM_FOREIGN_PYTHON)"; exit 1; }
    log "creating $venv with $py ($("$py" --version 2>&1))"
    rm -rf "$venv"
    "$py" -m venv "$venv"
  fi
  log "installing ${packages[*]}"
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check "${packages[@]}" >&2
  echo "$want" > "$stamp"
fi
echo "$venv/bin/python"
