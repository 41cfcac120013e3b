"""ATL06-style surface finding and first-photon-bias (FPB) correction (lidar_mitsuba.products.atl06),
end to end on simulated tracks; the FPB building blocks are tested in test_fpb.py.

Tolerances. Every Monte Carlo estimate is compared with its truth within Z = 4.5 standard
errors (two-sided p ~ 7e-6 each), the standard error taken from the sample: binomial for
fractions, sd / sqrt(n) for means, sd * sqrt((kurtosis - 1) / (4 n)) for standard deviations,
and batch means (20 independent blocks of shots) for the dead-time-weighted estimators, whose
terms are correlated within a block. Segments overlap by half, so segment statistics use every
other segment (those are disjoint, hence independent); Poisson errors for background counts.
All seeds are fixed, so the file is deterministic; the tolerances say how likely a different
seed would be to fail.
"""
import json
import math

import numpy as np
import pytest
from scipy import stats

from lidar_mitsuba.products import atl06
from lidar_mitsuba.detector import pmt
from lidar_mitsuba.instrument import Instrument
from lidar_mitsuba.constants import C_M_PER_NS
from closed_forms import T0, Z, gaussian_returns


# ---------------------------------------------------------- 1. fractal track with background

@pytest.fixture(scope="module")
def fractal_tracks():
    from lidar_mitsuba.run import simulate
    from lidar_mitsuba.ground.surface import SurfaceSpec
    out = {}
    for k, bg in enumerate((1.0, 5.0, 10.0)):
        out[bg] = simulate(instrument=Instrument(beam="strong", background_mhz=bg),
                           surface=SurfaceSpec(kind="fractal", p=1.8, size_m=512),
                           shots=6000, seed=100 + k, progress=False)
    return out


def _table(res):
    inst = res.instrument
    d = res.detections
    return atl06.fit_segments(
        photon_along_m=res.along_track_m[d.shot], h_m=res.h_m, shot=d.shot, channel=d.channel,
        n_shots=res.n_shots, shot_along_m=res.along_track_m, n_channels=inst.channels,
        dead_time_ns=inst.effective_dead_time_ns, paralyzable=inst.paralyzable,
        pulse_sigma_ns=inst.pulse_sigma_ns, range_gate_m=inst.range_gate_m,
        z_ref_m=res.z_ref_m, gate_center_h_m=res.z_ref_m,
        footprint_sigma_m=inst.footprint_sigma_m)


@pytest.mark.parametrize("bg", [1.0, 5.0, 10.0])
def test_fractal_track_unbiased_within_sigma(fractal_tracks, bg):
    """Strong beam over the p = 1.8 fractal (6000 shots, 4.2 km, 208 segments, 104 of them
    disjoint) with solar background. Over alternate (independent) unflagged segments, n of them:
    * mean(h_li - h_ref) is within 4 sqrt(mean(h_li_sigma^2) / n): unbiased within the stated
      errors;
    * |h_li - h_ref| < 3 h_li_sigma in ~99 %: the failures are at most the count that a
      1 % rate exceeds with probability < 1e-3 (binomial); and |z| < 1 in 50-87 % (68 % +-
      4 binomial sigma), so h_li_sigma is not inflated either;
    * the background estimate (pooled) is within Z Poisson errors of the truth
      (background_mhz * fill factor * PDE)."""
    res = fractal_tracks[bg]
    tab = _table(res)
    alt = tab.good & (np.arange(len(tab)) % 2 == 0)
    n = int(alt.sum())
    assert n >= 0.9 * (len(tab) + 1) // 2
    d = (tab.h_li - tab.h_ref_m)[alt]
    sig = tab.h_li_sigma[alt]
    tol = 4 * math.sqrt(np.mean(sig ** 2) / n)
    z = np.abs(d / sig)
    max_fail = int(stats.binom.isf(1e-3, n, 0.01))
    inst = res.instrument
    true = inst.background_mhz * inst.fill_factor * inst.pde
    n_bg = tab.bckgrd_n_photons[alt].sum()
    obs = n_bg / tab.bckgrd_exposure_ns[alt].sum() * 1e3
    est = atl06.corrected_background_mhz(obs, n_channels=inst.channels,
                                         dead_time_ns=inst.dead_time_ns, paralyzable=False)
    print(f"\nbg {bg} MHz: {n} segments, mean(h_li - h_ref) = {100 * d.mean():.2f} cm "
          f"(tol {100 * tol:.2f}), uncorrected {100 * np.mean((tab.h_mean - tab.h_ref_m)[alt]):.2f}"
          f" cm, |z|<3: {np.mean(z < 3):.3f} (fails {np.sum(z >= 3)} <= {max_fail}), "
          f"|z|<1: {np.mean(z < 1):.3f}, bckgrd {est:.3f} +- {est / math.sqrt(n_bg):.3f} MHz "
          f"(true {true:.3f})")
    assert abs(d.mean()) < tol
    assert np.sum(z >= 3) <= max_fail
    assert 0.5 < np.mean(z < 1) < 0.87
    assert abs(est - true) < Z * est / math.sqrt(n_bg)


