#!/usr/bin/env bash
# Creates (or refreshes) the project's Python virtual environment in .venv and installs
# tests/python/requirements.txt. Idempotent; prints the interpreter path on its last line.
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=${OILFILM_PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
stamp=.venv/.requirements.sha256
want=$(sha256sum tests/python/requirements.txt | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  .venv/bin/python -m pip install --quiet --upgrade pip
  .venv/bin/python -m pip install --quiet -r tests/python/requirements.txt
  echo "$want" > "$stamp"
fi
echo "$(pwd)/.venv/bin/python"
