#!/usr/bin/env bash
# Wheels for a GPU machine lent through the workplace's `device` tool, which cannot reach
# the network: cp312 x86-64 builds of what its image lacks (mitsuba, drjit, trimesh; numpy,
# scipy, numba, h5py, matplotlib and tqdm are there), saved in .whl/ (ignored by git).
# The mitsuba wheel is cut to the llvm/cuda mono variants: the rgb, spectral, polarized and
# scalar modules would put it over the 64 MiB that travel with a call.
#
#   bash scripts/device_wheels.sh            # here, once per session
#   then, on the device (the `run` tool, carry [".whl"]):  bash scripts/device_bench.sh
set -euo pipefail
cd "$(dirname "$0")/.."
grep -qx '/.whl/' .git/info/exclude 2>/dev/null || echo '/.whl/' >> .git/info/exclude
rm -rf .whl && mkdir -p .whl
py=$(command -v python3)
"$py" -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 \
    --platform manylinux2014_x86_64 -d .whl \
    "mitsuba==$(.venv/bin/python -c 'import mitsuba; print(mitsuba.__version__)')" \
    "drjit==$(.venv/bin/python -c 'import drjit; print(drjit.__version__)')" \
    "trimesh==$(.venv/bin/python -c 'import trimesh; print(trimesh.__version__)')"
whl=$(ls .whl/mitsuba-*.whl)
# drop the variants we never load (zip -d takes patterns inside the archive)
zip -q -d "$whl" 'mitsuba/*_rgb.cpython*' 'mitsuba/*_spectral*.cpython*' \
    'mitsuba/*_polarized*.cpython*' 'mitsuba/scalar_*.cpython*'
du -ch .whl/* | tail -n 1
