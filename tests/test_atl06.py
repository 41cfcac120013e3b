"""ATL06-style surface finding and first-photon-bias (FPB) correction (lidar_mitsuba.atl06).

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
from scipy import integrate, stats

from lidar_mitsuba import atl06, pmt
from lidar_mitsuba.photons import Returns
from lidar_mitsuba.constants import C_M_PER_NS
from lidar_mitsuba.instrument import Instrument
from reference_loops import loop_nonparalyzable, loop_paralyzable

Z = 4.5
T0 = 2 * 496e3 / C_M_PER_NS          # round-trip time to h = 0 [ns]


def gaussian_returns(rng, n_shots, sigma_ns, k=48):
    """Synthetic traced returns: ``k`` paths per shot, weight 1, Gaussian times about T0."""
    return Returns.at_times(T0 + sigma_ns * rng.standard_normal(n_shots * k), paths_per_shot=k)


def first_photon_moments(lam, sigma):
    """First arrival of a Poisson process of mean ``lam`` with Gaussian intensity (sd sigma),
    given at least one: density lam phi(t) exp(-lam Phi(t)) / (1 - exp(-lam)).
    Returns (p_detect, mean, sd, kurtosis)."""
    norm = -math.expm1(-lam)

    def f(t):
        return (lam * stats.norm.pdf(t, scale=sigma)
                * math.exp(-lam * stats.norm.cdf(t, scale=sigma)) / norm)

    lim = 12 * sigma
    m1 = integrate.quad(lambda t: t * f(t), -lim, lim, epsabs=1e-13)[0]
    m2 = integrate.quad(lambda t: (t - m1) ** 2 * f(t), -lim, lim, epsabs=1e-13)[0]
    m4 = integrate.quad(lambda t: (t - m1) ** 4 * f(t), -lim, lim, epsabs=1e-13)[0]
    return norm, m1, math.sqrt(m2), m4 / m2 ** 2


def paralyzable_detections_per_channel(lam, sigma, tau):
    """Mean detections per channel-pulse of a paralyzable channel fed a Poisson process of
    mean ``lam`` with Gaussian intensity: an arrival at t is detected when no arrival came in
    (t - tau, t), so the rate is lam phi(t) exp(-lam (Phi(t) - Phi(t - tau)))."""
    def f(t):
        return lam * stats.norm.pdf(t, scale=sigma) * math.exp(
            -lam * (stats.norm.cdf(t, scale=sigma) - stats.norm.cdf(t - tau, scale=sigma)))
    return integrate.quad(f, -12 * sigma, 12 * sigma + tau, epsabs=1e-13)[0]


def loop_paralyzable_weights(t, dead, npc):
    """Reference for the paralyzable correction: in time order, each photon's weight is
    exp(sum of the weights of the photons in (t - dead, t) / npc), npc the channel-pulses
    other than the photon's own."""
    order = np.argsort(t, kind="stable")
    w = np.empty(t.size)
    for a, i in enumerate(order):
        s = 0.0
        for j in order[:a]:
            if t[i] - dead < t[j] < t[i]:
                s += w[j]
        w[i] = math.exp(s / npc)
    return w


def batch_se(values_fn, shot, n_shots, n_batches=20):
    """Standard error of an estimator from ``n_batches`` disjoint blocks of shots."""
    edges = np.linspace(0, n_shots, n_batches + 1).astype(int)
    est = [values_fn((shot >= a) & (shot < b), b - a) for a, b in zip(edges[:-1], edges[1:])]
    return float(np.std(est, ddof=1) / math.sqrt(n_batches))


# ---------------------------------------------------------------------------- 1. closed forms

