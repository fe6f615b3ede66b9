#!/usr/bin/env bash
# Creates the ROS 2 (kilted) Python environment from PyPI wheels and builds the
# oilfilm_msgs interface package with it. Idempotent and cached: a second run only checks
# stamps. No sudo, no apt: the wheels bring rclpy, rmw_fastrtps, rosidl and cmake.
#
#   .venv-ros/                      the venv (rclpy, std_msgs, rosidl generators, cmake)
#   target/ros/build/oilfilm_msgs/  cmake build tree
#   target/ros/oilfilm_msgs/        install space of oilfilm_msgs
#
# On success prints `export ...` lines (sourceable: `eval "$(bash tests/interop/setup-ros-venv.sh)"`);
# progress goes to stderr.
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
venv=$root/.venv-ros
build=$root/target/ros/build/oilfilm_msgs
install=$root/target/ros/oilfilm_msgs
log() { echo "setup-ros-venv: $*" >&2; }

# The ROS kilted wheels (ros-rclpy 9.1.2) are built for CPython 3.10 to 3.13
# (cp310..cp313, manylinux_2_28_x86_64). Python.h must exist too: rosidl compiles the
# Python type support against it.
packages=(
  'ros-kilted-rclpy[fastrtps]' ros-kilted-std-msgs
  ros-kilted-rosidl-default-generators ros-kilted-ament-cmake cmake ros-kilted-ament-package
  ros-kilted-ament-cmake-include-directories ros-kilted-rosidl-core-generators
  ros-kilted-ament-cmake-ros-core catkin_pkg
)

python_ok() {
  "$1" - <<'PY' 2>/dev/null
import os, sys, sysconfig
ok = (3, 10) <= sys.version_info[:2] <= (3, 13)
ok = ok and os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h"))
sys.exit(0 if ok else 1)
PY
}

pick_python() {
  local c
  for c in ${OILFILM_ROS_PYTHON:-} python3 python3.12 python3.11 python3.10 python3.13; do
    if command -v "$c" >/dev/null 2>&1 && python_ok "$(command -v "$c")"; then
      command -v "$c"; return 0
    fi
  done
  for c in "$HOME"/.pyenv/versions/3.1[0-3]*/bin/python3; do
    if [ -x "$c" ] && python_ok "$c"; then echo "$c"; return 0; fi
  done
  return 1
}

# 1. The venv and the wheels, cached by the package list.
want_pkgs=$(printf '%s\n' "${packages[@]}" | sha256sum | cut -d' ' -f1)
pkg_stamp=$venv/.oilfilm-packages.sha256
if [ ! -f "$pkg_stamp" ] || [ "$(cat "$pkg_stamp")" != "$want_pkgs" ] || [ ! -x "$venv/bin/python" ]; then
  if [ ! -x "$venv/bin/python" ] || ! python_ok "$venv/bin/python"; then
    py=$(pick_python) || { log "no CPython 3.10-3.13 with headers found (set OILFILM_ROS_PYTHON)"; exit 1; }
    log "creating $venv with $py ($("$py" --version 2>&1))"
    rm -rf "$venv"
    "$py" -m venv "$venv"
  fi
  log "installing ${packages[*]}"
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check "${packages[@]}" >&2
  echo "$want_pkgs" > "$pkg_stamp"
  rm -f "$venv/.oilfilm-cmake-paths"
fi

# 2. The wheels' exported CMake files name the build container's interpreter headers
# (/opt/python/cpXY-cpXY/include/pythonX.Y and its numpy/_core/include). Point them at
# this venv's interpreter and numpy, once per install.
if [ ! -f "$venv/.oilfilm-cmake-paths" ]; then
  read -r py_inc np_inc < <("$venv/bin/python" -c 'import sysconfig, numpy; print(sysconfig.get_paths()["include"], numpy.get_include())')
  fixed=0
  while IFS= read -r -d '' f; do
    sed -i -E \
      -e "s#/opt/python/cp[0-9]+-cp[0-9]+[a-z]*/lib/python3\.[0-9]+/site-packages/numpy/_core/include#${np_inc}#g" \
      -e "s#/opt/python/cp[0-9]+-cp[0-9]+[a-z]*/include/python3\.[0-9]+[a-z]*#${py_inc}#g" \
      "$f"
    fixed=$((fixed + 1))
  done < <(grep -rlZ --include='*.cmake' '/opt/python/cp' "$venv/share" "$venv/lib" 2>/dev/null || true)
  if grep -rq --include='*.cmake' '/opt/python/cp' "$venv/share" "$venv/lib" 2>/dev/null; then
    log "a build-container path is left in the exported CMake files:"
    grep -rn --include='*.cmake' '/opt/python/cp' "$venv/share" "$venv/lib" >&2 | head -5
    exit 1
  fi
  log "rewrote interpreter include paths in $fixed CMake files"
  touch "$venv/.oilfilm-cmake-paths"
fi

site=$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
pyver=$("$venv/bin/python" -c 'import sys; print("python%d.%d" % sys.version_info[:2])')

# 3. Build and install oilfilm_msgs, cached by the package's sources.
want_msgs=$( (cd msgs && cat package.xml CMakeLists.txt msg/*.msg; echo "$pyver") | sha256sum | cut -d' ' -f1)
msgs_stamp=$install/.oilfilm-msgs.sha256
if [ ! -f "$msgs_stamp" ] || [ "$(cat "$msgs_stamp")" != "$want_msgs" ]; then
  log "building oilfilm_msgs into $install"
  rm -rf "$build" "$install"
  mkdir -p "$build"
  export AMENT_PREFIX_PATH=$venv
  export CMAKE_PREFIX_PATH=$venv
  export PATH=$venv/bin:$PATH
  export PYTHONPATH=$site
  "$venv/bin/cmake" -S msgs -B "$build" \
    -DCMAKE_BUILD_TYPE=Release \
    -DCMAKE_INSTALL_PREFIX="$install" \
    -DBUILD_TESTING=OFF \
    -DPython3_EXECUTABLE="$venv/bin/python" \
    -DPython3_FIND_VIRTUALENV=ONLY \
    >"$build/../oilfilm_msgs-configure.log" 2>&1 || { tail -40 "$build/../oilfilm_msgs-configure.log" >&2; exit 1; }
  "$venv/bin/cmake" --build "$build" --parallel "${OILFILM_ROS_JOBS:-2}" \
    >"$build/../oilfilm_msgs-build.log" 2>&1 || { tail -40 "$build/../oilfilm_msgs-build.log" >&2; exit 1; }
  "$venv/bin/cmake" --install "$build" >"$build/../oilfilm_msgs-install.log" 2>&1 \
    || { tail -40 "$build/../oilfilm_msgs-install.log" >&2; exit 1; }
  echo "$want_msgs" > "$msgs_stamp"
fi

msgs_site=$(cd "$install" && ls -d lib/python3*/site-packages 2>/dev/null | head -1)
[ -n "$msgs_site" ] || { log "no site-packages under $install/lib"; exit 1; }
echo "export OILFILM_ROS_PYTHON_BIN=$venv/bin/python"
echo "export AMENT_PREFIX_PATH=$install:$venv"
echo "export PYTHONPATH=$install/$msgs_site\${PYTHONPATH:+:\$PYTHONPATH}"
echo "export LD_LIBRARY_PATH=$install/lib:$venv/lib\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
echo "export RMW_IMPLEMENTATION=rmw_fastrtps_cpp"
