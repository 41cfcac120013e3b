"""Shared fixtures. The Mitsuba variant is the one the renderer's set-up chose from
LIDAR_MITSUBA_VARIANT (default llvm_ad_mono), with our plugins registered in it."""
import gc

import numpy as np
import pytest

import lidar_mitsuba

mi = lidar_mitsuba.ensure_renderer()     # the renderer, set up as a first run would
VARIANT = mi.variant()


def pytest_xdist_auto_num_workers(config):
    """``-n auto`` (the default, pyproject.toml): one worker per core, at most 4 (each holds
    its own renderer, ~1.5 GB)."""
    import os
    return max(1, min(4, len(os.sched_getaffinity(0))))


#: The test files that take longest (seconds on one of two workers: the per-file sums of
#: setup, call and teardown in a whole-suite run, ``pytest -v --durations=0``, session 26:
#: cold numba cache as on a fresh clone, the 2-core VM shared at a load of ~3; only their
#: order counts), started first: with ``--dist loadfile`` a file stays on one worker, and
#: xdist's default order (files with the most tests first) left the heaviest, with few tests,
#: to the end of the run, where one worker finished them alone. Longest first (the LPT rule)
#: ends the workers within about the last file's time of each other (that run: 469 and 468 s
#: of tests). A file not listed runs after these, in collection order; a new slow file
#: belongs here.
SLOW_FILES = {"test_bench.py": 144, "test_snow_kernel.py": 112, "test_docs.py": 93,
              "test_notebooks.py": 70, "test_reproduce.py": 52, "test_campaign.py": 49,
              "test_twin.py": 43, "test_snow.py": 36, "test_import_boundaries.py": 27,
              "test_real_fill.py": 25, "test_granule.py": 22, "test_peer_media.py": 22,
              "test_atl03_fields.py": 19, "test_fpb_matrix.py": 19, "test_sweep.py": 18, "test_detector_pinned.py": 16,
              "test_peer.py": 16, "test_cli.py": 14, "test_cloud.py": 12,
              "test_brdf_variants.py": 12, "test_realism.py": 11, "test_plan.py": 11,
              "test_forest_twin.py": 10}


#: the controller's compiling processes (:func:`pytest_configure`), awaited once
_COMPILING: list = []


def pytest_configure(config):
    """The whole suite on xdist workers (the README's command): the numba kernels are compiled
    by the controller's own processes when their cache beside the package is cold (a fresh
    clone, or an edited kernel): the detector's in one process and the DEM footprint means',
    the ATL06 fit's and ATL03's fields' in another, side by side (lidar_mitsuba.precompile; ~38 s and ~26 s CPU
    on the 2-core VM), while the workers start and collect; no test is handed out before they
    are done (:func:`pytest_xdist_node_collection_finished`). Otherwise both workers compile
    the detector at once, each its own copy (both begin with files that detect photons), and
    later processes compile what is not cached yet. Cached kernels: nothing runs. A selection
    of files (or ``-n 0``) compiles, as before, what its tests use."""
    import subprocess
    import sys
    from lidar_mitsuba import precompile as pc
    whole_suite = config.args_source is pytest.Config.ArgsSource.TESTPATHS
    workers = getattr(config.option, "numprocesses", None) or 0
    if hasattr(config, "workerinput") or not whole_suite or workers < 2:
        return
    steps = []
    if not pc.is_cached("detector"):
        steps.append("p._detector()")
    rest = [f"p._{stage}()" for stage in pc.KERNELS
            if stage != "detector" and not pc.is_cached(stage)]
    if rest:
        steps.append("; ".join(rest))
    _COMPILING.extend(subprocess.Popen([sys.executable, "-c",
                                        f"from lidar_mitsuba import precompile as p; {code}"])
                      for code in steps)