@pytest.mark.parametrize("paralyzable", [False, True])
@pytest.mark.parametrize("channels", [4, 16])
def test_detection_fraction_per_channel(rng, channels, paralyzable):
    """A channel detects in a shot iff at least one photon arrives on it (the first arrival
    always finds it alive, in both models): fraction 1 - exp(-mu / C), mu = S ff pde."""
    inst = Instrument(beam="strong", channels=channels, signal_photons=6.0,
                      paralyzable=paralyzable)
    n_shots = 20000
    det = pmt.detect(gaussian_returns(rng, n_shots, inst.pulse_sigma_ns), inst, rng)
    mu = inst.signal_photons * inst.fill_factor * inst.pde
    p = -math.expm1(-mu / channels)
    frac = np.unique(det.shot * channels + det.channel).size / (n_shots * channels)
    assert abs(frac - p) < Z * math.sqrt(p * (1 - p) / (n_shots * channels))


@pytest.mark.parametrize("channels", [4, 16])
def test_nonparalyzable_first_photon_and_its_correction(rng, channels):
    """Dead time 3 ns >> pulse sigma 0.42 ns: each channel records its first photon only.
    Its mean and spread match the closed form, and the dead-time weights undo it: the
    weighted count per channel-pulse is lam (the true mean) and the weighted mean time 0."""
    inst = Instrument(beam="strong", channels=channels)
    n_shots = 40000
    sigma = inst.pulse_sigma_ns
    det = pmt.detect(gaussian_returns(rng, n_shots, sigma), inst, rng)
    lam = inst.signal_photons * inst.fill_factor * inst.pde / channels
    _, mean, sd, kurt = first_photon_moments(lam, sigma)
    dt = det.time_ns - T0
    n = dt.size
    assert abs(dt.mean() - mean) < Z * sd / math.sqrt(n)
    assert abs(dt.std(ddof=1) - sd) < Z * sd * math.sqrt((kurt - 1) / (4 * n))

    w, ok = atl06.dead_time_weights(dt, n_pulses=n_shots, n_channels=channels,
                                    dead_time_ns=inst.dead_time_ns, paralyzable=False)
    assert ok and np.all(w >= 1)
    lam_hat = w.sum() / (n_shots * channels)
    mean_hat = np.sum(w * dt) / w.sum()

    def count(sel, ns):
        ww, _ = atl06.dead_time_weights(dt[sel], n_pulses=ns, n_channels=channels,
                                        dead_time_ns=inst.dead_time_ns, paralyzable=False)
        return ww.sum() / (ns * channels)

    def centroid(sel, ns):
        ww, _ = atl06.dead_time_weights(dt[sel], n_pulses=ns, n_channels=channels,
                                        dead_time_ns=inst.dead_time_ns, paralyzable=False)
        return np.sum(ww * dt[sel]) / ww.sum()

    assert abs(lam_hat - lam) < Z * batch_se(count, det.shot, n_shots)
    assert abs(mean_hat) < Z * batch_se(centroid, det.shot, n_shots)
    assert abs(mean) > 10 * batch_se(centroid, det.shot, n_shots)   # there was a bias to undo


@pytest.mark.parametrize("tau", [1.0, 3.0, 6.0])
def test_paralyzable_rate_and_its_correction(rng, tau):
    """Paralyzable channel, return spread comparable to the dead time (sigma 3 ns): mean
    detections per channel-pulse match the quadrature closed form, and the paralyzable
    weights recover the true count lam and mean time 0."""
    channels, lam, sigma = 4, 2.0, 3.0
    inst = Instrument(beam="strong", channels=channels, signal_photons=lam * channels,
                      fill_factor=1.0, pde=1.0, dead_time_ns=tau, paralyzable=True)
    n_shots = 20000
    det = pmt.detect(gaussian_returns(rng, n_shots, sigma, k=64), inst, rng)
    expect = paralyzable_detections_per_channel(lam, sigma, tau)
    per_cp = np.bincount(det.shot * channels + det.channel, minlength=n_shots * channels)
    assert abs(per_cp.mean() - expect) < Z * per_cp.std(ddof=1) / math.sqrt(per_cp.size)
    dt = det.time_ns - T0

    def est(sel, ns):
        w, ok = atl06.dead_time_weights(dt[sel], n_pulses=ns, n_channels=channels,
                                        dead_time_ns=tau, paralyzable=True)
        assert ok
        return w.sum() / (ns * channels), np.sum(w * dt[sel]) / w.sum()

    lam_hat, mean_hat = est(np.ones(dt.size, bool), n_shots)
    assert abs(lam_hat - lam) < Z * batch_se(lambda s, n: est(s, n)[0], det.shot, n_shots)
    assert abs(mean_hat) < Z * batch_se(lambda s, n: est(s, n)[1], det.shot, n_shots)


