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

python_ok() {
  "$1" -c 'import sys; sys.exit(0 if sys.version_info[:2] >= (3, 10) else 1)' 2>/dev/null
}

want=$(printf '%s\n' "${packages[@]}" | sha256sum | cut -d' ' -f1)
stamp=$venv/.oilfilm-packages.sha256
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ] || [ ! -x "$venv/bin/python" ]; then
  if [ ! -x "$venv/bin/python" ] || ! python_ok "$venv/bin/python"; then
    py=
    for c in ${OILFILM_BAG_PYTHON:-} python3 python3.13 python3.12 python3.11 python3.10; do
      if command -v "$c" >/dev/null 2>&1 && python_ok "$(command -v "$c")"; then py=$(command -v "$c"); break; fi
    done
    [ -n "$py" ] || { log "no Python >= 3.10 found (set OILFILM_BAG_PYTHON)"; exit 1; }
    log "creating $venv with $py ($("$py" --version 2>&1))"
    rm -rf "$venv"
    "$py" -m venv "$venv"
  fi
  log "installing ${packages[*]}"
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check "${packages[@]}" >&2
  echo "$want" > "$stamp"
fi
echo "$venv/bin/python"
