# Sourced by the setup-*-venv.sh scripts: a venv of pinned PyPI wheels, cached by a stamp of
# its package list.
#
#   pip_venv VENV PYTHON_OVERRIDE_VAR PACKAGE...
#
# Creates VENV with the first Python >= 3.10 found (the variable named PYTHON_OVERRIDE_VAR
# first, then python3, python3.13 ... python3.10) unless it holds one already, installs the
# packages unless the stamp says they are in, and prints the venv's python on stdout;
# progress goes to stderr through the caller's `log`.
pip_venv() {
  local venv=$1 override_var=$2
  shift 2
  local packages=("$@")
  python_ok() {
    "$1" -c 'import sys; sys.exit(0 if sys.version_info[:2] >= (3, 10) else 1)' 2>/dev/null
  }
  local want stamp py c
  want=$(printf '%s\n' "${packages[@]}" | sha256sum | cut -d' ' -f1)
  stamp=$venv/.oilfilm-packages.sha256
  if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ] || [ ! -x "$venv/bin/python" ]; then
    if [ ! -x "$venv/bin/python" ] || ! python_ok "$venv/bin/python"; then
      py=
      for c in ${!override_var:-} python3 python3.13 python3.12 python3.11 python3.10; do
        if command -v "$c" >/dev/null 2>&1 && python_ok "$(command -v "$c")"; then py=$(command -v "$c"); break; fi
      done
      [ -n "$py" ] || { log "no Python >= 3.10 found (set $override_var)"; exit 1; }
      log "creating $venv with $py ($("$py" --version 2>&1))"
      rm -rf "$venv"
      "$py" -m venv "$venv"
    fi
    log "installing ${packages[*]}"
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check "${packages[@]}" >&2
    echo "$want" >"$stamp"
  fi
  echo "$venv/bin/python"
}
