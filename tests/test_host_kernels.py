"""The host stages' shortcuts (issue 43) give the bits of the code they shortcut: the
detector's path for shots without noise against its general path, and the footprint means'
ramps evaluated only where they are not at their float64 limits. No rendering."""
import math

import numpy as np
from scipy.special import ndtr

from lidar_mitsuba.detector import deadtime
from lidar_mitsuba.ground.dem import heights


def test_shots_without_noise_are_the_general_paths_events():
    """``detect_shots`` with a noise rate of 0 (its no-noise path: signal sorted at the head
    of the buffers) against a rate of 1e-300 per ns (the general path: the first noise gap,
    ~1e300 ns, ends past the gate, so it draws no noise event): the same recorded events and
    order, bit for bit, with ties in time (whole ns: a stable order), a shot of 100 photons
    (a long insertion sort) and shots past its 160 (the merge argsort), photons outside the
    gate, a gate at +inf (no surface), and both dead-time models."""
    rng = np.random.default_rng(7)
    n_shots = 600
    n_sig = rng.poisson(3.0, n_shots)
    n_sig[5], n_sig[77], n_sig[9] = 400, 170, 100        # the argsort's, and a long sort
    start = np.concatenate([[0], np.cumsum(n_sig)]).astype(np.int64)
    t = np.round(rng.uniform(-20.0, 220.0, start[-1]))     # ties, and some out of the gate
    anode = rng.integers(0, 16, t.size).astype(np.int16)
    index = np.arange(t.size, dtype=np.int32)
    gate = np.zeros(n_shots)
    gate[::50] = np.inf
    for paralyzable in (False, True):
        for channels in (16, 4):
            args = lambda rate: (start, t, anode, index, gate, 200.0,  # noqa: E731
                                 np.full(n_shots, rate), 16, channels, 3.0, paralyzable, 5,
                                 1)                # spare given, as pmt.detect gives it
            fast, general = deadtime.detect_shots(*args(0.0)), deadtime.detect_shots(*args(1e-300))
            assert fast[0].size > 0.5 * t.size
            for a, b in zip(fast, general):
                assert a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _axis_weights_numpy(p, *, posting_m, sigma_m):
    """The footprint means' axis weights as numpy evaluated them before issue 43: ``ndtr``
    and ``exp`` over every ramp of every stencil."""
    P = posting_m
    reach, n = heights._stencil(P, sigma_m)
    p = np.where(np.isfinite(p), p, 0.0)
    first = np.floor((p - reach) / P).astype(np.int64)
    u = (p[:, None] - (first[:, None] + np.arange(-1, n + 1)) * P) / sigma_m
    r = sigma_m * (u * ndtr(u) + np.exp(-0.5 * u * u) / math.sqrt(2.0 * math.pi))
    return first, (r[:, :-2] - 2.0 * r[:, 1:-1] + r[:, 2:]) / P


def test_footprint_weights_are_the_numpy_expressions_bits():
    """``_axis_weights`` (``ndtr`` and ``exp`` only where ``-40 < u < 9``, the rest compiled)
    against the numpy expression over every ramp: the same bits for positions swept densely
    across the pixels (ramp arguments crossing the -40 and 9 limits, the -37.7 and -38.6
    where ``ndtr`` and ``exp`` reach their limits and the 8.29 from which ``ndtr`` is 1), NaN
    positions among them, at footprint sigmas from 1 mm to 30 m on 100 m and 2 m postings;
    and the ramp's mean over a dense sweep of ``u`` in [8.29, 40] is ``sigma u`` exactly."""
    u = np.linspace(8.2925, 40.0, 400_001)
    for sigma_m in (1e-3, 2.5, 30.0):
        r = sigma_m * (u * ndtr(u) + np.exp(-0.5 * u * u) / math.sqrt(2.0 * math.pi))
        assert r.tobytes() == (sigma_m * u).tobytes()
    for posting_m, p in ((100.0, np.linspace(-150.0, 450.0, 24_001)),
                         (2.0, np.linspace(-3.0, 5.0, 1_601))):
        p = np.concatenate([p, [np.nan, 0.0, -0.0]])
        for sigma_m in (1e-3, 0.37, 2.5, 30.0):
            first, w = heights._axis_weights(p, posting_m=posting_m, sigma_m=sigma_m)
            first0, w0 = _axis_weights_numpy(p, posting_m=posting_m, sigma_m=sigma_m)
            assert first.tobytes() == first0.tobytes()
            assert w.shape == w0.shape and w.tobytes() == w0.tobytes(), (posting_m, sigma_m)


def test_kernels_load_once_a_process_beside_the_caller():
    """``load_kernels`` loads the first serial kernels on a thread of its own, once a process:
    afterwards they have their compiled version (from numba's cache, or none when a kernel
    is not cached: then it starts nothing), and a second call starts nothing."""
    from lidar_mitsuba import precompile
    loader = precompile.load_kernels()
    if loader is not None:
        loader.join(120.0)
        assert not loader.is_alive()
        assert deadtime.shot_stats.signatures and heights._stencil_sums.signatures
        assert heights._ramp_arguments.signatures and heights._hat_means.signatures
    assert precompile.load_kernels() is None


