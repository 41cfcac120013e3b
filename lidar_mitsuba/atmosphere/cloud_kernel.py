"""A cloud's effect on the ground's return, tabulated once from the media integrator and
applied to any run's returns at the cost of a few numpy passes.

**The table** (:func:`table`). The ``mediapathlength`` integrator traces the cloud (a
homogeneous layer, Henyey-Greenstein phase, the run's footprint, field of view and range)
over a flat Lambertian 0.9 plate, with a zero-width pulse. Per traced path (weights: the
plate in clear air is 1):

* ``direct``: the ground's unscattered light, exp(-2 tau) by Beer-Lambert (traced, and
  checked against it: ``traced_direct``);
* ``forward``: the ground's light that was scattered in the cloud, on the way down, the way
  up or both, and still reaches the receiver from its field of view: its mean weight and the
  quantile function of its delay (late by ``delay``: the surface appears ``c delay / 2``
  lower). Only light that appears at or below the ground counts (the cloud's own backscatter
  above it is the closed form's, :meth:`~.cloud_layer.Cloud.backscatter_weight`).

Tables are kept in memory per cloud and geometry (:func:`table` is cached).

**Applied to a run** (:class:`CloudSource`): every traced return of weight ``w`` (any
surface, any BSDF, snow) becomes, with probability ``q = F / (D + F)`` (D = exp(-2 tau),
F = ``forward``), a forward-scattered one delayed by a draw from the table, and its weight
is ``w (D + F)``. Each path stays one iid return (the detector's draws need that), the mean
return is ``D`` times the clear one plus ``F`` times the clear one delayed: exact for a flat
ground; where the ground's height changes within the field of view (the forward-scattered
light lands up to the field of view's radius away) it is the flat ground's delay. Where the
cloud lies inside the range gate, each path's return also carries the cloud's own
backscatter in the gate (``B`` per path, the closed form), drawn with probability
``B / (w (D + F) + B)`` at a height drawn from the layer's return profile, with the pulse's
spread.

Where the cheap kernel is enough is charted by
:func:`lidar_mitsuba.studies.cloud.kernel_vs_full`: the kernel against the full trace of the
same cloud over the same plate (docs/guide/clouds.md).
"""
from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass

import numpy as np

from ..constants import C_M_PER_NS
from .cloud_layer import Cloud

_CLOUD_STREAM = 0x434C4F          # 'CLO': the kernel's draws apart from tracer and detector
LEVELS = 1025
"""Quantile levels of the delay table (evenly spaced in [0, 1], both ends included)."""
SHOTS, PATHS = 2000, 128
"""Shots and paths per shot a table traces (256 000 paths: the forward part of a tau = 1
cloud 1 km up, ~2 % of the ground's light, to ~4 % of itself)."""
MAX_DEPTH = 8
"""Vertices per path the table's trace follows (as trace.materials.AIR_DEPTH)."""


@dataclass(frozen=True)
class CloudTable:
    """A cloud's effect on a flat ground's return, per path (plate in clear air = 1).

    Attributes:
        direct: exp(-2 tau), the unscattered part (closed form, used).
        traced_direct, traced_direct_se: the same traced, and its standard error over shots.
        forward, forward_se: the forward-scattered part in the field of view and its SE.
        delay_ns: (LEVELS,) quantiles of the forward-scattered light's delay [ns].
        mean_delay_ns: its weighted mean [ns]; window_m: the heights below the ground
            it holds [m]; shots, paths_per_shot, seconds: the trace's size and cost.
    """
    direct: float
    traced_direct: float
    traced_direct_se: float
    forward: float
    forward_se: float
    delay_ns: np.ndarray
    mean_delay_ns: float
    window_m: float
    shots: int
    paths_per_shot: int
    seconds: float

    @property
    def total(self) -> float:
        """D + F: the ground's light reaching the receiver relative to clear sky."""
        return self.direct + self.forward

    @property
    def forward_probability(self) -> float:
        return self.forward / self.total if self.total > 0 else 0.0

    def draw_delay_ns(self, u: np.ndarray) -> np.ndarray:
        """Delays [ns] at uniforms ``u`` (the quantile function, linear between levels)."""
        return np.interp(u, np.linspace(0.0, 1.0, self.delay_ns.size), self.delay_ns)

    def summary(self) -> dict:
        return {"direct": self.direct, "traced_direct": self.traced_direct,
                "traced_direct_se": self.traced_direct_se, "forward": self.forward,
                "forward_se": self.forward_se, "mean_delay_ns": self.mean_delay_ns,
                "mean_lowering_m": C_M_PER_NS * self.mean_delay_ns / 2,
                "shots": self.shots, "paths_per_shot": self.paths_per_shot,
                "seconds": self.seconds}