def test_fractal_tracks_pooled(fractal_tracks):
    """The three tracks together (~310 independent segments): mean(h_li - h_ref) within
    4 sqrt(sum(h_li_sigma^2)) / n, about 0.5 cm. (The strong beam's uncorrected bias here is
    only ~0.5-1 cm -- 3.3 detectable photons over 16 channels -- so this is the sharper check;
    one track alone could not tell a corrected from an uncorrected height.)"""
    d, sig, du = [], [], []
    for res in fractal_tracks.values():
        tab = _table(res)
        alt = tab.good & (np.arange(len(tab)) % 2 == 0)
        d.append((tab.h_li - tab.h_ref_m)[alt])
        du.append((tab.h_mean - tab.h_ref_m)[alt])
        sig.append(tab.h_li_sigma[alt])
    d, du, sig = (np.concatenate(a) for a in (d, du, sig))
    tol = 4 * math.sqrt(np.sum(sig ** 2)) / d.size
    print(f"\npooled: {d.size} segments, mean(h_li - h_ref) = {100 * d.mean():.2f} cm "
          f"(tol {100 * tol:.2f}), uncorrected {100 * du.mean():.2f} cm")
    assert abs(d.mean()) < tol


def test_atl03_file_to_segments_and_back(fractal_tracks, tmp_path):
    """segments_from_atl03 on a written ATL03 file matches fitting in memory; write/read
    round-trips with units; summarize is JSON-safe; a failed write leaves nothing behind."""
    from lidar_mitsuba.products import atl03
    res = fractal_tracks[5.0]
    f03 = atl03.write(res, tmp_path / "track.h5")
    tab = atl06.segments_from_atl03(f03)
    ref = _table(res)
    np.testing.assert_allclose(tab.h_li, ref.h_li, equal_nan=True)
    np.testing.assert_array_equal(tab.flags, ref.flags)

    out = atl06.write(tab, tmp_path / "atl06.h5")
    back = atl06.read(out)
    for name in atl06.FIELDS:
        np.testing.assert_array_equal(getattr(back, name), getattr(tab, name))
    import h5py
    with h5py.File(out) as f:
        assert f["land_ice_segments/bckgrd"].attrs["units"] == "MHz"
        assert f["land_ice_segments/h_li"].attrs["units"] == "meters"
        assert "description" in f["land_ice_segments/fpb_corr_m"].attrs
    s = atl06.summarize(tab)
    json.dumps(s, allow_nan=False)
    json.dumps(tab.to_dict(), allow_nan=False)
    assert s["n_good"] + s["n_flagged"] == len(tab)

    with pytest.raises(TypeError):
        atl06.write(tab, tmp_path / "bad.h5", attrs={"x": object()})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["atl06.h5", "track.h5"]


# ------------------------------------------------------------------------------ 2. flags

