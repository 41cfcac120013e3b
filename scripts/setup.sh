#!/usr/bin/env bash
# Set up lidar_mitsuba on a fresh Debian/Ubuntu machine: libLLVM 19 (Dr.Jit's LLVM backend aborts
# with the libLLVM 15/16 these machines ship), then a virtual environment in .venv with the
# package installed. Usage: bash scripts/setup.sh [--test]   (--test adds the test extras and
# the documentation's, which tests/test_docs.py builds)
set -euo pipefail
cd "$(dirname "$0")/.."

have_llvm() {   # any libLLVM >= 17 (a glob that matches nothing stays literal and fails -e)
  for f in /usr/lib/*-linux-gnu/libLLVM-1[7-9].so* /usr/lib/*-linux-gnu/libLLVM-2[0-9].so* \
           /usr/lib/llvm-1[7-9]/lib/libLLVM*.so* /usr/lib/llvm-2[0-9]/lib/libLLVM*.so*; do
    [ -e "$f" ] && return 0
  done
  return 1
}
if ! have_llvm; then
  SUDO=""
  [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  echo "== installing libllvm19 (Dr.Jit needs libLLVM >= 17)"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libllvm19 >/dev/null
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "== creating .venv"
  "$PY" -m venv .venv
fi
extras=""
[ "${1:-}" = "--test" ] && extras="[test,docs]"
echo "== installing lidar_mitsuba$extras"
.venv/bin/python -m pip install -q --disable-pip-version-check -e ".$extras"
.venv/bin/python -c "import lidar_mitsuba as lm; print('lidar_mitsuba ready:', lm.ensure_renderer().variant())"