def layer_scene_dict(cloud: Cloud, *, ground_albedo: float = 0.9) -> dict:
    """A Lambertian plate at z = 0 under ``cloud`` (a ``null``-bounded box, wide enough that
    light leaving it sideways cannot come back into the field of view)."""
    from ..trace.lazy import mi
    T = mi.ScalarTransform4f
    half = max(5000.0, 4.0 * cloud.top_m)
    d = {"type": "scene",
         "ground": {"type": "rectangle", "to_world": T().scale([half, half, 1]),
                    "bsdf": {"type": "diffuse",
                             "reflectance": {"type": "uniform", "value": ground_albedo}}}}
    if not cloud.clear:
        h = cloud.thickness_m
        d["layer"] = {"type": "cube", "bsdf": {"type": "null"},
                      "to_world": T().translate([0, 0, (cloud.base_m + cloud.top_m) / 2])
                      .scale([0.96 * half, 0.96 * half, h / 2]),
                      "interior": {"type": "homogeneous", "sigma_t": cloud.extinction_per_m,
                                   "albedo": cloud.single_scattering_albedo,
                                   "phase": {"type": "hg", "g": cloud.g}}}
    return d


def trace_plate(cloud: Cloud, *, altitude_m: float, footprint_sigma_m: float,
                fov_radius_m: float, shots: int, paths_per_shot: int, seed: int,
                pulse_sigma_ns: float = 0.0, max_depth: int = MAX_DEPTH):
    """The full media trace of ``cloud`` over the 0.9 plate: ``(returns, apparent height
    [m] of each return)``."""
    from ..trace.lazy import mi
    from ..trace.variant import ensure_renderer
    ensure_renderer()
    integ = mi.load_dict({"type": "mediapathlength", "max_depth": int(max_depth),
                          "altitude_m": float(altitude_m),
                          "footprint_sigma_m": float(footprint_sigma_m),
                          "fov_radius_m": float(fov_radius_m),
                          "pulse_sigma_ns": float(pulse_sigma_ns)})
    r = integ.trace(mi.load_dict(layer_scene_dict(cloud)), shot_x_m=np.zeros(shots),
                    shot_y_m=np.zeros(shots), paths_per_shot=int(paths_per_shot),
                    seed=int(seed))
    h = altitude_m - C_M_PER_NS * np.asarray(r.time_ns, np.float64) / 2.0
    return r, h


def _per_shot(r, keep) -> tuple[float, float]:
    w = np.bincount(np.asarray(r.shot)[keep], weights=np.asarray(r.weight, np.float64)[keep],
                    minlength=r.n_shots) / r.paths_per_shot
    return float(w.mean()), float(w.std(ddof=1) / math.sqrt(r.n_shots))


def split(r, h: np.ndarray, *, window_m: float) -> dict:
    """The ground's unscattered returns (first vertex, on the plate) and its scattered ones
    (every later vertex whose light appears within ``window_m`` of the ground: scattered on
    the way down, up, or in the layer many times), with their weights per path and SEs over
    shots, and the scattered ones' delays [ns] (negative: above the ground)."""
    z, first = np.asarray(r.z_m), np.asarray(r.depth) == 1
    direct = first & (z < 1.0)
    # the rest in the window around the ground, but the layer's single scattering (its
    # first vertex in the layer: the closed form's, Cloud.backscatter_weight)
    fwd = ~first & (np.abs(h) <= window_m)
    d, d_se = _per_shot(r, direct)
    f, f_se = _per_shot(r, fwd)
    return {"direct": d, "direct_se": d_se, "forward": f, "forward_se": f_se,
            "delay_ns": -2.0 * h[fwd] / C_M_PER_NS,
            "delay_weight": np.asarray(r.weight, np.float64)[fwd]}


