"""The first run on a machine compiles the compiled kernels: the detector's (numba, ~40 s on
2 cores) and, for tracks of 20 km or more, the compiled ATL06 fit (numba, ~22 s); numba keeps
them in ``__pycache__`` beside the package, so later runs load them in a fraction of a second.
(Dr.Jit's tracing kernels compile too, ~0.1-1 s each, and stay in ``~/.drjit``.)

:func:`compile_kernels` compiles them up front on tiny inputs, in a worker thread, while a
progress bar says what is happening and keeps moving; when every kernel is already cached it
returns at once and shows nothing.
"""
from __future__ import annotations

import os
import pathlib
import sys
import threading
import time

import numpy as np

#: rough compile times on the 2-core VM [s], for the bar's length (measured on a quiet machine,
#: empty numba cache, 2026-11-27: 40.1, 21.5 and 2.2 s)
DETECTOR_S = 40.0
ATL06_S = 22.0
#: (ESTIMATE: the 2.2 s were the stencil sums alone; the footprint weights' two kernels of
#: issue 43 took 1.5x their compile CPU under load, 0.9 against 0.6 s: 2.2 x 2.5)
HEIGHTS_S = 5.5
#: (ESTIMATE: ATL03's per-photon kernels compiled in ~1 s of CPU under load, 2026-11-27; x2)
ATL03_S = 2.0
#: (ESTIMATE: the HDF5 chunks' byte shuffle, four small loops, like ATL03's kernel; x2)
H5_S = 2.0
#: the geodesics' line loop (:mod:`lidar_mitsuba.geodesic`), the histogram test's pass over
#: the photons (:mod:`lidar_mitsuba.products.classify`) and the detector's binomial draws
#: (:mod:`lidar_mitsuba.detector.draws`): 0.9, ~2 and ~3 s of CPU measured, under load
GEODESIC_S = 1.0
CLASSIFY_S = 2.0
DRAWS_S = 3.0
#: the polar stereographic projection's loop (:mod:`lidar_mitsuba.polar_stereo`): 0.3 s of
#: CPU measured under load (2026-11-27), rounded up as the geodesics' is
POLAR_STEREO_S = 1.0
#: a DEM-pixel corridor tile's two passes (:mod:`lidar_mitsuba.ground.dem.pixel_mesh`): 2.1 s
#: of CPU measured on a cold cache (with the bilinear look-up they call), 2026-11-27
PIXEL_MESH_S = 2.0
#: each stage's numba kernels: the module (under ``lidar_mitsuba``) and the functions whose
#: cache entries say the stage is compiled (:func:`is_cached`): the detector's, the DEM
#: footprint means' (:mod:`lidar_mitsuba.ground.dem.heights`) and the compiled ATL06 fit's
KERNELS = {"detector": ("detector.deadtime", ("detect_shots", "choose_returns", "shot_stats")),
           "heights": ("ground.dem.heights", ("_stencil_sums", "_ramp_arguments", "_hat_means",
                                              "_bilinear", "_on_grid", "block_extents")),
           "atl06": ("products.atl06.kernel", ("fit_segment", "reference_heights")),
           "atl03": ("products.atl03.kernels", ("ph_id_count",)),
           "h5": ("products.h5kernels", ("shuffle",)),
           "geodesic": ("geodesic", ("direct_lines",)),
           "classify": ("products.classify", ("_photon_cells",)),
           "draws": ("detector.draws", ("binomial_inversion",)),
           "polar_stereo": ("polar_stereo", ("_stere_north_south",)),
           "pixel_mesh": ("ground.dem.pixel_mesh", ("corridor_cells", "split_mesh"))}

#: each stage's name on :func:`compile_kernels`' bar and its rough compile time [s], in the
#: order they compile; ``_<stage>`` (below) runs a stage's kernels once
STAGE_BAR = {"detector": ("the detector", DETECTOR_S),
             "heights": ("the DEM footprint means", HEIGHTS_S),
             "geodesic": ("the geodesics", GEODESIC_S),
             "classify": ("the histogram test", CLASSIFY_S),
             "draws": ("the detector's draws", DRAWS_S),
             "polar_stereo": ("the polar stereographic projection", POLAR_STEREO_S),
             "pixel_mesh": ("the DEM's corridor tiles", PIXEL_MESH_S),
             "atl06": ("the ATL06 fit", ATL06_S),
             "atl03": ("the ATL03 fields", ATL03_S),
             "h5": ("the HDF5 chunks' shuffle", H5_S)}
#: the stages :func:`compile_kernels` compiles only when asked (its ``atl06``, ``atl03``)
_ASKED = ("atl06", "atl03")


