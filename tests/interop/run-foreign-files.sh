#!/usr/bin/env bash
# Records written by the libraries labs use (npTDMS, scipy.io.savemat, pandas, from PyPI in
# .venv-foreign) imported and identified by `oilfilm` to the coefficients of the same record
# in our ASCII format; a comma-decimal CSV refused.
#
#   bash tests/interop/run-foreign-files.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
py=$(bash tests/interop/setup-foreign-venv.sh)
work=$(mktemp -d "${TMPDIR:-/tmp}/oilfilm-foreign-interop.XXXXXX")
trap 'rm -rf "$work"' EXIT
bash tests/interop/build-binaries.sh
OILFILM_BIN=$(pwd)/target/debug/oilfilm \
  "$py" -m pytest -q -p no:cacheprovider --durations=5 --basetemp "$work/pytest" tests/interop/test_foreign_files.py