def test_flagged_segments_are_kept_marked_and_left_out(rng):
    """A gap in the photons (too few photons) and a saturating return (~60 photons on each
    of 4 channels: P_alive N C < 3 at the tail) are flagged with their reasons, kept in the
    table, and left out of summarize; the ordinary 3-photon segments before them are not."""
    n_shots = 1800
    along = np.arange(n_shots) * 0.7
    gate = np.full(n_shots, T0)
    parts = []
    for sp, region in ((3.0, along < 800), (240.0, along >= 800)):
        inst = Instrument(beam="weak", signal_photons=sp, fill_factor=1.0, pde=1.0,
                          background_mhz=2.0)
        det = pmt.detect(gaussian_returns(rng, n_shots, inst.pulse_sigma_ns, k=400), inst, rng,
                         gate_center_ns=gate)
        keep = region[det.shot] & ~((along[det.shot] >= 300) & (along[det.shot] < 400))
        parts.append((det.shot[keep], det.channel[keep], det.time_ns[keep]))
    shot, channel, t = (np.concatenate(a) for a in zip(*parts))
    h = inst.altitude_m - C_M_PER_NS / 2 * t
    tab = atl06.fit_segments(
        photon_along_m=along[shot], h_m=h, shot=shot, channel=channel, n_shots=n_shots,
        shot_along_m=along, n_channels=4, dead_time_ns=3.0, paralyzable=False,
        pulse_sigma_ns=inst.pulse_sigma_ns, range_gate_m=30.0, z_ref_m=np.zeros(n_shots),
        gate_center_h_m=np.zeros(n_shots))
    gap = (tab.x_atc > 320) & (tab.x_atc < 380)
    sat = tab.x_atc > 840
    assert gap.any() and sat.any()
    assert np.all(tab.flags[gap] & atl06.FLAG_BITS["too_few_photons"])
    assert np.all(tab.flags[sat] & atl06.FLAG_BITS["fpb_dead"])
    assert "fpb_dead" in tab.flag_reasons(int(np.flatnonzero(sat)[0]))
    assert np.all(tab.atl06_quality_summary[gap | sat] == 1)
    ok = tab.good
    ordinary = (tab.x_atc < 280) | ((tab.x_atc > 420) & (tab.x_atc < 780))
    assert np.all(ok[ordinary]) and not np.any(ok & (gap | sat))
    s = atl06.summarize(tab)
    assert s["n_good"] == ok.sum() and s["n_flagged"] == len(tab) - ok.sum()
    assert s["h_li_minus_ref_mean_m"] == pytest.approx(np.mean(tab.h_li[ok]))


# ---------------------------------------------------------- compiled fit = numpy reference

def _same_tables(a, b):
    """Every column equal: integers exactly, floats to 1e-9 relative (numba sums in another
    order than numpy's pairwise sums) with NaN where NaN."""
    for name in atl06.FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype, name
        if x.dtype.kind in "iu":
            np.testing.assert_array_equal(x, y, err_msg=name)
        else:
            np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-12, equal_nan=True, err_msg=name)


@pytest.mark.parametrize("paralyzable,bg_mhz,signal", [(False, 5.0, 3.0), (True, 5.0, 3.0),
                                                        (False, 300.0, 3.0), (True, 300.0, 3.0),
                                                        (False, 2.0, 240.0), (True, 0.0, 60.0)])
def test_compiled_fit_is_the_numpy_reference(rng, paralyzable, bg_mhz, signal):
    """The numba kernel (the default) against the step-by-step numpy reference on the same
    photons, across the regimes the reference's branches cover: weak signal, 300 MHz
    background (dead-time-corrected background, the paralyzable one through Lambert W),
    saturation (fpb_dead, fpb_gain), a photon gap (too few photons), with and without gate
    centres; every column of every segment agrees."""
    n_shots = 1500
    along = np.arange(n_shots) * 0.7
    inst = Instrument(beam="weak", signal_photons=signal, background_mhz=bg_mhz,
                      paralyzable=paralyzable)
    det = pmt.detect(gaussian_returns(rng, n_shots, inst.pulse_sigma_ns, k=400), inst, rng,
                     gate_center_ns=np.full(n_shots, T0))
    keep = ~((along[det.shot] >= 300) & (along[det.shot] < 400))           # a gap
    shot, channel = det.shot[keep], det.channel[keep]
    h = inst.altitude_m - C_M_PER_NS / 2 * det.time_ns[keep]
    h = h + 0.02 * along[shot]                                              # a 2 % slope
    for gate in (np.zeros(n_shots), None):
        kw = dict(photon_along_m=along[shot], h_m=h, shot=shot, channel=channel,
                  n_shots=n_shots, shot_along_m=along, n_channels=inst.channels,
                  dead_time_ns=3.0, paralyzable=paralyzable,
                  pulse_sigma_ns=inst.pulse_sigma_ns, range_gate_m=30.0,
                  z_ref_m=0.02 * along, gate_center_h_m=gate, footprint_sigma_m=2.5)
        ref = atl06.fit_segments(**kw, engine="reference")
        _same_tables(ref, atl06.fit_segments(**kw, engine="compiled"))
        assert (ref.flags != 0).any()                       # the gap at least
        assert ref.good.any() == (signal < 100)      # saturated: every segment fpb-flagged


