"""Compiled kernels of the detector stage (numba).

The dead-time decision is sequential within a channel (a non-paralyzable detector is dead after
each *recorded* event), which numpy can only do in many passes. Here each shot's events are put
in time order and scanned once, keeping the last relevant time of each channel; shots run in
parallel on all cores, with a counter-based RNG so that parallel runs are reproducible.
``cache=True`` keeps the compiled code between runs.
"""
from __future__ import annotations

import contextlib

import numba
import numpy as np

_INSERTION_MAX = 160     # longer shots are sorted with argsort
#: shots per block of :func:`detect_shots` and :func:`choose_returns` (blocks run in
#: parallel, each reusing its buffers)
BLOCK_SHOTS = 256


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
def choose_returns(start, weight, w_max, need, exchangeable, seed):
    """For each shot, ``need[s]`` distinct returns drawn in proportion to weight.

    Rejection sampling: returns are visited in a uniformly random order (their own order when
    ``exchangeable``, else a lazy partial Fisher-Yates shuffle) and accepted with probability
    ``w / w_max`` until ``need[s]`` are accepted; accepted returns are iid draws from the
    weighted distribution. If a shot runs out, its remaining picks are drawn with replacement
    by weight. Work grows with the picks, not with the number of returns. Shots run in
    parallel with a counter-based RNG keyed by (seed, shot, j): the same seed gives the same
    picks.

    Args:
        start: (n_shots + 1,) offsets of each shot's returns; weight: (n_returns,).
        need: (n_shots,) picks per shot.

    Returns:
        ``(index, ran_out, offsets)``: (sum(need),) int64 return indices, by shot; (n_shots,)
        bool, the shots that ran out; (n_shots + 1,) where each shot's picks begin in
        ``index``.
    """
    n_shots = need.size
    off = np.zeros(n_shots + 1, np.int64)
    for s in range(n_shots):
        off[s + 1] = off[s] + need[s]
    out = np.empty(off[n_shots], np.int64)
    ran_out = np.zeros(n_shots, np.bool_)
    n_blocks = (n_shots + BLOCK_SHOTS - 1) // BLOCK_SHOTS
    for blk in numba.prange(n_blocks):
        # one shuffle buffer a block of shots (none when exchangeable), not one a shot: an
        # allocation a shot was two thirds of the kernel's time on single-bounce returns
        s0, s1 = blk * BLOCK_SHOTS, min(n_shots, (blk + 1) * BLOCK_SHOTS)
        cap = 0
        if not exchangeable:
            for s in range(s0, s1):
                cap = max(cap, start[s + 1] - start[s])
        scratch = np.empty(cap, np.int64)
        for s in range(s0, s1):
            _choose_shot(s, start, weight, w_max, need, exchangeable, seed, off, out, ran_out,
                         scratch)
    return out, ran_out, off


@numba.njit(cache=True, nogil=True, inline="always")
def _choose_shot(s, start, weight, w_max, need, exchangeable, seed, off, out, ran_out, scratch):
    """Shot ``s``'s picks of :func:`choose_returns` into ``out`` from ``off[s]`` on
    (``scratch``: at least its returns' room when not ``exchangeable``)."""
    k = need[s]
    if k == 0:
        return
    a, b = start[s], start[s + 1]
    m = b - a
    if not exchangeable:
        for j in range(m):
            scratch[j] = a + j
    pos = off[s]
    got = 0
    j = 0
    r = 0
    while got < k and j < m:
        if exchangeable:
            i = a + j
        else:
            pick = j + min(int(_uniform(seed, s, r) * (m - j)), m - j - 1)
            r += 1
            i = scratch[pick]
            scratch[pick] = scratch[j]
            scratch[j] = i
        j += 1
        u = _uniform(seed, s, r)
        r += 1
        if u * w_max < weight[i]:
            out[pos] = i
            pos += 1
            got += 1
    if got < k:                      # fallback: with replacement, by weight
        ran_out[s] = True
        cw = np.empty(m, np.float64)
        acc = 0.0
        for i in range(m):
            acc += weight[a + i]
            cw[i] = acc
        while got < k:
            if acc <= 0.0:
                out[pos] = a
            else:
                u = _uniform(seed, s, r) * acc
                r += 1
                out[pos] = a + min(np.searchsorted(cw, u, side="right"), m - 1)
            pos += 1
            got += 1


