#!/usr/bin/env bash
# Creates (or refreshes) .venv-ross with ROSS (ross-rotordynamics 3.1.0 from PyPI) for
# `oilfilm-bench physics`, on Python 3.13 when the machine has it (pyenv's or python3.13 on
# PATH), else the newest python3 found; prints the interpreter on its last line.
set -euo pipefail
cd "$(dirname "$0")/../.."
pick() {
  for c in "$HOME/.pyenv/versions/3.13"*/bin/python3.13 python3.13 python3.12 python3.11 python3.10 python3; do
    if command -v "$c" > /dev/null 2>&1; then echo "$c"; return; fi
  done
}
PY=${OILFILM_ROSS_PYTHON:-$(pick)}
if [ ! -x .venv-ross/bin/python ]; then
  "$PY" -m venv .venv-ross
fi
want="ross-rotordynamics==3.1.0"
if [ "$(cat .venv-ross/.installed 2>/dev/null)" != "$want" ]; then
  .venv-ross/bin/python -m pip install --quiet --upgrade pip
  .venv-ross/bin/python -m pip install --quiet "$want"
  echo "$want" > .venv-ross/.installed
fi
echo "$(pwd)/.venv-ross/bin/python"