def test_a_granules_detector_runs_on_one_thread_for_every_chunk(monkeypatch):
    """``trace.stream.run`` under a trace launcher (a granule's sections) detects every chunk
    with numba on the simulating thread alone, the last one too (a parallel region whose
    second thread is busy elsewhere spins at its barrier); outside a granule the last chunk,
    with nothing left to trace, has every thread. Synthetic returns, no rendering."""
    import numba
    from concurrent.futures import ThreadPoolExecutor
    from lidar_mitsuba.detector.records import Returns
    from lidar_mitsuba.instrument import Instrument
    from lidar_mitsuba.trace import stream

    class Source:
        def launch(self, a, b, seed):
            ret = Returns.at_times(np.full((b - a) * 4, 3.3e6), paths_per_shot=4)
            return type("Done", (), {"result": lambda self: ret})()

    seen = []
    detect = stream.pmt.detect

    def counting(*args, **kw):
        seen.append(numba.get_num_threads())
        return detect(*args, **kw)
    monkeypatch.setattr(stream.pmt, "detect", counting)
    every = numba.get_num_threads()
    runs = {"granule": ThreadPoolExecutor(1), "alone": None}
    for name, launcher in runs.items():
        monkeypatch.setattr(stream, "trace_launcher", lambda launcher=launcher: launcher)
        seen.clear()
        stream.run(source=Source(), detectors={"d": Instrument()}, z_ref_m=np.zeros(30),
                   seed=1, chunk_shots=10)
        assert seen[:2] == [1, 1] and len(seen) == 3
        assert seen[2] == (1 if name == "granule" else every)
    runs["granule"].shutdown()


def test_block_extents_are_numpys_minima_and_maxima():
    """``block_extents`` (one pass) against numpy's per-block expression it replaced in
    ``DEM.windows``: finite points only (NaN and infinite coordinates among them, a block
    with none, a short last block, signed zeros), the same found flags and bits."""
    rng = np.random.default_rng(5)
    n, block = 10_000, 700
    x, y = rng.normal(0.0, 1e5, n), rng.normal(0.0, 1e5, n)
    x[rng.random(n) < 0.1], y[rng.random(n) < 0.1] = np.nan, np.inf
    x[1400:2100] = np.nan                                 # block 2: no finite point
    x[2100:2110], y[2100:2110] = -0.0, 0.0
    found, x_lo, x_hi, y_lo, y_hi = heights.block_extents(x, y, block)
    assert found.size == -(-n // block) and not found[2] and found.sum() == found.size - 1
    for k, a in enumerate(range(0, n, block)):
        xs, ys = x[a:a + block], y[a:a + block]
        ok = np.isfinite(xs) & np.isfinite(ys)
        assert found[k] == ok.any()
        if ok.any():
            want = (xs[ok].min(), xs[ok].max(), ys[ok].min(), ys[ok].max())
            assert (x_lo[k], x_hi[k], y_lo[k], y_hi[k]) == want


def _choose_returns_loop(start, weight, w_max, need, exchangeable, seed):
    """``choose_returns`` as a plain loop, a shuffle buffer a shot (the kernel before issue
    43's session 24 allocated one a shot): the reference for its picks."""
    u = deadtime._uniform
    off = np.concatenate([[0], np.cumsum(need)]).astype(np.int64)
    out, ran_out = np.empty(off[-1], np.int64), np.zeros(need.size, bool)
    for s, k in enumerate(need):
        a, m = start[s], start[s + 1] - start[s]
        scratch, pos, got, j, r = list(range(a, a + m)), off[s], 0, 0, 0
        while got < k and j < m:
            if exchangeable:
                i = a + j
            else:
                pick = j + min(int(u(seed, s, r) * (m - j)), m - j - 1)
                r += 1
                i = scratch[pick]
                scratch[pick], scratch[j] = scratch[j], i
            j += 1
            r += 1
            if u(seed, s, r - 1) * w_max < weight[i]:
                out[pos], pos, got = i, pos + 1, got + 1
        if got < k:
            ran_out[s] = True
            cw = np.cumsum(weight[a:a + m])
            while got < k:
                if m == 0 or cw[-1] <= 0.0:
                    out[pos] = a
                else:
                    out[pos] = a + min(np.searchsorted(cw, u(seed, s, r) * cw[-1], "right"),
                                       m - 1)
                    r += 1
                pos, got = pos + 1, got + 1
    return out, ran_out, off


def test_choose_returns_blocks_pick_as_a_buffer_a_shot():
    """``choose_returns`` (a shuffle buffer a block of 256 shots) against the plain loop
    with one a shot: the same picks, run-out shots and offsets, for exchangeable returns and
    shuffled ones, over 600 shots (three blocks, the last short) with shots of no returns,
    picks past a shot's returns (the fallback by weight) and zero weights."""
    rng = np.random.default_rng(3)
    n_shots = 600
    start = np.concatenate([[0], np.cumsum(rng.integers(0, 12, n_shots))]).astype(np.int64)
    weight = rng.uniform(0.0, 1.0, start[-1])
    weight[::9] = 0.0
    need = rng.integers(0, 5, n_shots).astype(np.int64)
    need[rng.random(n_shots) < 0.05] = 20                # more picks than returns
    for exchangeable in (True, False):
        got = deadtime.choose_returns(start, weight, 1.0, need, exchangeable, 99)
        want = _choose_returns_loop(start, weight, 1.0, need, exchangeable, 99)
        assert got[1].any()
        for g, w in zip(got, want):
            assert np.array_equal(g, w)


def test_the_compile_bar_is_one_short_line_naming_the_stage():
    """The first run's compile bar names the stage compiling now, on one line that a
    100-column terminal holds with its timer (a long line wraps and repeats at each refresh)."""
    from lidar_mitsuba import precompile
    steps = [(*precompile.STAGE_BAR[s], None) for s in precompile.STAGE_BAR]
    for i, (name, _, _) in enumerate(steps):
        words = precompile._compiling(i, steps)
        assert name in words and f"{i + 1}/{len(steps)}" in words
        assert len(words) + len(": 00:00 of ~99s") <= 100, words
