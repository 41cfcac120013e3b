"""``max_depth="auto"``: a small two-bounce pilot decides whether a run needs the second bounce.

On a plane nothing bounces twice, so single bounce is exact and no pilot runs. Elsewhere a
``max_depth = 2`` trace of up to :data:`PILOT_SHOTS` shots spread along the track (fixed random
numbers: the choice depends on the scene and the run's size, not on its seed) measures what
leaving out the second bounce does to the bias and the precision, and keeps single bounce only
when both move by less than :data:`PILOT_MARGIN` of the run's own Monte Carlo error
(:func:`single_bounce_error`, pure numpy).
"""
from __future__ import annotations

import math

import numpy as np

from .variant import ensure_renderer

mi = ensure_renderer()        # the renderer, set up on first use

from ..products import retrieval
from ..constants import C_M_PER_NS
from ..instrument import Instrument
from ..track import spread_shots

PILOT_SHOTS = 1024      # shots (spread along the track) of the multiple-scattering pilot
PILOT_SEED = 0x50494C4F54   # fixed: a scene's choice does not depend on the run's seed
#: single bounce is enough when the second bounce moves bias and precision by less than this
#: fraction of the run's Monte Carlo error: far from 1, so that neither the pilot's own noise
#: nor its asymptotic error model flips the choice on a borderline scene
PILOT_MARGIN = 0.25


def single_bounce_error(*, dh_m: np.ndarray, weight: np.ndarray, depth: np.ndarray,
                        n_photons: float) -> dict:
    """What leaving out the second bounce does to a run's bias and precision, against the
    Monte Carlo error of that run. Pure numpy: the input is a ``max_depth = 2`` pilot trace.

    The returns are weighted samples of the photon height error ``dh = h - z_ref``. Single
    bounce keeps the depth-1 returns only; the full model keeps all. Their weighted means and
    standard deviations differ by ``d_bias_m`` and ``d_std_m``. A run of the full model that
    detects ``n_photons`` signal photons has Monte Carlo errors ``sigma / sqrt(n)`` in the bias
    and ``sigma * sqrt((kurtosis - 1) / (4 n))`` in the precision (the standard error of a
    sample standard deviation), with ``sigma`` and the kurtosis of the full distribution: a
    late tail of twice-scattered photons makes the precision of a run noisy, and a
    simplification need only stay below that noise. Single bounce is enough when both
    differences are under ``PILOT_MARGIN`` (a quarter) of the Monte Carlo error.

    Args:
        dh_m: (n,) height error of each return [m].
        weight: (n,) return weights (>= 0).
        depth: (n,) surface interaction of each return (1 = first surface, 2 = second).
        n_photons: detected signal photons of the run the choice is for.

    Returns:
        dict: ``d_bias_m``, ``d_std_m`` [m] (full model minus single bounce), ``mc_bias_m``,
        ``mc_std_m`` [m] (Monte Carlo error of the run), ``depth2_weight_fraction`` and
        ``single_bounce_enough`` (both differences under ``PILOT_MARGIN`` of the Monte Carlo
        error).
    """
    dh = np.asarray(dh_m, np.float64)
    w = np.asarray(weight, np.float64)
    depth = np.asarray(depth)
    ok = np.isfinite(dh) & (w > 0)
    dh, w, depth = dh[ok], w[ok], depth[ok]
    one = depth == 1
    if not one.any():
        raise ValueError("the pilot has no first-surface returns")

    def moments(x, v):
        m = np.average(x, weights=v)
        var = np.average((x - m) ** 2, weights=v)
        kurt = np.average((x - m) ** 4, weights=v) / var ** 2 if var > 0 else 3.0
        return m, math.sqrt(var), kurt

    m1, s1, _ = moments(dh[one], w[one])
    m, s, k = moments(dh, w)
    n = max(float(n_photons), 1.0)
    mc_bias, mc_std = s / math.sqrt(n), s * math.sqrt(max(k - 1.0, 0.0) / (4.0 * n))
    d_bias, d_std = m - m1, s - s1
    return {"d_bias_m": float(d_bias), "d_std_m": float(d_std),
            "mc_bias_m": float(mc_bias), "mc_std_m": float(mc_std),
            "depth2_weight_fraction": float(w[~one].sum() / w.sum()),
            "single_bounce_enough": bool(abs(d_bias) <= PILOT_MARGIN * mc_bias
                                         and abs(d_std) <= PILOT_MARGIN * mc_std)}


