"""The PMT stage against closed forms and an independent, deliberately simple implementation.

Tolerances: each Monte Carlo estimate is compared with its closed form within Z = 4.5 standard
errors, the standard error computed from the sample (binomial for fractions, sigma/sqrt(n) for
means, sigma*sqrt((kurtosis-1)/(4n)) for standard deviations). With ~25 such comparisons the
chance of a false failure is below 1e-4.
"""
import math

import numpy as np
import pytest

from lidar_mitsuba.detector import pmt
from lidar_mitsuba.detector.records import Returns
from lidar_mitsuba.constants import C_M_PER_NS
from lidar_mitsuba.instrument import Instrument
from closed_forms import T0, Z, first_photon_moments, gaussian_returns
from reference_loops import loop_nonparalyzable, loop_paralyzable


@pytest.mark.parametrize("dead", [0.0, 0.5, 3.0, 20.0])
def test_dead_time_masks_match_simple_loops(rng, dead):
    n = 4000
    group = rng.integers(0, 60, n)
    t = 3.3e6 + rng.uniform(0, 40, n)          # absolute times at orbital range [ns]
    t[::7] = t[1::7][: t[::7].size] if dead else t[::7]   # exact ties
    assert np.array_equal(pmt.nonparalyzable_mask(group, t, dead), loop_nonparalyzable(group, t, dead))
    assert np.array_equal(pmt.paralyzable_mask(group, t, dead), loop_paralyzable(group, t, dead))


def test_dead_time_boundary_is_exact():
    """An event exactly one dead time after a recorded one is recorded (dead on [t, t+tau))."""
    t = np.array([0.0, 1.0, 3.0, 3.5, 6.0]) + 3.3e6
    g = np.zeros(5, int)
    assert pmt.nonparalyzable_mask(g, t, 3.0).tolist() == [True, False, True, False, True]
    assert pmt.paralyzable_mask(g, t, 3.0).tolist() == [True, False, False, False, False]


def test_arrivals_poisson_and_weighted(rng):
    """Counts are Poisson(mu) with mu = S * mean weight; arrivals pick returns by weight."""
    n_shots, k = 20000, 32
    shot = np.repeat(np.arange(n_shots), k)
    w = np.where(np.arange(shot.size) % 2 == 0, 0.5, 1.5)       # mean weight 1
    idx, mu, counts, run_out = pmt.sample_arrivals(shot, w, n_shots=n_shots, paths_per_shot=k,
                                                   signal_photons=3.0, rng=rng)
    assert np.allclose(mu, 3.0)
    # Poisson: mean 3 and variance 3; SE of the mean sqrt(3/n), of the variance ~ sqrt(2*9/n)
    assert abs(counts.mean() - 3.0) < Z * math.sqrt(3.0 / n_shots)
    assert abs(counts.var() - 3.0) < Z * math.sqrt((2 * 9 + 3) / n_shots)
    # heavy returns (w = 1.5) are chosen with probability 0.75; binomial SE
    frac = np.mean(idx % 2 == 1)
    assert abs(frac - 0.75) < Z * math.sqrt(0.75 * 0.25 / idx.size)
    # distinct paths within a shot
    pairs = shot[idx] * shot.size + idx
    assert np.unique(pairs).size == idx.size and not run_out.any()
    assert np.all(shot[idx] == np.repeat(np.arange(n_shots), counts))


def test_arrivals_exchangeable_fast_path(rng):
    """Single-bounce traces are in iid order: the unshuffled fast path is just as unbiased."""
    n_shots, k = 20000, 32
    shot = np.repeat(np.arange(n_shots), k)
    w = rng.choice([0.5, 1.5], shot.size)
    idx, mu, counts, run_out = pmt.sample_arrivals(shot, w, n_shots=n_shots, paths_per_shot=k,
                                                   signal_photons=3.0, rng=rng,
                                                   exchangeable=True)
    frac = np.mean(w[idx] == 1.5)
    p_heavy = 1.5 * np.mean(w == 1.5) / np.mean(w)     # weight share of the heavy returns
    assert abs(frac - p_heavy) < Z * math.sqrt(p_heavy * (1 - p_heavy) / idx.size)
    pairs = shot[idx] * shot.size + idx
    assert np.unique(pairs).size == idx.size


def test_arrivals_fallback_keeps_weights(rng):
    """More arrivals than paths: the fallback draws with replacement, still by weight."""
    n_shots, k = 5000, 2
    shot = np.repeat(np.arange(n_shots), k)
    w = np.tile([1.0, 3.0], n_shots)
    idx, mu, counts, run_out = pmt.sample_arrivals(shot, w, n_shots=n_shots, paths_per_shot=k,
                                                   signal_photons=6.0, rng=rng)
    frac = np.mean(idx % 2 == 1)
    assert abs(frac - 0.75) < Z * math.sqrt(0.75 * 0.25 / idx.size) * 3  # clustered draws: 3x SE
    assert np.all(shot[idx] == np.repeat(np.arange(n_shots), counts))
    # one pass accepts the heavy return and the light one with probability 1/3: a shot runs
    # out always with 3 or more picks, never with 0 or 1, and with 2 with probability 2/3
    assert run_out[counts >= 3].all() and not run_out[counts <= 1].any()
    two = run_out[counts == 2]
    assert abs(two.mean() - 2 / 3) < Z * math.sqrt(2 / 9 / two.size)