@pytest.mark.parametrize("dead", [0.5, 3.0, 10.0, 40.0])
def test_dead_time_masks_event_by_event(rng, dead):
    """pmt's vectorised masks against plain loops, on event lists like a real gate: dense
    signal clusters on a uniform background, at orbital times, with exact ties."""
    n_groups = 50
    sig_g = rng.integers(0, n_groups, 3000)
    sig_t = T0 + rng.normal(0, 0.5, sig_g.size) + rng.normal(0, 2.0, n_groups)[sig_g]
    bg_g = rng.integers(0, n_groups, 2000)
    bg_t = T0 + rng.uniform(-100, 100, bg_g.size)
    group = np.concatenate([sig_g, bg_g])
    t = np.concatenate([sig_t, bg_t])
    t[::9] = t[1::9][: t[::9].size]                   # exact ties
    assert np.array_equal(pmt.paralyzable_mask(group, t, dead), loop_paralyzable(group, t, dead))
    assert np.array_equal(pmt.nonparalyzable_mask(group, t, dead),
                          loop_nonparalyzable(group, t, dead))


@pytest.mark.parametrize("dead", [0.3, 1.0, 3.0])
def test_paralyzable_weights_match_sequential_loop(rng, dead):
    """The vectorised fixed-point solution of the causal paralyzable equation equals the
    plain in-time-order loop, photon by photon; the non-paralyzable weights are
    1 / (1 - detections in (t - dead, t) / (N C - 1))."""
    # detections of a paralyzable detector: 50 pulses x 4 channels, Poisson(2) arrivals per
    # channel-pulse (Gaussian, sd 1 ns) on a uniform background
    n_cp = 50 * 4
    k = rng.poisson(2.0, n_cp)
    group = np.concatenate([np.repeat(np.arange(n_cp), k), rng.integers(0, n_cp, 100)])
    t = np.concatenate([rng.normal(0, 1.0, k.sum()), rng.uniform(-8, 8, 100)])
    t = t[loop_paralyzable(group, t, dead)]
    npc = n_cp - 1               # the channel-pulses other than the photon's own (known alive)
    w, ok = atl06.dead_time_weights(t, n_pulses=50, n_channels=4, dead_time_ns=dead,
                                    paralyzable=True)
    assert ok
    np.testing.assert_allclose(w, loop_paralyzable_weights(t, dead, npc), rtol=1e-8)
    assert w.max() > 1.2                                     # the correction matters
    # non-paralyzable: 1 / (1 - detections in (t - dead, t) / npc)
    w_np, _ = atl06.dead_time_weights(t, n_pulses=50, n_channels=4, dead_time_ns=dead,
                                      paralyzable=False)
    k = np.array([np.sum((t > ti - dead) & (t < ti)) for ti in t])
    np.testing.assert_allclose(w_np, 1 / (1 - k / npc))


@pytest.mark.parametrize("paralyzable", [False, True])
def test_background_dead_time_correction_inverts_the_models(paralyzable):
    tau, channels, true_mhz = 3.0, 4, 40.0
    r = true_mhz * 1e-3 / channels
    obs = r / (1 + r * tau) if not paralyzable else r * math.exp(-r * tau)
    got = atl06.corrected_background_mhz(obs * channels * 1e3, n_channels=channels,
                                         dead_time_ns=tau, paralyzable=paralyzable)
    assert got == pytest.approx(true_mhz, rel=1e-12)


# ---------------------------------------------------------- 2. fractal track with background

@pytest.fixture(scope="module")
def fractal_tracks():
    from lidar_mitsuba.simulate import simulate
    from lidar_mitsuba.surface import SurfaceSpec
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
    from lidar_mitsuba import atl03
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


# ------------------------------------------------------------------------------ 3. flags

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
