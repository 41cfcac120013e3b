"""``paths_per_shot="auto"``: trace as many photon paths per shot as the detector's sampling
needs, judged from a small scout trace. Pure numpy and scipy.

The detector (:func:`lidar_mitsuba.detector.pmt.sample_arrivals`) uses a shot's traced paths twice:

1. their mean weight ``m`` sets the shot's Poisson mean, ``mu = signal_photons * m``. With
   ``N`` paths its Monte Carlo noise adds ``lam * m * cv**2 / N`` of extra variance, as a
   fraction of the Poisson variance of the kept photon count (``lam = signal_photons *
   fill_factor * pde`` kept photons per unit weight, ``cv`` the coefficient of variation of a
   path's weight);
2. each kept photon is a *distinct* return, accepted with probability ``w / w_max``. A shot
   that needs more picks than its returns can give "runs out", and its extra photons are
   drawn with replacement (two photons on one path: a small first-photon-bias error).

The run's paths per shot is the smallest of :data:`LADDER` for which, over the scout's shots,
the expected fraction of shots that run out is at most :data:`RUN_OUT_MAX` and the mean extra
variance is at most :data:`EXTRA_VARIANCE_MAX`. On the default p = 1.8 snow, whose Ward
weights vary by a few per cent, this is 16 paths for the strong beam and 8 for the weak one
instead of 128: the trace, the run's largest cost, shrinks eight to sixteenfold while every
kept photon is still an iid draw from the traced return distribution. Both criteria use the
scout's largest weight for ``w_max``; the run counts the shots that actually ran out
(``Detections.run_out_shots``) and warns when they exceed ten times the target.
"""
from __future__ import annotations

import numpy as np
from scipy import special
from scipy.special import _ufuncs

from ..track import spread_shots
from .stream import gate_center_ns, in_gate

LADDER = (8, 16, 32, 64, 128, 256, 512, 1024)
"""Paths per shot ``auto`` chooses from (powers of two)."""
SCOUT_SHOTS = 256
"""Shots, spread along the track, of the scout trace."""
SCOUT_PATHS = 128
"""Paths per shot of the scout trace (the former fixed default)."""
SCOUT_SEED = 0x53434F5554       # fixed: a scene's choice does not depend on the run's seed
RUN_OUT_MAX = 1e-4
"""Largest expected fraction of shots whose picks run out of distinct returns."""
EXTRA_VARIANCE_MAX = 0.01
"""Largest Monte Carlo noise of the shots' Poisson means, as a fraction of the Poisson
variance of their kept photon counts."""


def shot_moments(shot: np.ndarray, weight: np.ndarray, depth: np.ndarray, *, n_shots: int,
                 paths_per_shot: int, max_depth: int = 1) -> dict:
    """Per-shot weight statistics of a scout trace (``Returns`` arrays, in any order).

    Args:
        shot, weight, depth: (n_returns,) the scout's returns.
        n_shots, paths_per_shot: the scout's shots and paths per shot.
        max_depth: returns a path can have: 1 for single bounce and for a snow volume (one
            record per photon, whatever its ``depth``), the integrator's ``max_depth`` for
            multiple bounces (one return per vertex).

    Returns:
        dict: (n_shots,) arrays ``m``, the mean weight per path, ``m1``, its first returns'
        share (``m`` for one return per path), and ``m2``, an upper bound on the mean squared
        weight per path; ``w_max``, the largest return weight. A path with several returns
        weighs ``W = w1 + ... + wD``, and the returns do not say which path they belong to;
        but every product in ``W**2 - sum(wd**2)`` has a factor from depth 2 or deeper and
        another of at most ``W <= D * w_max``, so ``W**2 <= sum(wd**2) + 2 D w_max (w2 + ...
        + wD)``: tight when the deeper returns are weak, as on terrain.
    """
    s = np.asarray(shot, np.int64)
    w = np.asarray(weight, np.float64)
    d = int(max_depth)
    w_max = float(np.max(w, initial=0.0))
    k = float(paths_per_shot)
    m = np.bincount(s, weights=w, minlength=n_shots) / k
    m2 = np.bincount(s, weights=w * w, minlength=n_shots) / k
    m1 = m
    if d > 1:
        deep = np.asarray(depth) > 1
        m_deep = np.bincount(s[deep], weights=w[deep], minlength=n_shots) / k
        m1 = m - m_deep
        m2 = m2 + 2.0 * d * w_max * m_deep
    return {"m": m, "m1": m1, "m2": m2, "w_max": w_max}


