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


@numba.njit(inline="always")
def _uniform(seed, shot, j):
    """Counter-based uniform in [0, 1) (splitmix64 of seed, shot, j): parallel-safe."""
    z = np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(shot) * np.uint64(0xD1B54A32D192ED03) \
        + np.uint64(j) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True, nogil=True, parallel=True)
def detect_shots(sig_start, sig_time, sig_anode, sig_index, gate_start, gate_ns, noise_count,
                 anodes, n_channels, dead_time_ns, paralyzable, seed):
    """The whole detector stage per shot, in one parallel pass, already in output order.

    For each shot: its signal photons inside the gate and ``noise_count[s]`` noise events
    (background photons and dark counts: uniform in the gate and, since every channel has the
    same dark rate, uniform over the anodes), in time order, then dead time per channel
    (non-paralyzable or paralyzable). Noise times are generated sorted (normalised cumulative
    exponential spacings) with a counter-based RNG keyed by (seed, shot, j), and merged with the
    shot's few sorted signal photons; nothing is sorted globally.

    Args:
        sig_start: (n_shots + 1,) offsets of each shot's signal photons in ``sig_*``.
        sig_time, sig_anode, sig_index: signal photons' time [ns], anode, traced-return index.
        gate_start: (n_shots,) gate opening [ns]; gate_ns: gate length [ns] (inf: no gate).
        noise_count: (n_shots,) noise events per shot.
    Returns:
        ``(time_ns, anode, index, recorded, slot_start)``: per slot (by shot, then time),
        ``index`` -1 for noise; ``recorded`` marks the events the detector records.
    """
    n_shots = noise_count.size
    size = np.empty(n_shots + 1, np.int64)
    size[0] = 0
    for s in range(n_shots):
        size[s + 1] = size[s] + (sig_start[s + 1] - sig_start[s]) + noise_count[s]
    total = size[n_shots]
    t_out = np.empty(total, np.float64)
    a_out = np.empty(total, np.int16)
    i_out = np.empty(total, sig_index.dtype)
    rec = np.zeros(total, np.bool_)
    per_ch = anodes // n_channels
    for s in numba.prange(n_shots):
        o, end = size[s], size[s + 1]
        mn = noise_count[s]
        g0 = gate_start[s]
        # signal inside the gate, insertion-sorted into the tail of the shot's slots
        q = o + mn
        for j in range(sig_start[s], sig_start[s + 1]):
            t = sig_time[j]
            if t >= g0 and t < g0 + gate_ns:
                k = q - 1
                while k >= o + mn and t_out[k] > t:
                    t_out[k + 1] = t_out[k]
                    a_out[k + 1] = a_out[k]
                    i_out[k + 1] = i_out[k]
                    k -= 1
                t_out[k + 1] = t
                a_out[k + 1] = sig_anode[j]
                i_out[k + 1] = sig_index[j]
                q += 1
        ms = q - (o + mn)
        # sorted noise times: cumulative sums of mn + 1 exponentials, normalised
        total_e = 0.0
        for j in range(mn + 1):
            total_e -= np.log(1.0 - _uniform(seed, s, 2 * j))
        w = o            # write position; the unread signal starts at o + mn + read
        read = 0
        acc = 0.0
        for j in range(mn):
            acc -= np.log(1.0 - _uniform(seed, s, 2 * j))
            t = g0 + gate_ns * (acc / total_e)
            while read < ms and t_out[o + mn + read] <= t:
                src = o + mn + read
                t_out[w], a_out[w], i_out[w] = t_out[src], a_out[src], i_out[src]
                w += 1
                read += 1
            t_out[w] = t
            a_out[w] = min(int(_uniform(seed, s, 2 * j + 1) * anodes), anodes - 1)
            i_out[w] = -1
            w += 1
        while read < ms:
            src = o + mn + read
            t_out[w], a_out[w], i_out[w] = t_out[src], a_out[src], i_out[src]
            w += 1
            read += 1
        last = np.full(n_channels, -np.inf)
        for j in range(o, w):
            c = a_out[j] // per_ch
            t = t_out[j]
            if t - last[c] >= dead_time_ns:
                rec[j] = True
                last[c] = t
            elif paralyzable:
                last[c] = t
        for j in range(w, end):   # slots of signal photons the gate dropped
            t_out[j] = np.inf
            a_out[j] = 0
            i_out[j] = -1
    return t_out, a_out, i_out, rec, size