def pytest_xdist_node_collection_finished(node, ids):
    """The controller, as each worker has collected: the kernels' compiling processes are
    awaited before the first test is handed out (:func:`pytest_configure`)."""
    while _COMPILING:
        p = _COMPILING.pop()
        if p.wait() != 0:
            raise RuntimeError(f"compiling the numba kernels failed ({p.args[-1]})")


def pytest_collection_modifyitems(config, items):
    """The slow files first, longest first (:data:`SLOW_FILES`; the sort is stable: each
    file's tests keep their order, and pyproject's ``--no-loadscope-reorder`` keeps xdist
    from reordering the files by their number of tests)."""
    items.sort(key=lambda item: -SLOW_FILES.get(item.path.name, 0))


@pytest.fixture
def rng():
    """A seeded numpy generator: every test that draws numbers is reproducible."""
    return np.random.default_rng(20131125)


@pytest.fixture(scope="session")
def variant():
    return VARIANT


@pytest.fixture(autouse=True, scope="session")
def _kernel_cache(tmp_path_factory):
    """Snow kernel tables (lidar_mitsuba.ground.snow.kernel) go to a folder of this test run's
    own, shared by its workers: each table is built from the walk once per run, never read
    from an earlier run (subprocesses inherit the setting)."""
    import os
    old = os.environ.get("LIDAR_MITSUBA_CACHE")
    if os.environ.get("PYTEST_XDIST_WORKER"):     # one folder for all workers of this run
        cache = tmp_path_factory.getbasetemp().parent / "cache"   # (tables are locked while built)
        cache.mkdir(exist_ok=True)
    else:
        cache = tmp_path_factory.mktemp("cache")
    os.environ["LIDAR_MITSUBA_CACHE"] = str(cache)
    # Tables of 2^14 walk photons a node (the default is 2^17): the tests that use a table
    # check what a run does with it, not its precision; tests/test_snow_kernel.py sets its own
    # counts and checks the tables against the walk (validate's smoke run in
    # tests/test_twin.py builds its tables at this size too: its verdicts do not turn on it).
    from lidar_mitsuba.ground.snow import kernel
    old_photons, kernel.PHOTONS = kernel.PHOTONS, 1 << 14
    os.environ["LIDAR_MITSUBA_KERNEL_PHOTONS"] = str(1 << 14)
    yield
    kernel.PHOTONS = old_photons
    os.environ.pop("LIDAR_MITSUBA_KERNEL_PHOTONS", None)
    if old is None:
        os.environ.pop("LIDAR_MITSUBA_CACHE", None)
    else:
        os.environ["LIDAR_MITSUBA_CACHE"] = old


@pytest.fixture(scope="session")
def snow_study_file(_kernel_cache):
    """Where tests/test_bench.py's bench run leaves its snow study (``snow_bias.run(quick=True,
    smoke=True)``, the JSON of ``bench.json["snow"]``) for notebook 02 in
    tests/test_notebooks.py, which makes the same call: the notebook reads it back (its
    ``SNOW_STUDY_JSON``) instead of running it again (~20 CPU-s) where the bench ran first in
    this test run (the folder is this run's, shared by its workers: :func:`_kernel_cache`);
    otherwise it runs the study itself."""
    import os
    import pathlib
    return pathlib.Path(os.environ["LIDAR_MITSUBA_CACHE"]) / "snow_study_smoke.json"


@pytest.fixture(autouse=True, scope="module")
def _free_mitsuba_objects():
    """Collect each test module's garbage when it ends (a collection costs ~0.25 s with this
    suite's imports: once per module, not per test), so that the scenes of earlier modules
    (Mitsuba objects held in reference cycles) do not stay registered. Dr.Jit compiles a call on a
    shape or BSDF for every live instance of its kind; with stale meshes of two kinds
    interleaved in the registry, drjit 1.5's LLVM backend once emitted one merged callable
    twice and aborted the process ("invalid redefinition of function"), in the full suite
    only (test_xml_scenes::test_flipped_ply_is_diagnosed)."""
    yield
    gc.collect()