def _detector() -> None:
    from .detector import pmt
    from .instrument import Instrument
    from .detector.records import Returns
    t0 = 3.3e6
    ret = Returns.at_times(np.full(64 * 4, t0), paths_per_shot=64)
    pmt.detect(ret, Instrument(background_mhz=1.0), np.random.default_rng(0),
               gate_center_ns=np.full(4, t0))
    pmt.paralyzable_mask(np.zeros(3, np.int64), np.arange(3.0), 3.0)


def _heights() -> None:
    from .ground.dem import heights
    heights._axis_weights(np.zeros(1), posting_m=1.0, sigma_m=0.5)
    a = np.full((1, 2), 0.5)
    heights._stencil_sums(np.zeros((2, 2)), np.zeros(1, np.int64), np.zeros(1, np.int64), a, a,
                          np.empty(1), np.empty(1))
    heights.bilinear_nan(np.zeros((3, 3)), 1.0, np.ones(1), np.ones(1))
    heights._on_grid(np.ones(1), np.ones(1), np.zeros((1, 2)), 1.0, 3, 3)
    heights.block_extents(np.ones(1), np.ones(1), 1)


def _geodesic() -> None:
    from . import geodesic
    geodesic._proj()          # its check against pyproj runs the kernel


def _classify() -> None:
    from .products import classify
    classify.histogram_test(shot=np.zeros(2, np.int64), h_m=np.zeros(2),
                            gate_center_h_m=np.zeros(1), range_gate_m=30.0)


def _draws() -> None:
    from .detector import draws
    draws._compiled_ok()      # its check against numpy runs the kernel


def _polar_stereo() -> None:
    from . import polar_stereo
    polar_stereo._stere_north_south(np.zeros(1), np.full(1, 70.0), False, 0.0, 1.9, 0.08,
                                    6378137.0, 0.0, 0.0, np.empty(1), np.empty(1))