@functools.lru_cache(maxsize=64)
def table(cloud: Cloud, *, altitude_m: float, footprint_sigma_m: float, fov_radius_m: float,
          window_m: float = 100.0, shots: int = SHOTS, paths_per_shot: int = PATHS,
          seed: int = 0) -> CloudTable:
    """The :class:`CloudTable` of ``cloud`` for a lidar at ``altitude_m`` with this footprint
    and field of view (traced once per process and geometry; cached)."""
    from ..ground.snow.kernel import weighted_quantile_at
    t0 = time.perf_counter()
    r, h = trace_plate(cloud, altitude_m=altitude_m, footprint_sigma_m=footprint_sigma_m,
                       fov_radius_m=fov_radius_m, shots=shots, paths_per_shot=paths_per_shot,
                       seed=seed)
    s = split(r, h, window_m=window_m)
    if s["delay_ns"].size:
        q = weighted_quantile_at(s["delay_ns"], s["delay_weight"], np.linspace(0, 1, LEVELS))
        mean = float(np.average(s["delay_ns"], weights=s["delay_weight"]))
    else:
        q, mean = np.zeros(LEVELS), 0.0
    return CloudTable(direct=cloud.two_way_transmission, traced_direct=s["direct"],
                      traced_direct_se=s["direct_se"], forward=s["forward"],
                      forward_se=s["forward_se"], delay_ns=np.asarray(q, np.float64),
                      mean_delay_ns=mean, window_m=float(window_m), shots=int(shots),
                      paths_per_shot=int(paths_per_shot), seconds=time.perf_counter() - t0)


def table_for(cloud: Cloud, instrument, **kw) -> CloudTable:
    """:func:`table` at ``instrument``'s geometry (an :class:`~lidar_mitsuba.instrument.Instrument`)."""
    kw = {"shots": SHOTS, "paths_per_shot": PATHS, **kw}      # (the module's, when called)
    return table(cloud, altitude_m=float(instrument.altitude_m),
                 footprint_sigma_m=float(instrument.footprint_sigma_m),
                 fov_radius_m=float(instrument.fov_diameter_m / 2),
                 window_m=max(100.0, float(instrument.range_gate_m)), **kw)


def apply(ret, cloud: Cloud, tab: CloudTable, *, instrument, gate_center_ns: np.ndarray,
          rng: np.random.Generator):
    """``ret`` (:class:`~lidar_mitsuba.detector.records.Returns` of a clear-sky trace, local
    shot indices) under ``cloud`` (the module's text). ``gate_center_ns``: (n_shots,) each
    shot's gate centre, the round-trip time of its reference surface [ns]."""
    n = len(ret)
    if n == 0:
        return ret
    w = np.asarray(ret.weight, np.float64) * tab.total
    t = np.asarray(ret.time_ns, np.float64).copy()
    z = np.asarray(ret.z_m, np.float32).copy()
    u = rng.random(n)
    fwd = u < tab.forward_probability
    t[fwd] += tab.draw_delay_ns(rng.random(int(fwd.sum())))
    lo, hi = (-instrument.range_gate_m / 2.0, instrument.range_gate_m / 2.0)
    b = cloud.backscatter_weight(lo, hi)
    if b > 0:
        shot = np.asarray(ret.shot, np.int64)
        per_return = b * ret.paths_per_shot / np.bincount(shot, minlength=ret.n_shots)[shot]
        own = rng.random(n) * (w + per_return) < per_return
        k = int(own.sum())
        hgt = cloud.backscatter_heights_m(rng.random(k), lo, hi)
        t[own] = (np.asarray(gate_center_ns, np.float64)[shot[own]] - 2.0 * hgt / C_M_PER_NS
                  + instrument.pulse_sigma_ns * rng.standard_normal(k))
        z[own] = np.asarray(ret.z_m, np.float32)[own] + hgt.astype(np.float32)
        w = w + per_return
    return dataclasses.replace(ret, weight=w.astype(np.float32), time_ns=t, z_m=z)


class CloudSource:
    """``source`` (a chunk source of :mod:`lidar_mitsuba.trace.stream`) under ``cloud``: each
    chunk's returns go through :func:`apply` with a generator seeded by the chunk's trace
    seed (same seed, same photons)."""

    def __init__(self, source, cloud: Cloud, tab: CloudTable, *, instrument,
                 gate_center_ns: np.ndarray):
        self.source, self.cloud, self.table = source, cloud, tab
        self.instrument, self.center = instrument, np.asarray(gate_center_ns)

    def launch(self, a: int, b: int, seed: int):
        launch = getattr(self.source, "launch", None)
        pending = launch(a, b, seed) if launch is not None else _Ready(self.source(a, b, seed))
        return _Clouded(pending, self, self.center[a:b], seed)

    def __call__(self, a: int, b: int, seed: int):
        return self.launch(a, b, seed).result()


class _Ready:
    def __init__(self, returns):
        self.returns = returns

    def result(self):
        return self.returns


class _Clouded:
    def __init__(self, pending, src: CloudSource, center, seed: int):
        self.pending, self.src, self.center, self.seed = pending, src, center, seed

    def result(self):
        src = self.src
        rng = np.random.default_rng([int(self.seed), _CLOUD_STREAM])
        return apply(self.pending.result(), src.cloud, src.table, instrument=src.instrument,
                     gate_center_ns=self.center, rng=rng)
