"""The typed records between the stages (lidar_mitsuba.detector.records): Returns and Detections.
Pure numpy; exact comparisons (these are bookkeeping operations, no sampling)."""
import dataclasses

import numpy as np
import pytest

from lidar_mitsuba.constants import C_M_PER_NS
from lidar_mitsuba.detector.records import Detections, Returns

T0 = 2 * 496e3 / C_M_PER_NS          # round-trip time to h = 0 [ns]


def traced(rng, n_shots=10, k=6, depth_max=1):
    """Returns like a trace makes them: sorted by shot, uint32 shots, some shots empty,
    a varying number of returns per shot."""
    per = rng.integers(0, 2 * k, n_shots)
    per[[2, 7]] = 0                                   # shots without a return
    n = int(per.sum())
    return Returns(shot=np.repeat(np.arange(n_shots), per).astype(np.uint32),
                   time_ns=T0 + rng.normal(0, 0.4, n), weight=rng.uniform(0.1, 2, n).astype(np.float32),
                   x_m=rng.normal(0, 3, n).astype(np.float32), y_m=rng.normal(0, 3, n).astype(np.float32),
                   z_m=rng.normal(0, 1, n).astype(np.float32),
                   depth=rng.integers(1, depth_max + 1, n).astype(np.uint8),
                   n_shots=n_shots, paths_per_shot=k)


def assert_returns_equal(a: Returns, b: Returns):
    for key in Returns.ARRAYS:
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)
        assert getattr(a, key).dtype == getattr(b, key).dtype, key
    assert (a.n_shots, a.paths_per_shot) == (b.n_shots, b.paths_per_shot)


def test_slice_shots_then_concatenate_is_the_identity(rng):
    r = traced(rng)
    cuts = [0, 3, 4, 7, 10]                           # chunks of 3, 1, 3, 3 shots
    parts = [(r.slice_shots(a, b), a) for a, b in zip(cuts[:-1], cuts[1:])]
    for (p, a), b in zip(parts, cuts[1:]):
        assert p.n_shots == b - a and p.paths_per_shot == r.paths_per_shot
        assert p.shot.dtype == np.uint32 and (p.shot.size == 0 or p.shot.max() < b - a)
        assert len(p) == np.count_nonzero((r.shot >= a) & (r.shot < b))
    back = Returns.concatenate(parts, n_shots=r.n_shots)
    assert back.shot.dtype == np.int64                # global indices once joined
    for key in Returns.ARRAYS:
        np.testing.assert_array_equal(getattr(back, key), getattr(r, key), err_msg=key)
    assert back.n_shots == r.n_shots and back.paths_per_shot == r.paths_per_shot
    # an empty slice (shots 2..2) and the empty join
    e = r.slice_shots(2, 3)
    assert len(e) == 0 and e.n_shots == 1
    empty = Returns.concatenate([], n_shots=5)
    assert len(empty) == 0 and empty.n_shots == 5
    # one chunk from shot 0 is joined without copying its arrays (only the shots widen)
    one = Returns.concatenate([(r, 0)], n_shots=r.n_shots)
    assert one.shot.dtype == np.int64 and np.array_equal(one.shot, r.shot)
    assert all(getattr(one, k) is getattr(r, k) for k in Returns.ARRAYS if k != "shot")


def test_select_keeps_the_trace_header(rng):
    r = traced(rng)
    keep = r.weight > 1.0
    s = r.select(keep)
    assert len(s) == keep.sum() and (s.n_shots, s.paths_per_shot) == (r.n_shots, r.paths_per_shot)
    np.testing.assert_array_equal(s.time_ns, r.time_ns[keep])


def test_moved_shifts_points_and_times_consistently(rng):
    """Tracing a copy of the surface displaced by -dz and moving the returns back by +dz must
    give the returns of the surface itself: z up by dz, the round trip shorter by 2 dz / c
    (in float64: a millimetre at orbital range is 6.7 ps), x and y by dx, dy."""
    r = traced(rng)
    dx = rng.normal(0, 100, r.n_shots)
    dy = rng.normal(0, 100, r.n_shots)
    dz = rng.normal(0, 10, r.n_shots)
    dz[3] = 1e-3                                      # one shot moved by a millimetre
    m = r.moved(dx_m=dx, dy_m=dy, dz_m=dz)
    s = r.shot
    np.testing.assert_array_equal(m.time_ns, r.time_ns - 2.0 * dz[s] / C_M_PER_NS)
    assert m.time_ns.dtype == np.float64
    # the height of each return from its time changes by exactly dz (float64 rounding)
    h = 496e3 - C_M_PER_NS * r.time_ns / 2
    h_moved = 496e3 - C_M_PER_NS * m.time_ns / 2
    np.testing.assert_allclose(h_moved - h, dz[s], rtol=0, atol=1e-9)
    for key, d in (("x_m", dx), ("y_m", dy), ("z_m", dz)):
        assert getattr(m, key).dtype == np.float32          # rounded once, to float32
        np.testing.assert_allclose(getattr(m, key), getattr(r, key).astype(np.float64) + d[s],
                                   rtol=2.0 ** -24, atol=0, err_msg=key)
    for key in ("shot", "weight", "depth"):
        np.testing.assert_array_equal(getattr(m, key), getattr(r, key))
    # no displacement: nothing changes
    zero = np.zeros(r.n_shots)
    assert_returns_equal(r.moved(dx_m=zero, dy_m=zero, dz_m=zero), r)


