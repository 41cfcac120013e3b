"""The first-photon-bias building blocks (lidar_mitsuba.products.first_photon_bias): dead-time weights that undo the
first-photon bias of both dead-time models, against closed forms and plain loops, and the
background-rate correction. Tolerances: see tests/closed_forms.py."""
import math

import numpy as np
import pytest

from lidar_mitsuba.products import first_photon_bias as fpb
from lidar_mitsuba.detector import pmt
from lidar_mitsuba.instrument import Instrument
from closed_forms import (T0, Z, batch_se, first_photon_moments, gaussian_returns,
                          loop_paralyzable_weights, paralyzable_detections_per_channel)
from reference_loops import loop_paralyzable


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

    w, ok = fpb.dead_time_weights(dt, n_pulses=n_shots, n_channels=channels,
                                    dead_time_ns=inst.dead_time_ns, paralyzable=False)
    assert ok and np.all(w >= 1)
    lam_hat = w.sum() / (n_shots * channels)
    mean_hat = np.sum(w * dt) / w.sum()

    def count(sel, ns):
        ww, _ = fpb.dead_time_weights(dt[sel], n_pulses=ns, n_channels=channels,
                                        dead_time_ns=inst.dead_time_ns, paralyzable=False)
        return ww.sum() / (ns * channels)

    def centroid(sel, ns):
        ww, _ = fpb.dead_time_weights(dt[sel], n_pulses=ns, n_channels=channels,
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
        w, ok = fpb.dead_time_weights(dt[sel], n_pulses=ns, n_channels=channels,
                                        dead_time_ns=tau, paralyzable=True)
        assert ok
        return w.sum() / (ns * channels), np.sum(w * dt[sel]) / w.sum()

    lam_hat, mean_hat = est(np.ones(dt.size, bool), n_shots)
    assert abs(lam_hat - lam) < Z * batch_se(lambda s, n: est(s, n)[0], det.shot, n_shots)
    assert abs(mean_hat) < Z * batch_se(lambda s, n: est(s, n)[1], det.shot, n_shots)


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
    w, ok = fpb.dead_time_weights(t, n_pulses=50, n_channels=4, dead_time_ns=dead,
                                    paralyzable=True)
    assert ok
    np.testing.assert_allclose(w, loop_paralyzable_weights(t, dead, npc), rtol=1e-8)
    assert w.max() > 1.2                                     # the correction matters
    # non-paralyzable: 1 / (1 - detections in (t - dead, t) / npc)
    w_np, _ = fpb.dead_time_weights(t, n_pulses=50, n_channels=4, dead_time_ns=dead,
                                      paralyzable=False)
    k = np.array([np.sum((t > ti - dead) & (t < ti)) for ti in t])
    np.testing.assert_allclose(w_np, 1 / (1 - k / npc))


@pytest.mark.parametrize("paralyzable", [False, True])
def test_background_dead_time_correction_inverts_the_models(paralyzable):
    tau, channels, true_mhz = 3.0, 4, 40.0
    r = true_mhz * 1e-3 / channels
    obs = r / (1 + r * tau) if not paralyzable else r * math.exp(-r * tau)
    got = fpb.corrected_background_mhz(obs * channels * 1e3, n_channels=channels,
                                         dead_time_ns=tau, paralyzable=paralyzable)
    assert got == pytest.approx(true_mhz, rel=1e-12)


def test_iqr_per_sigma_is_scipy_stats_normal_iqr():
    """The Gaussian IQR constant (from scipy.special, not scipy.stats, to keep scipy.stats'
    import out of every run) is scipy.stats' 2 Phi^-1(0.75), to the bit."""
    from scipy import stats
    from lidar_mitsuba.products import first_photon_bias
    assert first_photon_bias.IQR_PER_SIGMA == float(2.0 * stats.norm.ppf(0.75))