@numba.njit(cache=True, nogil=True)
def shot_stats(shot, weight, n_shots):
    """Per-shot weight sums (float64, summed in return order), offsets (n_shots + 1), the
    largest weight, and whether ``shot`` is non-decreasing (if not, the rest is not valid).

    One serial pass over the returns (~1 ns a return). It runs while the tracer's threads
    trace the next chunk on every core: a parallel region here waited for a free core at
    each call (1.2 s of a six-beam 100 km granule's 216 chunks against 0.02 s serial).
    Shots at or beyond ``n_shots`` are left out."""
    n = shot.size
    w_sum = np.zeros(n_shots, np.float64)
    start = np.zeros(n_shots + 1, np.int64)
    w_max = 0.0
    p = np.int64(-1)
    i = 0
    while i < n:
        s = np.int64(shot[i])
        if s < p:
            return w_sum, start, 0.0, False
        if s >= n_shots:                # the rest (sorted) is beyond the shots asked for
            break
        for t in range(p + 1, s + 1):   # shots p + 1 .. s begin here (s: this one)
            start[t] = i
        acc = 0.0
        while i < n and shot[i] == s:
            w = float(weight[i])
            acc += w
            if w > w_max:
                w_max = w
            i += 1
        w_sum[s] = acc
        p = s
    for t in range(p + 1, n_shots + 1):
        start[t] = i
    return w_sum, start, w_max, True


@numba.njit(cache=True, nogil=True, inline="always")
def _dead_time(w, t_buf, a_buf, r_buf, last, per_ch, dead_time_ns, paralyzable):
    """Mark in ``r_buf`` which of the ``w`` time-sorted events in the buffers the detector
    records: each channel (``per_ch`` anodes) dead for ``dead_time_ns`` after each recorded
    event (non-paralyzable) or each event (``paralyzable``); ``last``: (n_channels,) scratch."""
    for c in range(last.size):
        last[c] = -np.inf
    for j in range(w):
        c = a_buf[j] // per_ch
        t = t_buf[j]
        if t - last[c] >= dead_time_ns:
            r_buf[j] = True
            last[c] = t
        else:
            r_buf[j] = False
            if paralyzable:
                last[c] = t


@numba.njit(cache=True, nogil=True, inline="always")
def _signal_events(s, sig_start, sig_time, sig_anode, sig_index, g0, gate_ns, per_ch,
                   dead_time_ns, paralyzable, t_buf, a_buf, i_buf, r_buf, last):
    """:func:`_shot_events` of a shot without noise: its signal in the gate, stably sorted by
    time at the head of the buffers (insertion sort, or a merge argsort past
    :data:`_INSERTION_MAX`: a stable sort's result is unique, so the same order), and dead time."""
    w = 0
    for j in range(sig_start[s], sig_start[s + 1]):
        t = sig_time[j]
        if t >= g0 and t < g0 + gate_ns:
            t_buf[w] = t
            a_buf[w] = sig_anode[j]
            i_buf[w] = sig_index[j]
            w += 1
    if w > _INSERTION_MAX:
        perm = np.argsort(t_buf[:w], kind="mergesort")
        t_buf[:w] = t_buf[:w][perm]
        a_buf[:w] = a_buf[:w][perm]
        i_buf[:w] = i_buf[:w][perm]
    else:
        for q in range(1, w):
            t = t_buf[q]
            if t_buf[q - 1] <= t:
                continue
            a, i = a_buf[q], i_buf[q]
            k = q - 1
            while k >= 0 and t_buf[k] > t:
                t_buf[k + 1] = t_buf[k]
                a_buf[k + 1] = a_buf[k]
                i_buf[k + 1] = i_buf[k]
                k -= 1
            t_buf[k + 1] = t
            a_buf[k + 1] = a
            i_buf[k + 1] = i
    _dead_time(w, t_buf, a_buf, r_buf, last, per_ch, dead_time_ns, paralyzable)
    return w


