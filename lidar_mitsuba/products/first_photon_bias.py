"""First-photon bias: the dead-time correction of detected photons, and the robust spread and
background rates it needs. Pure numpy/scipy; used by :mod:`lidar_mitsuba.products.atl06`.

**First-photon-bias correction** (ATBD 3.3, event by event instead of in 25 ps bins). The
window's photons (and those up to two dead times *earlier*, i.e. up to ``2 c tau / 2`` *above*
the window, which can kill channels at the window's top) are put on one time axis,
``t = -2 r / c`` (larger h = earlier). With ``N`` pulses and ``C`` channels (``N C``
channel-pulses), each photon gets the weight ``w = 1 / P_alive(t)``, the dead fraction being
taken over the ``N C - 1`` channel-pulses other than the photon's own (which is known to have
been alive: every event in its look-back window comes from another channel-pulse):

* non-paralyzable: a channel is dead at ``t`` when it detected a photon in ``(t - tau, t)``;
  a channel detects at most one photon per dead time, so
  ``P_dead(t) = #{detections in (t - tau, t)} / (N C - 1)``;
* paralyzable: a channel is dead when *any* photon arrived in ``(t - tau, t)``, detected or not,
  so ``P_alive(t) = exp(-Lambda(t))`` with ``Lambda`` the true (corrected) arrivals per
  channel-pulse in ``(t - tau, t)``, ``Lambda(t) = sum_{t_j in (t - tau, t)} w_j / (N C - 1)``;
  solved in time order (fixed-point iteration of the causal equation, exact on convergence).

The channels are pooled (they are statistically identical), and so are the pulses: a segment
whose shots see different return shapes (rough, sloping terrain) is corrected with their
average dead fraction, as in the ATBD.

The weighted photons are the corrected (true-rate) residual distribution. The background
(``bckgrd``, already dead-time corrected) is uniform over the window, which is symmetric about
``r = 0``: it adds ``N_bg = bckgrd * N * (2 W / c)`` to the total weight and nothing to the first
moment. So

* ``fpb_corr_m = sum(w r) / (sum(w) - N_bg) - mean(r)`` (``mean(r) = 0`` for a least-squares
  line): the shift of the signal centroid [m], added to ``h_mean``. Dead time favours early
  (high) photons, so the uncorrected fit is high and the correction is negative (up to noise);
* ``fpb_med_corr_m``: the median of the corrected, background-subtracted residual
  distribution (the ATBD's ``fpb_med_corr``, relative to the fitted line);
* ``fpb_gain = sum(w) / n``: corrected over observed photon count in the window (>= 1);
  ``fpb_min_alive``: the smallest ``P_alive`` met by a window photon (the ATBD's ``minGain``);
* ``fpb_n_corr = sum(w) - N_bg``: corrected signal photon count.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import special


#: interquartile range of a unit Gaussian, 2 Phi^-1(0.75) = 1.349 (computed once: scipy's
#: ppf costs ~0.2 ms a call, which ATL06's per-segment loop would pay three times a segment;
#: ``special.ndtri`` is the kernel of ``scipy.stats.norm.ppf``, without scipy.stats' import)
IQR_PER_SIGMA = float(2.0 * special.ndtri(0.75))


def robust_spread(r: np.ndarray, *, n_background: float, window: tuple[float, float]) -> float:
    """Background-corrected robust spread (a Gaussian sigma) of residuals ``r``.

    The residuals lie in ``window = (lo, hi)``, where a uniform background contributes
    ``n_background`` of them. The signal CDF is estimated as the empirical CDF minus the
    background's, ``S(x) = #{r <= x} - n_background (x - lo) / (hi - lo)``; its quartiles
    (``S = N_sig / 4`` and ``3 N_sig / 4``, ``N_sig = n - n_background``) give
    ``sigma = (q75 - q25) / 1.349``. Without signal (``N_sig <= 0``) or with a degenerate
    answer, the plain interquartile range of ``r`` / 1.349 is returned (NaN without photons).
    """
    r = np.sort(np.asarray(r, np.float64))
    n = r.size
    if n == 0:
        return float("nan")
    lo, hi = window
    n_sig = n - n_background
    iqr_scale = IQR_PER_SIGMA                     # 1.349
    if n_sig <= 0 or n < 4 or hi <= lo:
        return float(np.subtract(*np.percentile(r, [75, 25])) / iqr_scale)
    s = np.arange(n) + 0.5 - n_background * (r - lo) / (hi - lo)
    below = np.flatnonzero(s < 0.25 * n_sig)
    above = np.flatnonzero(s > 0.75 * n_sig)
    i0 = below[-1] if below.size else 0
    i1 = above[0] if above.size else n - 1
    sigma = (r[i1] - r[i0]) / iqr_scale
    if not sigma > 0:
        sigma = float(np.subtract(*np.percentile(r, [75, 25])) / iqr_scale)
    return float(sigma)


def dead_time_weights(t_ns: np.ndarray, *, n_pulses: int, n_channels: int, dead_time_ns: float,
                      paralyzable: bool, max_iterations: int = 500, tol: float = 1e-10
                      ) -> tuple[np.ndarray, bool]:
    """Per-photon weights ``1 / P_alive(t)`` correcting detected photons for dead time.

    Args:
        t_ns: (n,) detection times on one axis shared by the ``n_pulses * n_channels``
            channel-pulses (e.g. ``-2 r / c`` from residuals; any order).
        paralyzable: dead time started by every arrival (else by detections only).

    Non-paralyzable: ``w = 1 / (1 - k / (N C - 1))``, ``k`` the detections in ``(t - tau, t)``;
    paralyzable: ``w = exp(sum of w over (t - tau, t) / (N C - 1))``, solved by fixed-point
    iteration (monotone from ``w = 1``; each sweep fixes one more link of the causal chain).

    Returns:
        ``(w, ok)``: (n,) weights (>= 1; NaN where a channel is certainly dead), and whether the
        paralyzable fixed-point iteration converged (always True otherwise).
    """
    t = np.asarray(t_ns, np.float64)
    n = t.size
    w = np.ones(n)
    if n == 0 or dead_time_ns <= 0:
        return w, True
    order = np.argsort(t, kind="stable")
    ts = t[order]
    lo = np.searchsorted(ts, ts - dead_time_ns, side="right")   # first event in (t - tau, ...
    hi = np.searchsorted(ts, ts, side="left")                    # ... t): events strictly before
    # A detected photon's own channel-pulse is known to have been alive (no detection, and for
    # the paralyzable model no arrival, in (t - tau, t)), so the dead fraction is estimated from
    # the other N C - 1 channel-pulses: every event in the look-back window is from one of them.
    # (Dividing by N C instead biases the weights low by ~P_dead / (N C) and leaves ~3 % of a
    # 13 cm bias in 57-pulse, 4-channel segments.)
    npc = float(max(n_pulses * n_channels - 1, 1))
    if not paralyzable:
        p_dead = (hi - lo) / npc
        alive = 1.0 - p_dead
        ws = np.where(alive > 0, 1.0 / np.where(alive > 0, alive, 1.0), np.nan)
        w[order] = ws
        return w, True
    ws = np.ones(n)
    ok = False
    with np.errstate(over="ignore", invalid="ignore"):
        for _ in range(max_iterations):
            cw = np.concatenate([[0.0], np.cumsum(ws)])
            new = np.exp((cw[hi] - cw[lo]) / npc)
            if not np.all(np.isfinite(new)):
                ws = new
                break
            done = np.max(np.abs(new - ws) / new) < tol
            ws = new
            if done:
                ok = True
                break
    w[order] = ws
    return w, ok


def corrected_background_mhz(observed_mhz: float, *, n_channels: int, dead_time_ns: float,
                             paralyzable: bool) -> float:
    """Dead-time correction of a background rate observed on ``n_channels`` equal channels:
    per channel ``r_o = observed / C``; non-paralyzable ``r = r_o / (1 - r_o tau)``;
    paralyzable ``r_o = r exp(-r tau)`` solved on its lower branch (``r tau < 1``). NaN when no
    rate explains ``r_o`` (saturation)."""
    if observed_mhz <= 0 or dead_time_ns <= 0:
        return float(observed_mhz)
    ro = observed_mhz * 1e-3 / n_channels          # per ns per channel
    x = ro * dead_time_ns
    if paralyzable:
        if x >= 1.0 / math.e:
            return float("nan")
        r = -float(np.real(special.lambertw(-x, 0))) / dead_time_ns
    else:
        if x >= 1.0:
            return float("nan")
        r = ro / (1.0 - x)
    return float(r * n_channels * 1e3)


def weighted_median_minus_uniform(r: np.ndarray, w: np.ndarray, *, n_bg: float,
                                   half_w: float) -> float:
    """Median of the distribution ``sum_i w_i delta(r - r_i) - uniform(n_bg on [-half_w,
    half_w])``, by linear interpolation of its CDF at the mid-steps."""
    order = np.argsort(r)
    rs, ws = r[order], w[order]
    total = ws.sum() - n_bg
    if not total > 0:
        return float("nan")
    cdf = np.cumsum(ws) - 0.5 * ws - n_bg * (rs + half_w) / (2.0 * half_w)
    target = 0.5 * total
    k = np.flatnonzero(cdf >= target)
    if k.size == 0:
        return float(rs[-1])
    k = k[0]
    if k == 0:
        return float(rs[0])
    c0, c1 = cdf[k - 1], cdf[k]
    f = (target - c0) / (c1 - c0) if c1 > c0 else 0.5
    return float(rs[k - 1] + f * (rs[k] - rs[k - 1]))