def run_out_probability(*, kept_mean: np.ndarray, slots: np.ndarray,
                        accept_p: np.ndarray) -> np.ndarray:
    """Per shot, the probability that ``K ~ Poisson(kept_mean)`` picks exceed the returns the
    rejection sampler accepts in one pass over the shot, bounded below by ``A ~
    Binomial(slots, accept_p)``: ``P(K > A)``, with ``K`` and ``A`` independent.

    With ``N`` paths, ``slots = N`` and ``accept_p = m1 / w_max`` (first returns only: deeper
    ones can only add acceptances). Two further approximations, both toward more paths:
    among sums of ``N`` independent Bernoullis of one mean, the binomial has the largest
    variance (the heaviest lower tail near the mean); and in the run ``K``'s mean is the
    shot's own traced weight, low exactly when ``A`` is, so the real ``K`` and ``A`` are
    positively correlated and run out less often than independent ones. With constant
    weights and one return per path all is exact: ``P(Poisson(kept_mean) > N)``.
    All arguments (n,) arrays; returns (n,).
    """
    lam = np.asarray(kept_mean, np.float64)
    n = np.asarray(slots, np.int64)
    p = np.clip(np.asarray(accept_p, np.float64), 0.0, 1.0)
    out = np.zeros(lam.shape)
    ok = (lam > 0) & (n > 0)
    if not ok.any():
        return out
    lam, n, p = lam[ok], n[ok], p[ok]
    # sum over a of P(A = a) P(K > a); P(K > a) is negligible beyond Poisson's far tail
    top = int(min(n.max(), poisson_isf(1e-16, float(lam.max())) + 1))
    a = np.arange(top + 1)[None, :]
    terms = binom_pmf(a, n[:, None], p[:, None]) * poisson_sf(a, lam[:, None])
    out[ok] = terms.sum(axis=1)
    return out


# scipy.stats' binomial and Poisson functions, from the scipy.special kernels they call:
# importing scipy.stats costs about 0.5 s of every run's start, these three functions need
# none of it. tests/test_path_budget.py checks them against scipy.stats to the bit.
def binom_pmf(k, n, p) -> np.ndarray:
    """``scipy.stats.binom.pmf(k, n, p)`` for integer ``k >= 0``, ``n >= 0`` and ``p`` in
    [0, 1] (broadcast): boost's pmf, 0 beyond ``n``, clipped to [0, 1]."""
    k, n, p = np.broadcast_arrays(np.asarray(k, np.float64), np.asarray(n, np.float64),
                                  np.asarray(p, np.float64))
    out = np.zeros(k.shape)
    inside = k <= n
    out[inside] = np.clip(_ufuncs._binom_pmf(k[inside], n[inside], p[inside]), 0.0, 1.0)
    return out


def poisson_sf(k, mu) -> np.ndarray:
    """``scipy.stats.poisson.sf(k, mu)`` for integer ``k >= 0`` and ``mu > 0``: ``P(K > k)``."""
    return np.clip(special.pdtrc(np.floor(np.asarray(k, np.float64)), mu), 0.0, 1.0)


def poisson_isf(q: float, mu: float) -> float:
    """``scipy.stats.poisson.isf(q, mu)`` for ``q`` in (0, 1) and ``mu > 0``: the least ``k``
    with ``P(K > k) <= q``."""
    p = 1.0 - q
    k = np.ceil(special.pdtrik(p, mu))
    k1 = np.maximum(k - 1, 0)
    return float(np.where(special.pdtr(k1, mu) >= p, k1, k))


def choose(*, moments: dict, kept_per_weight: float, ladder=LADDER) -> dict:
    """The smallest paths per shot of ``ladder`` that meets both criteria of the module
    docstring over the scout's shots (the largest of ``ladder`` when none does).

    Args:
        moments: :func:`shot_moments` of the scout.
        kept_per_weight: kept photons per unit path weight, ``signal_photons * fill_factor *
            pde`` (for several detectors sharing a trace, the largest).

    Returns:
        dict: ``paths_per_shot``, ``run_out_fraction`` and ``extra_variance`` (expected, at
        the choice), ``w_max``, ``mean_weight``, ``weight_cv`` (mean over shots with returns),
        ``scout_shots``, ``met`` (both criteria met).
    """
    m, m1, m2 = moments["m"], moments["m1"], moments["m2"]
    w_max = moments["w_max"]
    lit = m > 0
    lam = float(kept_per_weight)
    base = {"w_max": w_max, "scout_shots": int(m.size),
            "mean_weight": float(m.mean()) if m.size else 0.0}
    if not lit.any() or lam <= 0 or w_max <= 0:     # nothing comes back: any count will do
        return {**base, "paths_per_shot": int(ladder[0]), "run_out_fraction": 0.0,
                "extra_variance": 0.0, "weight_cv": 0.0, "met": True}
    m, m1, m2 = m[lit], m1[lit], m2[lit]
    cv2 = np.maximum(m2 / (m * m) - 1.0, 0.0)
    frac_lit = lit.mean()
    for k in ladder:
        run_out = float(run_out_probability(kept_mean=lam * m, slots=np.full(m.size, k),
                                            accept_p=m1 / w_max).mean() * frac_lit)
        extra = float(np.mean(lam * m * cv2) / k)
        met = run_out <= RUN_OUT_MAX and extra <= EXTRA_VARIANCE_MAX
        if met or k == ladder[-1]:
            return {**base, "paths_per_shot": int(k), "run_out_fraction": run_out,
                    "extra_variance": extra, "weight_cv": float(np.sqrt(cv2.mean())),
                    "met": bool(met)}
    raise AssertionError("unreachable")