@numba.njit(cache=True, nogil=True, inline="always")
def _shot_events(s, sig_start, sig_time, sig_anode, sig_index, g0, gate_ns, noise_per_ns,
                 anodes, n_channels, dead_time_ns, paralyzable, seed, t_buf, a_buf, i_buf, r_buf,
                 last):
    """One shot: signal in the gate plus Poisson noise at ``noise_per_ns`` over the gate,
    time-sorted into the buffers, with ``r_buf`` marking what the detector records
    (``last``: (n_channels,) scratch, each channel's last relevant time, reset here). Returns
    the number of events, or -1 when the buffers are too short (the caller grows them and
    calls again). Deterministic: the same arguments give the same events."""
    cap = t_buf.size
    per_ch = anodes // n_channels
    if not noise_per_ns > 0:
        return _signal_events(s, sig_start, sig_time, sig_anode, sig_index, g0, gate_ns,
                              per_ch, dead_time_ns, paralyzable, t_buf, a_buf, i_buf, r_buf,
                              last)
    n_sig = 0
    for j in range(sig_start[s], sig_start[s + 1]):
        t = sig_time[j]
        if t >= g0 and t < g0 + gate_ns:
            n_sig += 1
    # signal inside the gate, sorted into the tail of the buffers (insertion sort for the
    # usual handful, argsort for saturating returns)
    base = cap - n_sig
    q = base
    big = n_sig > _INSERTION_MAX
    for j in range(sig_start[s], sig_start[s + 1]):
        t = sig_time[j]
        if t >= g0 and t < g0 + gate_ns:
            k = q - 1
            while not big and k >= base and t_buf[k] > t:
                t_buf[k + 1] = t_buf[k]
                a_buf[k + 1] = a_buf[k]
                i_buf[k + 1] = i_buf[k]
                k -= 1
            t_buf[k + 1] = t
            a_buf[k + 1] = sig_anode[j]
            i_buf[k + 1] = sig_index[j]
            q += 1
    if big:
        perm = np.argsort(t_buf[base:cap], kind="mergesort")
        t_buf[base:cap] = t_buf[base:cap][perm]
        a_buf[base:cap] = a_buf[base:cap][perm]
        i_buf[base:cap] = i_buf[base:cap][perm]
    # noise: a Poisson process over the gate (exponential gaps), merged forward with the
    # sorted signal; the write position must stay behind the unread signal
    w = 0
    read = 0
    j = 0
    t = g0
    if noise_per_ns > 0:
        while True:
            t -= np.log(1.0 - _uniform(seed, s, 2 * j)) / noise_per_ns
            if t >= g0 + gate_ns:
                break
            while read < n_sig and t_buf[base + read] <= t:
                t_buf[w], a_buf[w], i_buf[w] = t_buf[base + read], a_buf[base + read], i_buf[base + read]
                w += 1
                read += 1
            if w >= base + read:
                return -1
            t_buf[w] = t
            a_buf[w] = min(int(_uniform(seed, s, 2 * j + 1) * anodes), anodes - 1)
            i_buf[w] = -1
            w += 1
            j += 1
    while read < n_sig:
        t_buf[w], a_buf[w], i_buf[w] = t_buf[base + read], a_buf[base + read], i_buf[base + read]
        w += 1
        read += 1
    _dead_time(w, t_buf, a_buf, r_buf, last, per_ch, dead_time_ns, paralyzable)
    return w


@numba.njit(cache=True, nogil=True)
def _block_events(s0, s1, sig_start, sig_time, sig_anode, sig_index, gate_start, gate_ns,
                  noise_per_ns, anodes, n_channels, dead_time_ns, paralyzable, seed,
                  out_shot, out_t, out_a, out_i, o0, o1, noise):
    """Shots ``s0 .. s1 - 1`` (:func:`_shot_events` each, with one set of buffers grown as a
    shot needs), their recorded events written to the ``out_*`` arrays from ``o0`` on, never
    at or past ``o1``; the noise events generated per shot go to ``noise``. Returns the
    number written, or -1 when ``o1 - o0`` is too small (the caller retries with more)."""
    cap = 64
    t_buf = np.empty(cap, np.float64)
    a_buf = np.empty(cap, sig_anode.dtype)
    i_buf = np.empty(cap, sig_index.dtype)
    r_buf = np.empty(cap, np.bool_)
    last = np.empty(n_channels)        # each channel's last time: one array a block, not a shot
    o = o0
    for s in range(s0, s1):
        rate = noise_per_ns[s]
        mean = rate * gate_ns if rate > 0 else 0.0
        need = (sig_start[s + 1] - sig_start[s]) + int(mean + 8.0 * np.sqrt(mean) + 16.0)
        while True:
            if need > cap:
                cap = max(need, 2 * cap)
                t_buf = np.empty(cap, np.float64)
                a_buf = np.empty(cap, sig_anode.dtype)
                i_buf = np.empty(cap, sig_index.dtype)
                r_buf = np.empty(cap, np.bool_)
            w = _shot_events(s, sig_start, sig_time, sig_anode, sig_index, gate_start[s],
                             gate_ns, rate, anodes, n_channels, dead_time_ns, paralyzable, seed,
                             t_buf, a_buf, i_buf, r_buf, last)
            if w >= 0:
                break
            need = 2 * cap
        nz = 0
        for j in range(w):
            if i_buf[j] < 0:
                nz += 1
            if r_buf[j]:
                if o >= o1:
                    return -1
                out_shot[o] = s
                out_t[o] = t_buf[j]
                out_a[o] = a_buf[j]
                out_i[o] = i_buf[j]
                o += 1
        noise[s] = nz
    return o - o0


