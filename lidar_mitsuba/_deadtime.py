"""Compiled kernel of the detector stage (numba): dead time in one pass per shot.

The dead-time decision is sequential within a channel (a non-paralyzable detector is dead after
each *recorded* event), which numpy can only do in many passes. Here events are sorted by
(shot, time) with a counting sort on the shot and an insertion sort within it, then each shot is
scanned once in time order, keeping the last relevant time of each channel; shots run in
parallel on all cores. ``cache=True`` keeps the compiled code between runs.
"""
from __future__ import annotations

import numba
import numpy as np

_INSERTION_MAX = 160     # longer shots are sorted with argsort


@numba.njit(cache=True, nogil=True, parallel=True)
def _sort_by_shot_time(shot, time_ns, n_shots):
    n = shot.size
    start = np.zeros(n_shots + 1, np.int64)
    for i in range(n):
        start[shot[i] + 1] += 1
    for s in range(n_shots):
        start[s + 1] += start[s]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        s = shot[i]
        order[fill[s]] = i
        fill[s] += 1
    for s in numba.prange(n_shots):
        a, b = start[s], start[s + 1]
        if b - a > _INSERTION_MAX:
            sub = order[a:b]
            order[a:b] = sub[np.argsort(time_ns[sub], kind="mergesort")]
            continue
        for j in range(a + 1, b):
            i = order[j]
            t = time_ns[i]
            k = j - 1
            while k >= a and time_ns[order[k]] > t:
                order[k + 1] = order[k]
                k -= 1
            order[k + 1] = i
    return order, start


@numba.njit(cache=True, nogil=True, parallel=True)
def record(shot, channel, time_ns, n_shots, n_channels, dead_time_ns, paralyzable):
    """Which events the detector records, and all events in (shot, time) order.

    Non-paralyzable: an event is recorded when it comes at least ``dead_time_ns`` after the
    previous *recorded* event of its channel in its shot. Paralyzable: at least
    ``dead_time_ns`` after the previous event of its channel, recorded or not.

    Args:
        shot: (n,) int64 in [0, n_shots); channel: (n,) int64 in [0, n_channels);
        time_ns: (n,) float64.
    Returns:
        ``(keep, order)``: (n,) bool, and (n,) int64 indices sorting events by (shot, time).
    """
    order, start = _sort_by_shot_time(shot, time_ns, n_shots)
    keep = np.zeros(shot.size, np.bool_)
    for s in numba.prange(n_shots):
        a, b = start[s], start[s + 1]
        if a == b:
            continue
        last = np.full(n_channels, -np.inf)
        for j in range(a, b):
            i = order[j]
            c = channel[i]
            t = time_ns[i]
            if t - last[c] >= dead_time_ns:
                keep[i] = True
                last[c] = t
            elif paralyzable:
                last[c] = t
    return keep, order


@numba.njit(cache=True, nogil=True)
def choose_returns(start, weight, w_max, need, exchangeable, seed):
    """For each shot, ``need[s]`` distinct returns drawn in proportion to weight.

    Rejection sampling: returns are visited in a uniformly random order (their own order when
    ``exchangeable``, else a lazy partial Fisher-Yates shuffle) and accepted with probability
    ``w / w_max`` until ``need[s]`` are accepted; accepted returns are iid draws from the
    weighted distribution. If a shot runs out, its remaining picks are drawn with replacement
    by weight. Work grows with the picks, not with the number of returns. Serial, seeded: the
    same seed gives the same picks.

    Args:
        start: (n_shots + 1,) offsets of each shot's returns; weight: (n_returns,) float64.
        need: (n_shots,) picks per shot. Returns (sum(need),) int64 return indices, by shot.
    """
    np.random.seed(seed)
    n_shots = need.size
    out = np.empty(need.sum(), np.int64)
    pos = 0
    scratch = np.empty(0, np.int64)
    for s in range(n_shots):
        k = need[s]
        if k == 0:
            continue
        a, b = start[s], start[s + 1]
        m = b - a
        if not exchangeable:
            if scratch.size < m:
                scratch = np.empty(2 * m, np.int64)
            for j in range(m):
                scratch[j] = a + j
        got = 0
        j = 0
        while got < k and j < m:
            if exchangeable:
                i = a + j
            else:
                r = j + np.random.randint(0, m - j)
                i = scratch[r]
                scratch[r] = scratch[j]
                scratch[j] = i
            j += 1
            if np.random.random() * w_max < weight[i]:
                out[pos] = i
                pos += 1
                got += 1
        if got < k:                      # fallback: with replacement, by weight
            total = 0.0
            for i in range(a, b):
                total += weight[i]
            while got < k:
                if total <= 0.0:
                    out[pos] = a
                else:
                    u = np.random.random() * total
                    acc = 0.0
                    i = a
                    while i < b - 1:
                        acc += weight[i]
                        if acc > u:
                            break
                        i += 1
                    out[pos] = i
                pos += 1
                got += 1
    return out
