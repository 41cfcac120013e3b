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

from . import pmt
from .constants import C_M_PER_NS
from .instrument import Instrument
from .photons import Detections, Returns

CHUNK_SHOTS = 65536
"""Default shots per chunk."""
_DETECTOR_STREAM = 0x504D54         # 'PMT': keeps the detector's stream apart from the tracer's

#: ``source(first_shot, stop_shot, trace_seed) -> Returns`` of those shots (local shot indices)
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


def traced(integrator, scene, *, x_m: np.ndarray, y_m: np.ndarray, paths_per_shot: int,
           dx_m: np.ndarray | None = None, dy_m: np.ndarray | None = None,
           dz_m: np.ndarray | None = None) -> Source:
    """A source that traces shots at (``x_m``, ``y_m``) [m] in ``scene`` with ``integrator``;
    when the positions were folded into a tile, ``dx_m``/``dy_m``/``dz_m`` (n_shots,) move the
    returns back to the track (:meth:`Returns.moved`)."""
    def source(a: int, b: int, seed: int) -> Returns:
        ret = integrator.trace(scene, shot_x_m=x_m[a:b], shot_y_m=y_m[a:b],
                               paths_per_shot=int(paths_per_shot), seed=seed)
        if dx_m is None and dy_m is None and dz_m is None:
            return ret
        zero = np.zeros(b - a)
        return ret.moved(dx_m=zero if dx_m is None else dx_m[a:b],
                         dy_m=zero if dy_m is None else dy_m[a:b],
                         dz_m=zero if dz_m is None else dz_m[a:b])
    return source


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
        timings_s: ``trace_s`` and ``detect_s``, wall time of tracing and of detecting [s].
    """
    detections: dict[str, Detections]
    returns: Returns | None
    n_returns: int
    timings_s: dict = field(default_factory=dict)


def run(*, source: Source, detectors: Mapping[str, Instrument], z_ref_m: np.ndarray,
        seed: int, chunk_shots: int = CHUNK_SHOTS, keep_returns: bool = False,
        progress: bool = False) -> ChunkedRun:
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
    try:
        for k, a in enumerate(range(0, n_shots, per)):
            b = min(n_shots, a + per)
            t0 = time.perf_counter()
            ret = source(a, b, trace_seed(seed, k))
            t1 = time.perf_counter()
            for name, inst in detectors.items():
                det = pmt.detect(ret, inst, detector_rng(seed, k),
                                 gate_center_ns=gates[name][a:b])
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
    dets = {name: Detections.concatenate(p) for name, p in parts.items()}
    returns = Returns.concatenate(kept, n_shots=n_shots) if keep_returns else None
    return ChunkedRun(detections=dets, returns=returns, n_returns=n_returns,
                      timings_s={"trace_s": trace_s, "detect_s": detect_s})


def _progress_bar(total: int, enabled: bool):
    if not enabled:
        return None
    from tqdm.auto import tqdm
    return tqdm(total=total, desc="simulating", unit="shot", delay=2.0, leave=False)