def test_compiled_fit_on_a_simulated_track(fractal_tracks):
    res = fractal_tracks[10.0]
    _same_tables(atl06.segments_from_result(res, engine="reference"),
                 atl06.segments_from_result(res, engine="compiled"))
    with pytest.raises(ValueError, match="engine"):
        atl06.segments_from_result(res, engine="fast")


def test_compiled_fit_in_blocks_on_threads_is_bit_identical(monkeypatch, fractal_tracks):
    """The compiled fit split into contiguous blocks of segments on the host's threads gives
    the same bits as one block (segments are independent; each writes its own row)."""
    res = fractal_tracks[10.0]
    one = atl06.segments_from_result(res, engine="compiled")
    monkeypatch.setattr(atl06, "_SEGMENTS_PER_THREAD_MIN", 1)
    monkeypatch.setattr(atl06, "host_threads", lambda: 7)      # 7 uneven blocks
    split = atl06.segments_from_result(res, engine="compiled")
    for name in atl06.FIELDS:
        np.testing.assert_array_equal(getattr(one, name), getattr(split, name), err_msg=name)


def test_the_fit_s_sorts_are_numpy_s(rng):
    """The compiled fit's sorts (lidar_mitsuba.products.atl06.sorting): ``sort`` gives
    numpy's sorted values and ``argsort`` numpy's stable order, on the cases a quicksort, a
    merge sort and a distribution into buckets get wrong when they are wrong (sizes about
    the runs of 16 and the fewest distributed, ties, runs already sorted either way, one
    value repeated, a crowded bucket beside an outlier, infinities, a spread too small to
    scale, -0.0 beside 0.0); a NaN gets the merge sort's order in both."""
    from lidar_mitsuba.products.atl06 import sorting
    cases = [rng.normal(0, 1, n) for n in (0, 1, 2, 15, 16, 17, 33, 120, 257, 2000)]
    cases += [np.round(rng.normal(0, 3, 300)) / 3, np.sort(rng.normal(0, 1, 100)),
              np.sort(rng.normal(0, 1, 100))[::-1].copy(), np.full(50, 0.25),
              np.r_[rng.normal(0, 0.1, 150), 1e3, -30.0],          # (a bucket of ~150)
              np.r_[rng.normal(0, 1, 40), np.inf, -np.inf], np.r_[np.zeros(20), 5e-324],
              np.r_[np.round(rng.normal(0, 1, 60)), np.full(9, -0.0)]]
    for a in cases:
        np.testing.assert_array_equal(sorting.sort(a), np.sort(a))
        np.testing.assert_array_equal(sorting.argsort(a), np.argsort(a, kind="stable"))
    a = np.array([1.0, np.nan, 0.0, 2.0, np.nan, -1.0])
    np.testing.assert_array_equal(sorting.sort(a), a[sorting.argsort(a)])


def test_the_fit_s_reused_orders_are_its_sorts(rng):
    """The orders the compiled fit reuses instead of sorting again (issue 43) are the sorts'
    to the bit: ``sort_and_order`` gives ``sort``'s values and ``argsort``'s order (no order
    for an array with a zero, whose -0.0 and 0.0 may trade places); ``merged_order`` gives
    ``argsort`` of the extended window's residuals from the window's order, on windows of
    ties, an empty one, one without residuals above it, and where its preconditions fail (a
    selection outside the extended window, or not below the rest: then argsort itself)."""
    from lidar_mitsuba.products.atl06 import sorting
    cases = [rng.normal(0, 1, n) for n in (1, 2, 15, 16, 17, 120, 257)]
    cases += [np.round(rng.normal(0, 3, 300)) / 3, np.r_[rng.normal(0, 0.1, 150), 1e3, -30.0],
              np.r_[np.round(rng.normal(0, 1, 60)), np.full(9, -0.0)], np.zeros(0)]
    for a in cases:
        values, order = sorting.sort_and_order(a)
        assert values.tobytes() == sorting.sort(a).tobytes()
        expect = np.argsort(a, kind="stable") if not (a == 0).any() else np.zeros(0, int)
        np.testing.assert_array_equal(order, expect)
    for r in (np.round(rng.normal(0, 2, 300), 2), rng.normal(0, 1, 40), np.zeros(0)):
        for half_w, extra in ((1.5, 0.9), (3.0, 0.9), (10.0, 0.0), (0.0, 0.9)):
            ext = (r > -half_w) & (r < half_w + extra)
            for sel in (np.abs(r) < half_w, np.abs(r - 0.3) < half_w, rng.random(r.size) < 0.5):
                got = sorting.merged_order(r, ext, sel, sorting.argsort(r[sel]), r[ext])
                np.testing.assert_array_equal(got, np.argsort(r[ext], kind="stable"))
            got = sorting.merged_order(r, ext, ext & False, np.zeros(0, np.int64), r[ext])
            np.testing.assert_array_equal(got, np.argsort(r[ext], kind="stable"))


