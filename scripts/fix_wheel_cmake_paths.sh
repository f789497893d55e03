#!/usr/bin/env bash
# Point the ROS message wheels' exported CMake targets at this machine's Python and numpy.
#
# The wheels are built in a manylinux image whose interpreters live at
# /opt/python/cpXY-cpXY/ (cp311, cp312, ...); their *__rosidl_generator_pyExport.cmake files
# name that interpreter's include directory and its numpy include directory, which do not
# exist here, and CMake's generate step then fails for any package that depends on those
# messages. Whatever the builder's version, rewrite both to the given directories.
# Idempotent: once rewritten, no /opt/python/cp path is left to match.
#
# Usage: fix_wheel_cmake_paths.sh PYTHON_INCLUDE_DIR NUMPY_INCLUDE_DIR FILE...
set -euo pipefail
py_inc="$1"; np_inc="$2"; shift 2
for f in "$@"; do
  grep -q '/opt/python/cp3[0-9]*-cp3[0-9]*' "$f" || continue
  # numpy first: its path starts with the interpreter prefix the second rule rewrites.
  sed -i -E \
    -e "s#/opt/python/cp3[0-9]+-cp3[0-9]+/lib/python3\.[0-9]+/site-packages/numpy/(_core|core)/include#${np_inc}#g" \
    -e "s#/opt/python/cp3[0-9]+-cp3[0-9]+/include/python3\.[0-9]+#${py_inc}#g" "$f"
done
