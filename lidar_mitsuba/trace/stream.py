"""The trace -> detect chunk loop, with its seeding: the one place that turns a track into
detected photons chunk by chunk, so memory stays bounded by a chunk for any track length.

Chunk ``k`` of a run with ``seed`` traces with :func:`trace_seed` ``(seed, k)`` and detects
with the generator :func:`detector_rng` ``(seed, k)``. Every detector of a run sees the same
traced photons and the same detector stream, so two instruments that share a geometry differ
only by what the detector does (the studies use this to compare detectors on one trace), and
re-detecting kept returns with the same chunking gives exactly what a fresh run would.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from ..detector import pmt
from ..detector.deadtime import serial_while
from ..constants import C_M_PER_NS
from ..instrument import Instrument
from ..machine import trace_launcher
from ..detector.records import Detections, Returns

CHUNK_SHOTS = 65536
"""Default shots per chunk."""
_DETECTOR_STREAM = 0x504D54         # 'PMT': keeps the detector's stream apart from the tracer's

#: ``source(first_shot, stop_shot, trace_seed) -> Returns`` of those shots (local shot
#: indices); a source with a ``launch`` method of the same arguments returning an object
#: with ``result()`` (:class:`TracedSource`) lets :func:`run` overlap tracing and detecting
Source = Callable[[int, int, int], Returns]


def trace_seed(seed: int, chunk: int) -> int:
    """The integrator's seed for chunk ``chunk`` of a run seeded ``seed``."""
    return int(np.random.SeedSequence([int(seed), int(chunk)]).generate_state(1)[0])


def detector_rng(seed: int, chunk: int) -> np.random.Generator:
    """The detector's random generator for chunk ``chunk`` of a run seeded ``seed``."""
    return np.random.default_rng([int(seed), _DETECTOR_STREAM, int(chunk)])


def gate_heights_m(z_ref_m: np.ndarray) -> np.ndarray:
    """(n_shots,) height [m] the range gate of each shot is centred on: its reference
    elevation; for shots with no surface under them (NaN), interpolated along the track from
    the shots that have one (the nearest end's beyond them; 0 when no shot has one), so that
    their gates still record noise."""
    z = np.asarray(z_ref_m, np.float64)
    ok = np.isfinite(z)
    if ok.all():
        return z
    if not ok.any():
        return np.zeros_like(z)
    i = np.arange(z.size)
    return np.interp(i, i[ok], z[ok])


def gate_center_ns(instrument: Instrument, z_ref_m: np.ndarray) -> np.ndarray:
    """(n_shots,) round-trip time [ns] of the height each shot's range gate is centred on
    (:func:`gate_heights_m`)."""
    return 2.0 * (instrument.altitude_m - gate_heights_m(z_ref_m)) / C_M_PER_NS


class TracedSource:
    """A source that traces shots at (``x_m``, ``y_m``) [m] in ``scene`` with ``integrator``;
    when the positions were folded into a tile, ``dx_m``/``dy_m``/``dz_m`` (n_shots,) move the
    returns back to the track (on the device: the integrator's ``offset_m``).

    Besides being called, it can :meth:`launch` a chunk and hand back a pending trace, which
    :func:`run` uses to trace the next chunk while the host detects the last one."""

    def __init__(self, integrator, scene, *, x_m: np.ndarray, y_m: np.ndarray,
                 paths_per_shot: int, dx_m: np.ndarray | None = None,
                 dy_m: np.ndarray | None = None, dz_m: np.ndarray | None = None):
        self.integrator, self.scene = integrator, scene
        self.x_m, self.y_m, self.paths_per_shot = x_m, y_m, int(paths_per_shot)
        shifts = (dx_m, dy_m, dz_m)
        self.offsets = None
        if any(d is not None for d in shifts):
            zero = np.zeros(np.asarray(x_m).shape)
            self.offsets = tuple(zero if d is None else np.asarray(d, np.float64)
                                 for d in shifts)

    def launch(self, a: int, b: int, seed: int):
        """Start tracing shots ``a`` .. ``b - 1`` (local shot indices in the result)."""
        offset = None if self.offsets is None else tuple(d[a:b] for d in self.offsets)
        return self.integrator.launch(self.scene, shot_x_m=self.x_m[a:b],
                                      shot_y_m=self.y_m[a:b],
                                      paths_per_shot=self.paths_per_shot, seed=seed,
                                      offset_m=offset)

    def __call__(self, a: int, b: int, seed: int) -> Returns:
        return self.launch(a, b, seed).result()


#: ``chunks.traced(integrator, scene, x_m=..., y_m=..., paths_per_shot=...)``: the traced source
traced = TracedSource