def test_dead_time_weights_from_the_residuals_order_are_the_searched_ones(rng):
    """The non-paralyzable dead-time weights from the residuals' sorted order (both ends of
    each photon's dead-time window moving up, no search) equal, bit for bit, those found by
    numpy's binary search in the sorted times (the weights' definition: 1 / the fraction of
    the other N C - 1 channel-pulses not dead at the photon): photons within a dead time of
    each other, ties (equal residuals, and distinct ones whose times round to one value)."""
    from lidar_mitsuba.products.atl06 import kernel, sorting
    half_c, dead_ns, npc = 0.149896229, 3.0, 57 * 16 - 1
    r = np.round(rng.uniform(-1.5, 2.5, 400), 2)            # ~1 per cm: ties, dense
    r[:3] = [0.1, np.nextafter(0.1, 1.0), 0.1]
    for rr in (r, r[:37], r[:0]):
        t = -rr / half_c
        ts = np.sort(t)
        dead = np.searchsorted(ts, t, "left") - np.searchsorted(ts, t - dead_ns, "right")
        w = 1.0 / (1.0 - dead / npc)
        w2 = kernel._dead_time_weights_ordered(rr, sorting.argsort(rr), 57, 16, dead_ns, half_c)
        np.testing.assert_array_equal(w2, w)
        assert rr.size == 0 or w.max() > 1.0


def test_compiled_reference_heights_are_the_numpy_loop_to_the_bit(rng):
    """The truth column h_ref_m, compiled (numpy's pairwise sums replayed), equals the numpy
    loop bit for bit: segments of 0 to 300 shots (both sides of numpy's 8- and 128-element
    blocks), singular ones (one shot, all shots at one place) and ordinary ones."""
    from lidar_mitsuba import numeric
    from lidar_mitsuba.products.atl06 import kernel
    lengths = np.concatenate([np.arange(0, 300), [1, 1, 57, 57, 58]])
    s0 = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    s1 = s0 + lengths
    along = np.sort(rng.uniform(0, 1e5, s1[-1]))
    along[s0[-2]:s1[-2]] = along[s0[-2]]                        # a singular segment
    z = rng.normal(0, 1e3, along.size) + 2500.0
    centres = along[np.minimum(s0, along.size - 1)] + rng.uniform(0, 40, lengths.size)
    loop = np.full(lengths.size, np.nan)
    atl06._fill_reference_heights(loop, z, along, centres, s0, s1)
    compiled = np.full(lengths.size, np.nan)
    kernel.reference_heights(along, z, centres, s0, s1, compiled)
    assert np.isnan(compiled[0]) and np.isfinite(compiled[1:]).all()
    np.testing.assert_array_equal(compiled, loop)
    for n in (0, 7, 8, 127, 128, 129, 255, 1000, 4099):     # and numpy's halving above 128
        x = rng.normal(0, 1e3, n + 3)
        assert numeric.pairwise_sum(x, 3, n) == x[3:].sum()


def test_auto_engine_compiles_only_for_long_tracks(monkeypatch, fractal_tracks):
    """``engine="auto"``: the reference for a short track (the compile would cost more),
    the kernel from COMPILE_MIN_SEGMENTS segments on, whatever ran before in the process
    (so a track gives the same bits in a sweep's workers as in the caller: test_sweep)."""
    calls = []
    compiled = atl06._fit_compiled
    monkeypatch.setattr(atl06, "_fit_compiled", lambda *a: calls.append(1) or compiled(*a))
    res = fractal_tracks[1.0]                                  # ~200 segments
    atl06.segments_from_result(res, engine="compiled")         # the kernel is loaded now
    atl06.segments_from_result(res)
    assert calls == [1]
    monkeypatch.setattr(atl06, "COMPILE_MIN_SEGMENTS", 100)
    atl06.segments_from_result(res)
    assert calls == [1, 1]