def run_pilot(*, scene: mi.Scene, instrument: Instrument, x_m: np.ndarray, y_m: np.ndarray,
              dz_m: np.ndarray, z_ref_m: np.ndarray, paths_per_shot: int) -> dict:
    """Trace a ``max_depth = 2`` pilot on up to ``PILOT_SHOTS`` shots spread along the track
    and judge whether single bounce keeps the answer (:func:`single_bounce_error`), from the
    returns inside the range gate and the signal photons the run is expected to detect.

    Args:
        scene: the scene the run traces.
        x_m, y_m: (n_shots,) shot positions in the scene [m]; ``dz_m`` (n_shots,) the height
            offset folded out of them [m] (0 unless the track was folded into a plane's tile).
        z_ref_m: (n_shots,) reference elevation of each shot [m].

    Returns:
        :func:`single_bounce_error`'s dict plus ``pilot_shots`` and ``n_photons``; NaN numbers
        and ``single_bounce_enough`` False when nothing returned inside the range gate.
    """
    shots = int(np.asarray(x_m).size)
    idx = spread_shots(shots, PILOT_SHOTS)
    integrator = mi.load_dict(instrument.integrator_dict(max_depth=2))
    ret = integrator.trace(scene, shot_x_m=x_m[idx], shot_y_m=y_m[idx],
                           paths_per_shot=int(paths_per_shot), seed=PILOT_SEED)
    s = ret.shot.astype(np.int64)
    t_ns = ret.time_ns - 2.0 * dz_m[idx][s] / C_M_PER_NS
    dh = retrieval.photon_heights_m(t_ns, altitude_m=instrument.altitude_m) - z_ref_m[idx][s]
    dh[np.abs(dh) > instrument.range_gate_m / 2.0] = np.nan     # the gate records none of these
    photons_per_shot = (instrument.signal_photons * ret.weight.sum(dtype=np.float64)
                        / (idx.size * paths_per_shot))
    n_photons = shots * photons_per_shot * instrument.fill_factor * instrument.pde
    try:
        out = single_bounce_error(dh_m=dh, weight=ret.weight, depth=ret.depth,
                                  n_photons=n_photons)
    except ValueError:      # nothing returned inside the gate: nothing to judge, trace both
        out = dict.fromkeys(("d_bias_m", "d_std_m", "mc_bias_m", "mc_std_m",
                             "depth2_weight_fraction"), math.nan)
        out["single_bounce_enough"] = False
    out.update(pilot_shots=int(idx.size), n_photons=float(n_photons))
    return out


def explain(pilot: dict, max_depth: int) -> str:
    """The pilot's verdict in words (``simulate --explain``)."""
    if not math.isfinite(pilot["d_bias_m"]):
        return (f"bounces: the max_depth 2 pilot on {pilot['pilot_shots']} shots saw no "
                "first-surface return inside the range gate, so max_depth 2 to be safe")
    cm = {k: 100 * pilot[k] for k in ("d_bias_m", "d_std_m", "mc_bias_m", "mc_std_m")}
    verdict = ("below a quarter of it: single bounce (max_depth 1) keeps the answer"
               if max_depth == 1 else "not below a quarter of it: max_depth 2")
    return (f"bounces chosen by a max_depth 2 pilot on {pilot['pilot_shots']} shots: the "
            f"second bounce carries {100 * pilot['depth2_weight_fraction']:.2f} % of the "
            f"return and moves the bias by {cm['d_bias_m']:+.2f} cm and the precision by "
            f"{cm['d_std_m']:+.2f} cm, against this run's Monte Carlo error of "
            f"{cm['mc_bias_m']:.2f} / {cm['mc_std_m']:.2f} cm ({pilot['n_photons']:.0f} "
            f"signal photons): {verdict}; --max-depth N sets it")
