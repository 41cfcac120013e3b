"""The compiled ATL06 fit's dead-time weights (numba; :mod:`lidar_mitsuba.products.atl06.kernel`
calls them): the twins of :func:`lidar_mitsuba.products.first_photon_bias.dead_time_weights`,
each photon weighted by the inverse of the fraction of channel-pulses alive when it arrived
(the derivation is in :mod:`lidar_mitsuba.products.first_photon_bias`). Moved here from the
kernel's module as they were, to keep that module a room one can read (issue 28).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from .sorting import argsort, first_at_least


@numba.njit(cache=True, nogil=True)
def _dead_time_weights(t, n_pulses, n_channels, dead_time_ns, paralyzable):
    """:func:`lidar_mitsuba.products.first_photon_bias.dead_time_weights` (500 iterations, tol 1e-10): (w, ok)."""
    n = t.size
    w = np.ones(n)
    ok = True
    if n == 0 or dead_time_ns <= 0:
        return w, ok
    npc = float(max(n_pulses * n_channels - 1, 1))
    order = argsort(t)
    ts = t[order]
    lo = np.empty(n, np.int64)
    hi = np.empty(n, np.int64)
    for j in range(n):
        lo[j] = first_at_least(ts, ts[j] - dead_time_ns, True)
        hi[j] = first_at_least(ts, ts[j], False)
    if not paralyzable:      # (the weights of _dead_time_weights_ordered; kept for the twin)
        for j in range(n):
            alive = 1.0 - (hi[j] - lo[j]) / npc
            w[order[j]] = 1.0 / alive if alive > 0 else np.nan
        return w, ok
    ws = np.ones(n)
    cw = np.zeros(n + 1)
    new = np.empty(n)
    ok = False
    for _ in range(500):
        for j in range(n):
            cw[j + 1] = cw[j] + ws[j]
        finite = True
        for j in range(n):
            new[j] = math.exp((cw[hi[j]] - cw[lo[j]]) / npc)
            if not math.isfinite(new[j]):
                finite = False
        if not finite:
            ws[:] = new
            break
        worst = 0.0
        for j in range(n):
            worst = max(worst, abs(new[j] - ws[j]) / new[j])
        ws[:] = new
        if worst < 1e-10:
            ok = True
            break
    for j in range(n):
        w[order[j]] = ws[j]
    return w, ok


@numba.njit(cache=True, nogil=True)
def _dead_time_weights_ordered(r, order, n_pulses, n_channels, dead_time_ns, half_c):
    """:func:`_dead_time_weights` of the non-paralyzable detector at the times ``t = -r /
    half_c`` [ns] of the residuals ``r`` [m], given ``order``, ``r``'s stable argsort (NaN-free
    ``r``): the same weights. ``t`` runs up along ``order`` reversed, so both ends of each
    photon's dead-time window [t - dead time, t) only move up along it (no search)."""
    n = r.size
    w = np.ones(n)
    if n == 0 or dead_time_ns <= 0:
        return w
    npc = float(max(n_pulses * n_channels - 1, 1))
    ts = np.empty(n)
    for j in range(n):
        ts[j] = -r[order[n - 1 - j]] / half_c
    lo = 0
    hi = 0
    for j in range(n):
        while hi < n and ts[hi] < ts[j]:                  # first_at_least(ts, t, False)
            hi += 1
        while lo < n and ts[lo] <= ts[j] - dead_time_ns:  # first_at_least(ts, t - tau, True)
            lo += 1
        alive = 1.0 - (hi - lo) / npc
        w[order[n - 1 - j]] = 1.0 / alive if alive > 0 else np.nan
    return w