def explain(budget: dict) -> str:
    """The choice in words (``simulate --explain``)."""
    k = budget["paths_per_shot"]
    head = (f"{k} paths per shot, chosen by a scout of {budget['scout_shots']} shots "
            f"(weights {budget['mean_weight']:.3g} on average, at most {budget['w_max']:.3g}, "
            f"spread {100 * budget['weight_cv']:.1f} %): ")
    if not budget["met"]:
        return head + (f"the most auto gives; still {budget['run_out_fraction']:.2g} of the shots "
                       f"expected to run out of distinct returns and "
                       f"{100 * budget['extra_variance']:.2g} % extra count variance: "
                       f"--paths-per-shot sets more")
    return head + (f"expected {budget['run_out_fraction']:.1g} of the shots to run out of "
                   f"distinct returns (target <= {RUN_OUT_MAX:g}) and "
                   f"{100 * budget['extra_variance']:.2g} % extra count variance (target "
                   f"<= {100 * EXTRA_VARIANCE_MAX:g} %)")


def run_out_warning(run_out: int, shots: int) -> str | None:
    """A warning when more than ten times :data:`RUN_OUT_MAX` of the shots (and more than one)
    ran out of distinct returns, else ``None``."""
    if run_out > max(1.0, 10 * RUN_OUT_MAX * shots):
        return (f"{run_out} of {shots} shots had too few paths, photons share paths (a "
                f"first-photon-bias error): raise --paths-per-shot")
    return None


def path_moments(shot: np.ndarray, weight: np.ndarray, *, n_shots: int,
                 paths_per_shot: int) -> dict:
    """:func:`shot_moments` exactly, from a scout traced one path per "shot" (``n_shots *
    paths_per_shot`` of them, each real shot's paths side by side): each path's weight ``W``
    is the sum of its returns, so ``m2`` is the mean of ``W**2`` itself; every return of a
    path can be picked, so ``m1 = m`` (a path of several strong returns, a lake's surface and
    bottom, is not held to its first)."""
    w_path = np.bincount(np.asarray(shot, np.int64), weights=np.asarray(weight, np.float64),
                         minlength=n_shots * paths_per_shot).reshape(n_shots, paths_per_shot)
    m = w_path.mean(axis=1)
    return {"m": m, "m1": m, "m2": (w_path ** 2).mean(axis=1),
            "w_max": float(np.max(weight, initial=0.0))}


def scout(integrator, scene, x_m, y_m, instrument, *, returns_per_path: int,
          per_path: bool = False, gate_z_m: np.ndarray | None = None) -> dict:
    """``paths_per_shot="auto"``: trace the run's own model (``integrator`` on ``scene``, an
    :class:`~lidar_mitsuba.instrument.Instrument`) on up to :data:`SCOUT_SHOTS` of the shots
    at ``x_m``, ``y_m`` [m] spread along the track (fixed random numbers) and choose the paths
    per shot from its weights (:func:`choose`). ``per_path``: trace each path as a shot of its
    own and take the exact moments (:func:`path_moments`; for paths with several strong
    returns, where :func:`shot_moments`'s bound is loose). ``gate_z_m``: (n_shots,) range
    gate centres [m] (with ``per_path``): returns outside the instrument's gate are left out,
    as the run's detector leaves them (:class:`~lidar_mitsuba.trace.stream.GatedSource`)."""
    idx = spread_shots(x_m.size, SCOUT_SHOTS)
    if per_path:
        ret = integrator.trace(scene, shot_x_m=np.repeat(x_m[idx], SCOUT_PATHS),
                               shot_y_m=np.repeat(y_m[idx], SCOUT_PATHS), paths_per_shot=1,
                               seed=SCOUT_SEED)
        if gate_z_m is not None:
            centre = np.repeat(gate_center_ns(instrument, np.asarray(gate_z_m)[idx]),
                               SCOUT_PATHS)
            ret = ret.select(np.flatnonzero(in_gate(ret.shot, ret.time_ns, centre,
                                                    instrument.range_gate_ns / 2)))
        moments = path_moments(ret.shot, ret.weight, n_shots=idx.size,
                               paths_per_shot=SCOUT_PATHS)
    else:
        ret = integrator.trace(scene, shot_x_m=x_m[idx], shot_y_m=y_m[idx],
                               paths_per_shot=SCOUT_PATHS, seed=SCOUT_SEED)
        moments = shot_moments(ret.shot, ret.weight, ret.depth, n_shots=idx.size,
                               paths_per_shot=SCOUT_PATHS, max_depth=returns_per_path)
    return choose(moments=moments, kept_per_weight=(
        instrument.signal_photons * instrument.fill_factor * instrument.pde))