@pytest.mark.parametrize("tail", [None, -0.45])
def test_photon_times_unbiased_for_heavy_weights(rng, tail):
    """Paths at times x ~ U(0, 1) with weights rising toward x = 1: bounded (0.5 + x) or
    heavy-tailed ((1 - x)**-0.45: variance ~2x the squared mean, like snow-volume weights,
    where most shots run out and fall back to drawing with replacement). The photons pooled
    over shots have the weighted mean time of the continuous distribution, whatever the
    shot's few paths: E[sum_s w t] / E[sum_s w]. Closed forms: (1/4 + 1/3) and
    (a + 1)(1/(a + 1) - 1/(a + 2)). The sampler's acceptance bound must not depend on the
    shot's own weights for this to hold: the shot's largest weight as bound (fewer run-outs)
    was tried and over-picks its heaviest path, 9.8 SE off in the heavy case. SE: a ratio of
    shot totals (delta method), photons of one shot being correlated."""
    n_shots, k = 100000, 32
    x = rng.random(n_shots * k)
    if tail is None:
        w, target = 0.5 + x, 0.25 + 1 / 3
    else:
        a = tail
        w, target = (1 - x) ** a, (a + 1) * (1 / (a + 1) - 1 / (a + 2))
    shot = np.repeat(np.arange(n_shots), k)
    idx, _, _, run_out = pmt.sample_arrivals(shot, w, n_shots=n_shots, paths_per_shot=k,
                                             signal_photons=2.2, rng=rng)
    T = np.bincount(shot[idx], weights=x[idx], minlength=n_shots)
    K = np.bincount(shot[idx], minlength=n_shots).astype(float)
    mean = T.sum() / K.sum()
    se = math.sqrt(np.sum((T - mean * K) ** 2)) / K.sum()
    assert abs(mean - target) < Z * se
    if tail is not None:
        assert run_out.mean() > 0.5             # the fallback is what this case checks


@pytest.mark.parametrize("channels", [1, 4, 16])
def test_first_photon_statistics_closed_form(rng, channels):
    """Strong-beam signal (8.17 photons/shot) on a Gaussian return, dead time 3 ns >> pulse:
    each channel records exactly its first photon. Detection fraction per channel
    1 - exp(-lam), lam = S * ff * pde / channels, and first-photon mean and spread."""
    inst = Instrument(beam="strong", channels=channels)
    n_shots, k = 60000, 48
    sigma_ns = inst.pulse_sigma_ns
    t0 = 2 * inst.altitude_m / C_M_PER_NS
    returns = Returns.at_times(t0 + sigma_ns * rng.standard_normal(n_shots * k), paths_per_shot=k)
    det = pmt.detect(returns, inst, rng)
    lam = inst.signal_photons * inst.fill_factor * inst.pde / channels
    p_det, mean, sd, kurt = first_photon_moments(lam, sigma_ns)

    frac = len(det) / (n_shots * channels)
    assert abs(frac - p_det) < Z * math.sqrt(p_det * (1 - p_det) / (n_shots * channels))
    dt = det.time_ns - t0
    n = dt.size
    assert abs(dt.mean() - mean) < Z * sd / math.sqrt(n)
    assert abs(dt.std(ddof=1) - sd) < Z * sd * math.sqrt((kurt - 1) / (4 * n))
    # more channels, less first-photon bias (the paper's Fig. 7); in metres: h = -c t / 2
    assert mean < 0


def test_ideal_detector_keeps_every_photon(rng):
    inst = Instrument(beam="weak", ideal_detector=True)
    n_shots, k = 30000, 16
    returns = Returns.at_times(np.zeros(n_shots * k), paths_per_shot=k)
    det = pmt.detect(returns, inst, rng)
    expect = inst.signal_photons * inst.fill_factor * inst.pde     # Poisson thinning
    assert abs(len(det) / n_shots - expect) < Z * math.sqrt(expect / n_shots)
    assert det.channel.max() < inst.channels
    assert np.array_equal(det.channel, det.anode // 4)


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


def test_gate_openings_are_nan_to_num_s():
    """``detect``'s gate openings for its kernel (``_nan_to_inf``) are ``np.nan_to_num(x,
    nan=np.inf)``'s: finite openings as they are, and NaN, +inf and -inf replaced."""
    from lidar_mitsuba.detector.pmt import _nan_to_inf
    x = np.array([1.5, -2.0, 0.0, -0.0, 3.3e6])
    assert _nan_to_inf(x).tobytes() == np.nan_to_num(x, nan=np.inf).tobytes()
    y = np.array([1.5, np.nan, np.inf, -np.inf, -0.0])
    assert _nan_to_inf(y).tobytes() == np.nan_to_num(y, nan=np.inf).tobytes()