class TiledSource:
    """A source over a surface's :class:`~lidar_mitsuba.ground.tiling.Tiling`: each chunk is
    traced in the scene the tiling gives it (one scene for every chunk, or a DEM's corridor
    tile per chunk), its returns put back on the track on the device (the integrator's
    ``offset_m``)."""

    def __init__(self, integrator, tiling, *, paths_per_shot: int):
        self.integrator, self.tiling, self.paths_per_shot = integrator, tiling, int(paths_per_shot)
        self._prepared: dict = {}       # (a, b) -> the tiling's prepare(a, b), until launched

    def prepare(self, a: int, b: int) -> None:
        """Do now, on this thread, the numpy part of shots ``a`` .. ``b - 1``'s tile (a
        corridor tile's mesh: :meth:`~lidar_mitsuba.ground.dem.CorridorTiles.prepare`; a
        tiling without one has nothing to do) for their :meth:`launch` to take, maybe on
        another thread: a granule's stream meshes the next tile while the trace launcher
        traces this one. (Not the scene: built on this thread while the launcher's kernel
        runs, both wait for each other, ~2x the trace and ~10x the build.)"""
        prepare = getattr(self.tiling, "prepare", None)
        if prepare is not None:
            self._prepared[(a, b)] = prepare(a, b)

    def launch(self, a: int, b: int, seed: int):
        scene, x_local, y_local, offsets = self.tiling.tile(a, b,
                                                            self._prepared.pop((a, b), None))
        return self.integrator.launch(scene, shot_x_m=x_local, shot_y_m=y_local,
                                      paths_per_shot=self.paths_per_shot, seed=seed,
                                      offset_m=offsets)

    def __call__(self, a: int, b: int, seed: int) -> Returns:
        return self.launch(a, b, seed).result()


class GatedSource:
    """``source`` with each shot's returns outside its range gate dropped before detection
    (``gate_center_ns``: (n_shots,) gate centres, ``gate_ns`` its width, as the detector's).
    The detector loses them anyway: dropping them first thins the Poisson arrivals the same
    way (the same distribution of detections), and a layer in the air far above the ground
    no longer sets the track's largest weight, with which the detector's rejection sampling
    picks its photons. Used for scenes with layers in the air."""

    def __init__(self, source, *, gate_center_ns: np.ndarray, gate_ns: float):
        self.source, self.center, self.half = source, np.asarray(gate_center_ns), gate_ns / 2
        if hasattr(source, "prepare"):          # (TiledSource.prepare: the mesh made ahead)
            self.prepare = source.prepare

    def launch(self, a: int, b: int, seed: int):
        return _Gated(self.source.launch(a, b, seed), self.center[a:b], self.half)

    def __call__(self, a: int, b: int, seed: int) -> Returns:
        return self.launch(a, b, seed).result()


class _Gated:
    def __init__(self, pending, center, half):
        self.pending, self.center, self.half = pending, center, half

    def result(self) -> Returns:
        ret = self.pending.result()
        return ret.select(np.flatnonzero(in_gate(ret.shot, ret.time_ns, self.center,
                                                 self.half)))


def in_gate(shot: np.ndarray, time_ns: np.ndarray, center_ns: np.ndarray,
            half_ns: float) -> np.ndarray:
    """(n,) bool: returns whose time is within ``half_ns`` of their shot's gate centre."""
    return np.abs(np.asarray(time_ns) - np.asarray(center_ns)[np.asarray(shot)]) <= half_ns


def replayed(returns: Returns) -> Source:
    """A source that hands out the kept returns of an earlier run (no tracing)."""
    return lambda a, b, _seed: returns.slice_shots(a, b)


@dataclass
class ChunkedRun:
    """What :func:`run` produced.

    Attributes:
        detections: detector name -> its :class:`Detections` over the whole track.
        returns: every traced return (global shot indices), or ``None`` when not kept.
        n_returns: traced returns in all.
        timings_s: ``trace_s`` and ``detect_s``, wall time [s] the host spent waiting for
            and fetching traces (including launching the next chunk) and detecting; on a
            CUDA device the next chunk is traced while the host detects.
    """
    detections: dict[str, Detections]
    returns: Returns | None
    n_returns: int
    timings_s: dict = field(default_factory=dict)


