#!/usr/bin/env bash
# Set up lidar_mitsuba on a fresh Debian/Ubuntu machine: libLLVM 19 (Dr.Jit's LLVM backend aborts
# with the libLLVM 15/16 these machines ship), then a virtual environment in .venv with the
# package installed. Usage: bash scripts/setup.sh [--test]   (--test adds the test extras and
# the documentation's, which tests/test_docs.py builds, with the site's own MathJax and Mermaid)
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
# uv resolves and installs the ~200 packages in about a minute where pip takes four or more;
# pip does it alone where uv cannot be had. Both compile the bytecode at install time, so that
# every process the tests start imports from .pyc files (PYTHONDONTWRITEBYTECODE may be set).
if .venv/bin/python -m pip install -q --disable-pip-version-check "uv>=0.5" >/dev/null 2>&1; then
  .venv/bin/python -m uv pip install -q --python .venv/bin/python --compile-bytecode -e ".$extras"
else
  .venv/bin/python -m pip install -q --disable-pip-version-check -e ".$extras"
fi
# and our own modules' (an editable install compiles none): a fresh process would otherwise
# compile our ~70 modules from source each time, ~0.1 s of CPU before its first granule (a
# source edited later is compiled again, in memory, until this runs again)
.venv/bin/python -m compileall -q lidar_mitsuba plugins >/dev/null
if [ "${1:-}" = "--test" ]; then
  # the documentation's MathJax and Mermaid, shipped inside the built site (it works offline):
  # pinned files of the npm registry's packages, into .venv/share (docs/_ext/offline_assets.py)
  if ! command -v npm >/dev/null; then
    echo "== installing npm (the docs' MathJax and Mermaid come from the npm registry)"
    SUDO=""
    [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq npm >/dev/null
  fi
  echo "== fetching the docs' MathJax and Mermaid"
  .venv/bin/python docs/_ext/offline_assets.py
fi
.venv/bin/python -c "import lidar_mitsuba as lm; print('lidar_mitsuba ready:', lm.ensure_renderer().variant())"