@numba.njit(cache=True, nogil=True, parallel=True)
def detect_shots(sig_start, sig_time, sig_anode, sig_index, gate_start, gate_ns, noise_per_ns,
                 anodes, n_channels, dead_time_ns, paralyzable, seed, spare=1):
    """The whole detector stage per shot, in parallel, writing only the recorded events.

    For each shot: its signal photons inside the gate, and noise (background photons and dark
    counts) as a Poisson process of rate ``noise_per_ns[s]`` over the gate, uniform over the
    anodes (every channel has the same dark rate), in time order; then dead time per channel
    (non-paralyzable or paralyzable). Noise comes from a counter-based RNG keyed by
    (seed, shot, j), so the result does not depend on how shots are split among threads.

    Shots run in blocks of :data:`BLOCK_SHOTS` in parallel, each block reusing one set of
    buffers and writing its recorded events into a region of a shared array reserved for it
    (its signal photons plus its expected noise with 10 standard deviations and 64 events to
    spare); the regions are then packed. A block that would overflow its region (which no
    run has yet met) makes the whole pass run again with twice the room: the same events
    (``spare``: the first pass's multiple of that allowance; the tests pass 0 to force a retry).

    Args:
        sig_start: (n_shots + 1,) offsets of each shot's signal photons in ``sig_*``.
        sig_time, sig_anode, sig_index: signal photons' time [ns], anode, traced-return index.
        gate_start: (n_shots,) gate opening [ns]; gate_ns: gate length [ns] (inf: no gate, and
            then no noise).
        noise_per_ns: (n_shots,) rate of noise events inside each shot's gate [1/ns].
    Returns:
        ``(shot, time_ns, anode, index, noise_per_shot)``: the recorded events by shot then
        time (``index`` -1 for noise), and the noise events generated per shot.
    """
    n_shots = gate_start.size
    n_blocks = (n_shots + BLOCK_SHOTS - 1) // BLOCK_SHOTS
    room = np.zeros(n_blocks + 1, np.int64)
    noise = np.zeros(n_shots, np.int64)
    used = np.zeros(n_blocks, np.int64)
    while True:
        for b in range(n_blocks):
            s0, s1 = b * BLOCK_SHOTS, min(n_shots, (b + 1) * BLOCK_SHOTS)
            mean = 0.0
            for s in range(s0, s1):
                if noise_per_ns[s] > 0 and gate_ns < np.inf:
                    mean += noise_per_ns[s] * gate_ns
            room[b + 1] = room[b] + (sig_start[s1] - sig_start[s0]) + spare * int(
                mean + 10.0 * np.sqrt(mean) + 64.0)
        total = room[n_blocks]
        t_all = np.empty(total, np.float64)
        s_all = np.empty(total, np.int64)
        a_all = np.empty(total, sig_anode.dtype)
        i_all = np.empty(total, sig_index.dtype)
        for b in numba.prange(n_blocks):
            used[b] = _block_events(
                b * BLOCK_SHOTS, min(n_shots, (b + 1) * BLOCK_SHOTS), sig_start, sig_time,
                sig_anode, sig_index, gate_start, gate_ns, noise_per_ns, anodes, n_channels,
                dead_time_ns, paralyzable, seed, s_all, t_all, a_all, i_all, room[b],
                room[b + 1], noise)
        if n_blocks == 0 or used.min() >= 0:
            break
        spare = max(1, 2 * spare)
    start = np.zeros(n_blocks + 1, np.int64)
    for b in range(n_blocks):
        start[b + 1] = start[b] + used[b]
    n_out = start[n_blocks]
    shot_out = np.empty(n_out, np.int64)
    t_out = np.empty(n_out, np.float64)
    a_out = np.empty(n_out, sig_anode.dtype)
    i_out = np.empty(n_out, sig_index.dtype)
    for b in numba.prange(n_blocks):
        src, dst = room[b], start[b]
        for j in range(used[b]):
            shot_out[dst + j] = s_all[src + j]
            t_out[dst + j] = t_all[src + j]
            a_out[dst + j] = a_all[src + j]
            i_out[dst + j] = i_all[src + j]
    return shot_out, t_out, a_out, i_out, noise


@numba.njit(cache=True, nogil=True, parallel=True)
def signal_hits(index, x_m, y_m, z_m):
    """(n_events, 3) float32 scattering points of the events: ``(x, y, z)[index]`` where
    ``index >= 0`` (signal), NaN for noise (``index`` -1)."""
    n = index.size
    out = np.empty((n, 3), np.float32)
    for j in numba.prange(n):
        i = index[j]
        if i >= 0:
            out[j, 0] = x_m[i]
            out[j, 1] = y_m[i]
            out[j, 2] = z_m[i]
        else:
            out[j, 0] = np.nan
            out[j, 1] = np.nan
            out[j, 2] = np.nan
    return out


@contextlib.contextmanager
def serial_while(busy: bool):
    """The detector's kernels on this thread alone for the block when ``busy`` (the tracer
    traces the next chunk on every core meanwhile: a parallel region would wait for a core
    at each call, 0.6-1.2 s of a six-beam 100 km granule's 216 chunks); their results do
    not depend on the thread count (counter-based random numbers, sums in return order)."""
    if not busy:
        yield
        return
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(old)