def _pixel_mesh() -> None:
    from .ground.dem import pixel_mesh
    z = np.zeros((3, 3))
    i, j, _, _ = pixel_mesh.corridor_cells(z, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0,
                                           0.0, 1.0, -5.0, 5.0, -5.0, 5.0)
    pixel_mesh.split_mesh(i, j, 1, z, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def _atl06() -> None:
    from .products import atl06
    n = 2000
    along = np.arange(n) * 0.7
    atl06.fit_segments(photon_along_m=along, h_m=np.zeros(n), shot=np.arange(n),
                       channel=np.zeros(n, np.int16), n_shots=n, shot_along_m=along,
                       n_channels=16, dead_time_ns=3.0, paralyzable=False, pulse_sigma_ns=0.42,
                       range_gate_m=30.0, z_ref_m=np.zeros(n), engine="compiled")


def _atl03() -> None:
    from .products.atl03 import kernels
    kernels.ph_id_count(np.zeros(2, np.int64), np.zeros(2, np.int16), np.empty(2, np.uint8))


def _h5() -> None:
    from .products import h5kernels
    for size in h5kernels.SIZES:        # (each size's loop, and the byte loop)
        for n in (size, 1):
            h5kernels.shuffle(np.zeros(n * size, np.uint8), size, np.empty(n * size, np.uint8))


def is_cached(stage: str) -> bool:
    """Whether numba's cache holds every kernel of ``stage`` (a :data:`KERNELS` key)."""
    return _cached(*KERNELS[stage])


def _cached(module: str, functions: tuple[str, ...]) -> bool:
    """Whether numba's cache beside the package holds the index of each of ``functions`` of
    ``module`` as the code stands (numba names it ``module.function-LINE.pyXY.nbi``, LINE the
    function's first line): a missing one means a compile."""
    from importlib import import_module
    mod = import_module(f"lidar_mitsuba.{module}")
    cache = pathlib.Path(mod.__file__).parent / "__pycache__"
    tag = f"py{sys.version_info.major}{sys.version_info.minor}"
    for fn in functions:
        line = getattr(mod, fn).py_func.__code__.co_firstlineno
        if not (cache / f"{pathlib.Path(mod.__file__).stem}.{fn}-{line}.{tag}.nbi").exists():
            return False
    return True


def _compiling(i: int, steps: list) -> str:
    """The compile bar's words while step ``i`` of ``steps`` compiles (one short line: a long
    one wraps, and a terminal then repeats it at every refresh)."""
    return f"compiling kernels {i + 1}/{len(steps)} ({steps[i][0]}), once per machine"


def compile_kernels(*, atl06: bool = False, atl03: bool = False, progress: bool = True
                    ) -> float:
    """Compile the detector's kernels (and, with ``atl06``, the compiled ATL06 fit; with
    ``atl03``, ATL03's per-photon fields) if they are not cached yet; returns the seconds it
    took. With ``progress``, a bar on stderr names the stage compiling (one short line:
    :func:`_compiling`) and moves every half second."""
    wanted = [stage for stage in STAGE_BAR if stage not in _ASKED
              or (atl06 if stage == "atl06" else atl03)]
    steps = [(*STAGE_BAR[stage], globals()[f"_{stage}"]) for stage in wanted
             if not is_cached(stage)]
    if not steps:
        return 0.0
    t0 = time.perf_counter()
    errors: list[BaseException] = []

    current = [0]                           # the step compiling now (the bar names it)

    def work():
        try:
            for i, (_, _, fn) in enumerate(steps):
                current[0] = i
                fn()
        except BaseException as e:          # raised again in the caller's thread
            errors.append(e)

    worker = threading.Thread(target=work, name="lidar-compile", daemon=True)
    worker.start()
    bar = None
    if progress:
        from tqdm.auto import tqdm
        total = sum(s for _, s, _ in steps)
        bar = tqdm(total=round(total), unit="s", file=sys.stderr, leave=False,
                   desc=_compiling(0, steps), bar_format="{desc}: {elapsed} of ~{total}s")
    while worker.is_alive():
        worker.join(0.5)
        if bar is not None:           # one short line (a long one wraps and repeats)
            bar.set_description_str(_compiling(current[0], steps), refresh=False)
            bar.n = min(round(time.perf_counter() - t0), bar.total)
            bar.refresh()
    if bar is not None:
        bar.close()
    if errors:
        raise errors[0]
    return time.perf_counter() - t0


def start_numba() -> bool:
    """numba's first dispatch, on this thread: its CPU target (type registries, a BLAS check
    that imports ``scipy.linalg``, cffi: ~0.3 s of CPU, once a process) and the detector's
    :func:`~lidar_mitsuba.detector.deadtime.shot_stats` from numba's cache. Returns whether
    it ran: not when that kernel is not cached yet (a first run compiles it, with
    :func:`compile_kernels`' bar). The writer process's fork calls it first
    (:mod:`lidar_mitsuba.granule_writer`), so that the child inherits it; serial kernels
    only: numba's threading layer stays down (a fork needs it down)."""
    if not _cached(KERNELS["detector"][0], ("shot_stats",)):
        return False
    from .detector import deadtime
    deadtime.shot_stats(np.zeros(1, np.uint32), np.ones(1, np.float32), 1)
    return True


#: the process in which :func:`load_kernels` ran (a forked child runs it again)
_LOADED_PID: list = [None]


def load_kernels() -> threading.Thread | None:
    """Start loading, on a thread of its own, what a process's first granule would otherwise
    load on the simulating thread: numba's CPU target (its type registries, a BLAS check that
    imports ``scipy.linalg``, cffi: ~0.4-0.6 s of CPU, once a process) and the first serial
    kernels it calls (the detector's :func:`~lidar_mitsuba.detector.deadtime.shot_stats`, the
    footprint means' stencil sums), from numba's cache (the first two already loaded where
    the writer process was forked: :func:`start_numba` ran before the fork); then the
    imports of rasterio and pyproj (~0.25 s of CPU), which the DEM's opening and the first
    plan's geodesics would otherwise pay on the simulating thread. Call it before the
    renderer's set-up, which under load mostly waits with the GIL released (libLLVM, the
    variant's libraries: measured, a spinning Python thread beside it ran for 1.65 s of its
    2.05 s), so the two overlap; on an idle core the set-up does not wait (0.30 s of wall
    for 0.29 s of CPU) and the two take turns (docs/guide/campaigns.md, "Cold start").

    Returns the started thread, or ``None`` when it already ran in this process or a kernel is
    not cached yet (then the first run compiles it: :func:`compile_kernels`). The detector's
    parallel kernels are left to their first call, on the simulating thread: numba's
    ``workqueue`` threading layer (where OpenMP and TBB are missing) refuses parallel regions
    launched from two threads at once."""
    if _LOADED_PID[0] == os.getpid():
        return None
    _LOADED_PID[0] = os.getpid()
    if not (_cached(KERNELS["detector"][0], ("shot_stats",)) and is_cached("heights")):
        return None

    def load():
        start_numba()
        _heights()
        # the simulating thread's other kernels (the geodesics' also find PROJ's functions
        # and check them), each from the cache
        for stage, warm in (("geodesic", _geodesic), ("classify", _classify),
                            ("draws", _draws), ("polar_stereo", _polar_stereo),
                            ("pixel_mesh", _pixel_mesh)):
            if is_cached(stage):
                warm()
        import pyproj, rasterio  # noqa: E401, F401 (after the writer's fork: forking.refusal)

    loader = threading.Thread(target=load, name="lidar-kernels", daemon=True)
    loader.start()
    return loader