def run(*, source: Source, detectors: Mapping[str, Instrument], z_ref_m: np.ndarray,
        seed: int, chunk_shots: int = CHUNK_SHOTS, keep_returns: bool = False,
        progress: bool = False,
        detector_inputs: Callable[[int, int], dict] | None = None) -> ChunkedRun:
    """Trace and detect a track in chunks of ``chunk_shots`` shots.

    Args:
        source: gives the returns of a chunk (:func:`traced`, :func:`replayed`).
        detectors: name -> instrument; all must share the traced geometry. Each detects every
            chunk with the chunk's detector stream, inside its range gate around ``z_ref_m``.
        z_ref_m: (n_shots,) reference elevation of each shot [m] (centres the range gate;
            NaN where there is no surface: see :func:`gate_heights_m`).
        seed: the run's seed (see the module docstring).
        chunk_shots: shots per chunk.
        keep_returns: keep every traced return in ``ChunkedRun.returns``.
        progress: show a progress bar on runs longer than ~2 s.
        detector_inputs: ``detector_inputs(a, b)`` gives ``pmt.detect``'s per-shot keywords
            (``signal_scale``, ``background_mhz``) for shots ``a`` .. ``b - 1``
            (:meth:`lidar_mitsuba.radiometry.ShotRadiometry.detector_inputs`), or ``None``.
    """
    n_shots = int(np.asarray(z_ref_m).size)
    if not (isinstance(chunk_shots, (int, np.integer)) and chunk_shots >= 1):
        raise ValueError(f"chunk_shots must be an integer >= 1 (got {chunk_shots!r})")
    per = int(chunk_shots)
    gates = {name: gate_center_ns(inst, z_ref_m) for name, inst in detectors.items()}
    parts: dict[str, list] = {name: [] for name in detectors}
    kept: list[tuple[Returns, int]] = []
    n_returns = 0
    trace_s = detect_s = 0.0
    bar = _progress_bar(n_shots, progress)
    spans = [(k, a, min(n_shots, a + per)) for k, a in enumerate(range(0, n_shots, per))]
    # granule: a granule's sections (its one-thread trace on the launcher, the detector
    # always on this thread alone); prepare: a chunk's numpy part done here, ahead
    launch, granule, prepare = _launching(source)
    pending = None
    with serial_while(granule):        # (a granule's whole run on this thread alone)
        try:
            pending = launch(spans[0][1], spans[0][2], trace_seed(seed, 0)) if spans else None
            for i, (k, a, b) in enumerate(spans):
                t0 = time.perf_counter()
                if prepare is not None and i + 1 < len(spans):
                    # the next chunk's mesh made here while the launcher traces this one
                    # (this thread would only wait: the trace is the longer of the two)
                    prepare(spans[i + 1][1], spans[i + 1][2])
                ret = pending.result()
                pending = None        # its scene (a corridor tile) may go before the next's
                if i + 1 < len(spans):    # the device traces the next chunk while we detect
                    k1, a1, b1 = spans[i + 1]
                    pending = launch(a1, b1, trace_seed(seed, k1))
                t1 = time.perf_counter()
                per_shot = {} if detector_inputs is None else detector_inputs(a, b)
                # serial while the next chunk traces, and in a granule on every chunk (set
                # once, above): the writer process and the next section hold the other core,
                # and a parallel region whose second thread is not scheduled spins at its
                # barrier
                with serial_while(pending is not None and not granule):
                    for name, inst in detectors.items():
                        det = pmt.detect(ret, inst, detector_rng(seed, k),
                                         gate_center_ns=gates[name][a:b], **per_shot)
                        parts[name].append((det, a, n_returns))
                if keep_returns:
                    kept.append((ret, a))
                n_returns += len(ret)
                trace_s += t1 - t0
                detect_s += time.perf_counter() - t1
                if bar is not None:
                    bar.update(b - a)
        finally:
            if bar is not None:
                bar.close()
            if pending is not None and hasattr(pending, "exception"):
                pending.exception()    # (a trace still on the launcher thread: let it end)
    dets = {name: Detections.concatenate(p) for name, p in parts.items()}
    returns = Returns.concatenate(kept, n_shots=n_shots) if keep_returns else None
    return ChunkedRun(detections=dets, returns=returns, n_returns=n_returns,
                      timings_s={"trace_s": trace_s, "detect_s": detect_s})


def _launching(source):
    """``(launch, granule, prepare)`` for :func:`run`: how a chunk is launched (on the trace
    launcher thread when there is one: a granule's), whether it is a granule's, and the
    source's ``prepare`` (a granule's only, else ``None``)."""
    launch = getattr(source, "launch", None)
    if launch is None:
        return (lambda a, b, s: _Done(source(a, b, s))), False, None
    if (launcher := trace_launcher()) is not None:
        return _on(launcher, launch), True, getattr(source, "prepare", None)
    return launch, False, None


def _on(launcher, launch):
    """``launch`` whose trace is launched and fetched on the ``launcher`` thread (the same
    returns: each chunk's seed is its own)."""
    def later(a: int, b: int, seed: int):
        return launcher.submit(lambda: launch(a, b, seed).result())
    return later


class _Done:
    """An already finished trace (for sources that cannot launch asynchronously)."""

    def __init__(self, returns: Returns):
        self._returns = returns

    def result(self) -> Returns:
        return self._returns


def _progress_bar(total: int, enabled: bool):
    if not enabled:
        return None
    from tqdm.auto import tqdm
    return tqdm(total=total, desc="simulating", unit="shot", delay=2.0, leave=False)