def test_at_times_builds_first_surface_returns():
    t = T0 + np.arange(12, dtype=float)
    r = Returns.at_times(t, paths_per_shot=4)
    assert (r.n_shots, r.paths_per_shot, len(r)) == (3, 4, 12)
    np.testing.assert_array_equal(r.shot, np.repeat([0, 1, 2], 4))
    np.testing.assert_array_equal(r.time_ns, t)
    assert r.time_ns.dtype == np.float64
    np.testing.assert_array_equal(r.weight, np.ones(12, np.float32))
    assert np.all(r.depth == 1) and np.all(r.x_m == 0) and np.all(r.z_m == 0)
    assert r.single_bounce
    w = np.linspace(0.5, 1.5, 12)
    np.testing.assert_array_equal(Returns.at_times(t, paths_per_shot=4, weight=w).weight, w)
    # it feeds the chunk bookkeeping like a trace does
    np.testing.assert_array_equal(r.slice_shots(1, 3).time_ns, t[4:])


def test_single_bounce(rng):
    r = traced(rng, depth_max=1)
    assert r.single_bounce
    multi = traced(rng, depth_max=3)
    assert np.any(multi.depth > 1) and not multi.single_bounce
    assert Returns.empty(n_shots=3, paths_per_shot=8).single_bounce


def detections(rng, n_shots, n_returns):
    n = int(rng.integers(3, 9))
    idx = rng.integers(0, n_returns, n)
    idx[::3] = -1                                     # noise photons
    sig = idx >= 0
    hit = np.full((n, 3), np.nan, np.float32)
    hit[sig] = rng.normal(0, 1, (sig.sum(), 3))
    return Detections(shot=np.sort(rng.integers(0, n_shots, n)),
                      channel=rng.integers(0, 4, n).astype(np.int16),
                      anode=rng.integers(0, 16, n).astype(np.int16), time_ns=T0 + rng.normal(0, 1, n),
                      return_index=idx, is_signal=sig, hit_xyz_m=hit,
                      arrivals_per_shot=rng.poisson(3, n_shots),
                      mean_photons_per_shot=rng.uniform(1, 5, n_shots))


def test_detections_concatenate_offsets_shots_and_return_indices(rng):
    """Chunks of 5, 3 and 4 shots with 40, 0 and 25 traced returns: shots shift by the chunk's
    first shot, return indices by the returns before it, and noise (-1) stays -1."""
    chunks = [(5, 40), (3, 0), (4, 25)]
    parts, a, r0 = [], 0, 0
    for n_shots, n_ret in chunks:
        d = detections(rng, n_shots, max(n_ret, 1))
        if n_ret == 0:                                # no traced return: only noise
            d = dataclasses.replace(d, return_index=np.full(len(d), -1),
                                    is_signal=np.zeros(len(d), bool))
        parts.append((d, a, r0))
        a += n_shots
        r0 += n_ret
    out = Detections.concatenate(parts)
    assert len(out) == sum(len(d) for d, *_ in parts)
    k = 0
    for d, a, r0 in parts:
        sl = slice(k, k + len(d))
        np.testing.assert_array_equal(out.shot[sl], d.shot + a)
        np.testing.assert_array_equal(out.return_index[sl],
                                      np.where(d.return_index >= 0, d.return_index + r0, -1))
        for name in ("channel", "anode", "time_ns", "is_signal"):
            np.testing.assert_array_equal(getattr(out, name)[sl], getattr(d, name))
        np.testing.assert_array_equal(out.hit_xyz_m[sl], d.hit_xyz_m)
        k += len(d)
    assert np.all((out.return_index == -1) == ~out.is_signal)
    assert np.all(out.return_index[out.is_signal] >= 0)
    # per-shot arrays are joined shot by shot
    np.testing.assert_array_equal(out.arrivals_per_shot,
                                  np.concatenate([d.arrivals_per_shot for d, *_ in parts]))
    assert out.mean_photons_per_shot.size == 12 and out.hit_xyz_m.shape == (len(out), 3)
    # a single chunk from shot 0 and return 0 is the whole run as it is
    assert Detections.concatenate([(parts[0][0], 0, 0)]) is parts[0][0]


def test_detections_are_frozen(rng):
    d = detections(rng, 3, 10)
    with pytest.raises(AttributeError):
        d.shot = d.shot + 1


def test_at_times_refuses_a_partial_shot():
    with pytest.raises(ValueError, match="not a whole number of shots"):
        Returns.at_times(np.zeros(10), paths_per_shot=4)
