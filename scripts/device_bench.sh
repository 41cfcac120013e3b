#!/usr/bin/env bash
# On a GPU machine lent by the `device` tool (run there from the repository root, with
# carry [".whl"] made by scripts/device_wheels.sh):
#
#   bash scripts/device_bench.sh [bench|tests|all]      (default: bench)
#
# bench: `lidar-mitsuba bench --throughput-only` on cuda_ad_mono (and llvm_ad_mono beside it
#        when that machine's libLLVM is usable), into $OUT/bench (bench.json, throughput.png);
# tests: the test suite on cuda_ad_mono, not the slow ones, without the tests whose packages
#        the device lacks (listed as it starts), log in $OUT/tests.log.
# Prints the device, and each step's wall time. Everything it needs travels with the call.
set -uo pipefail
mode=${1:-bench}
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 LIDAR_MITSUBA_VARIANT=cuda_ad_mono
nvidia-smi -L || true
python3 -c "import lidar_mitsuba, mitsuba as mi; print('variant', mi.variant())" || exit 1
variants=cuda_ad_mono
if python3 -c "import sys, lidar_mitsuba.trace.variant as v; sys.exit('llvm_ad_mono' not in v.usable_variants())" 2>/dev/null; then
    variants=cuda_ad_mono,llvm_ad_mono
fi
if [ "$mode" = bench ] || [ "$mode" = all ]; then
    t0=$SECONDS
    python3 lidar_mitsuba_cli.py bench --throughput-only --variant "$variants" \
        --out "$OUT/bench" 2>&1 | tee "$OUT/bench.log"
    echo "bench: $((SECONDS - t0)) s"
fi
if [ "$mode" = tests ] || [ "$mode" = all ]; then
    # the device's image lacks the DEM, sweep and notebook stacks (rasterio and pyproj alone
    # would not fit beside the wheels): leave out the tests that need them
    skip=()
    python3 -c "import rasterio, pyproj" 2>/dev/null || skip+=(--ignore=tests/test_granule.py
        --ignore=tests/test_bench.py
        --deselect=tests/test_snow.py::test_snow_over_a_dem_granule_across_sections)
    python3 -c "import dask.distributed" 2>/dev/null || skip+=(--ignore=tests/test_sweep.py)
    python3 -c "import nbclient, nbformat" 2>/dev/null || skip+=(--ignore=tests/test_notebooks.py)
    echo "left out: ${skip[*]:-nothing}"
    t0=$SECONDS
    python3 -m pytest -q -m "not slow" -p no:cacheprovider "${skip[@]}" 2>&1 \
        | tee "$OUT/tests.log" | tail -n 30
    echo "tests: $((SECONDS - t0)) s"
fi
