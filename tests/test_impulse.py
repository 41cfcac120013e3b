"""ATLAS's impulse response as flown (lidar_mitsuba.detector.impulse) and what ATL03 writes of
it (quality_ph, saturation): the sampled mixture against its closed forms, afterpulse counts
against their expected rate, the dead-time echoes, and the Gaussian case unchanged to the bit.
No rendering (synthetic returns)."""
import math

import numpy as np
import pytest

from lidar_mitsuba.constants import C_M_PER_NS, ParameterError
from lidar_mitsuba.detector import impulse, pmt
from lidar_mitsuba.detector.records import Returns
from lidar_mitsuba.instrument import Instrument

T0_NS = 2 * 496e3 / C_M_PER_NS
R = impulse.ATLAS_RESPONSE


def test_sampled_delays_match_closed_form_moments_and_cdf():
    """Mixture of a point mass at 0, an exponential and two point masses. n = 400 000 draws:
    the mean's standard error is sqrt(var / n); the tolerance is 5 of them. The CDF is checked
    with the Kolmogorov-Smirnov statistic against its closed form: the KS bound
    sqrt(-ln(alpha / 2) / (2 n)) at alpha = 1e-4 (the distribution has atoms, where the KS
    statistic is, if anything, smaller)."""
    n = 400_000
    d = R.sample_delay_ns(n, np.random.default_rng(3))
    mean, var = R.delay_moments()
    assert abs(d.mean() - mean) < 5 * math.sqrt(var / n)
    # variance: SE of the sample variance ~ sqrt((m4 - var^2) / n), here bounded via the
    # sample's own fourth central moment
    m4 = np.mean((d - d.mean()) ** 4)
    assert abs(d.var() - var) < 5 * math.sqrt((m4 - var ** 2) / n)
    grid = np.concatenate([np.linspace(0, 6, 301), [R.echo_delays_ns[0] - 1e-9,
                                                   R.echo_delays_ns[0], 40.0]])
    emp = np.searchsorted(np.sort(d), grid, side="right") / n
    ks = np.max(np.abs(emp - R.delay_cdf(grid)))
    assert ks < math.sqrt(-math.log(1e-4 / 2) / (2 * n))
    # the component shares: echo counts are binomial
    for delay, a in zip(R.echo_delays_ns, R.echo_fractions):
        k = np.sum(d == delay)
        assert abs(k - n * a) < 5 * math.sqrt(n * a * (1 - a))


def test_whole_response_cdf_matches_gaussian_plus_sampled_delay():
    """The whole response's closed-form CDF (Gaussian + ex-Gaussian + shifted Gaussians)
    against Gaussian draws plus the mixture's delays: KS at alpha 1e-4, n = 200 000."""
    n, sigma = 200_000, 1.5 / 2.3548
    rng = np.random.default_rng(11)
    t = np.sort(sigma * rng.standard_normal(n) + R.sample_delay_ns(n, rng))
    grid = np.linspace(-3, 30, 2001)
    emp = np.searchsorted(t, grid, side="right") / n
    ks = np.max(np.abs(emp - R.cdf(grid, sigma_ns=sigma)))
    assert ks < math.sqrt(-math.log(1e-4 / 2) / (2 * n))
    assert R.calibration_ns() == pytest.approx(R.tail_fraction * R.tail_mean_ns)


def test_pdf_integrates_to_one_and_has_its_mean():
    """The whole response (Gaussian * delays) is a density whose mean is the delay's mean
    (the Gaussian is centred on 0): trapezoid sums on a fine grid, tolerance 1e-4."""
    t = np.linspace(-10, 60, 28_001)
    p = R.pdf(t, sigma_ns=1.5 / 2.3548)
    assert abs(np.trapezoid(p, t) - 1) < 1e-4
    assert abs(np.trapezoid(t * p, t) - R.delay_moments()[0]) < 1e-4


def test_gaussian_response_draws_nothing():
    rng = np.random.default_rng(1)
    state = rng.bit_generator.state
    assert not impulse.GAUSSIAN.adds_delay
    assert np.all(impulse.GAUSSIAN.sample_delay_ns(10, rng) == 0)
    assert rng.bit_generator.state == state
    assert impulse.response_of(Instrument()) is impulse.GAUSSIAN
    assert impulse.response_of(Instrument.atlas()) is impulse.ATLAS_RESPONSE


def test_bad_response_raises():
    with pytest.raises(ParameterError):
        impulse.ImpulseResponse(tail_fraction=0.9, tail_mean_ns=1.0, echo_delays_ns=(1.0,),
                                echo_fractions=(0.2,))
    with pytest.raises(ParameterError):
        Instrument(pulse_shape="square")


def _plate(n_shots, k, *, seed):
    rng = np.random.default_rng(seed)
    ret = Returns.at_times(T0_NS + 0.637 * rng.standard_normal(n_shots * k), paths_per_shot=k)
    ret.x_m = ret.y_m = ret.z_m = np.zeros(len(ret), np.float32)
    return ret


def test_afterpulse_counts_match_their_expected_rate():
    """Ideal detector (no dead time), no gate: every detection has an afterpulse with
    probability p, so their count is Binomial(detections, p); tolerance 5 sigma. Their
    delays are uniform over the window (KS at alpha 1e-4)."""
    inst = Instrument(beam="strong", ideal_detector=True, signal_photons=20.0, fill_factor=1.0,
                      pde=1.0, pulse_shape="atlas")
    det = pmt.detect(_plate(4000, 64, seed=5), inst, np.random.default_rng(7))
    n_sig = int(det.is_signal.sum())
    n_after = int((~det.is_signal).sum())
    p = R.afterpulse_probability
    assert abs(n_after - n_sig * p) < 5 * math.sqrt(n_sig * p * (1 - p))
    lo, hi = R.afterpulse_window_ns
    late = det.time_ns[~det.is_signal] - T0_NS
    assert late.min() > lo - 5 and late.max() < hi + 40     # parents: within ~30 ns of T0


def test_afterpulse_delays_are_uniform_and_cut_at_the_gate():
    """:func:`add_afterpulses` alone: delays uniform over the window (KS at alpha 1e-4), and
    none past the shot's gate end."""
    n = 200_000
    shot = np.repeat(np.arange(n // 10), 10)
    t = np.zeros(n)
    parent, delay = impulse.add_afterpulses(shot, t, response=R, rng=np.random.default_rng(4))
    p = R.afterpulse_probability
    assert abs(parent.size - n * p) < 5 * math.sqrt(n * p * (1 - p))
    lo, hi = R.afterpulse_window_ns
    u = np.sort((delay - lo) / (hi - lo))
    ks = np.max(np.abs(np.arange(1, u.size + 1) / u.size - u))
    assert ks < math.sqrt(-math.log(1e-4 / 2) / (2 * u.size)) + 1.0 / u.size
    end = np.full(n // 10, 100.0)
    parent, delay = impulse.add_afterpulses(shot, t, response=R, rng=np.random.default_rng(4),
                                            gate_end_ns=end)
    assert delay.size and delay.max() < 100.0


def test_dead_time_makes_the_echoes_at_045_and_09_m():
    """Lu et al. 2021's echoes ~0.45 m and ~0.9 m below a bright return come from the dead
    time: with a saturating return (300 photons/shot on 16 channels), a channel re-armed
    3.2 ns (0.48 m) after its first count records again on the same return's tail. The
    second and third counts of a channel lie near 1x and 2x the dead time after the first."""
    inst = Instrument(beam="strong", signal_photons=300.0, dead_time_ns=3.2, fill_factor=1.0,
                      pde=1.0)
    ret = Returns.at_times(T0_NS + 0.637 * np.random.default_rng(2).standard_normal(400 * 1024)
                           + np.random.default_rng(3).exponential(1.0, 400 * 1024)
                           * (np.random.default_rng(4).random(400 * 1024) < 0.5),
                           paths_per_shot=1024)
    ret.x_m = ret.y_m = ret.z_m = np.zeros(len(ret), np.float32)
    det = pmt.detect(ret, inst, np.random.default_rng(9))
    key = det.shot * 16 + det.channel
    order = np.lexsort((det.time_ns, key))
    k, t = key[order], det.time_ns[order]
    first = np.r_[True, k[1:] != k[:-1]]
    rank = np.arange(k.size) - np.maximum.accumulate(np.where(first, np.arange(k.size), 0))
    t0 = np.repeat(t[first], np.diff(np.r_[np.flatnonzero(first), k.size]))
    dz = (t - t0) * C_M_PER_NS / 2
    for r, expect in ((1, 0.48), (2, 0.96)):
        med = np.median(dz[rank == r])
        assert expect <= med < expect + 0.25, (r, med)


def test_quality_flags_below_a_saturated_return():
    """ATL03's quality_ph on a case where it is known: a pulse whose surface events fill
    every channel is saturated, and its photons 2-4 m and 10 m below get 1 and 2."""
    from types import SimpleNamespace
    from lidar_mitsuba.products.atl03 import beam
    h = np.array([0.0, -0.1, -0.2, -0.3, -2.3, -10.0, 0.0, -2.3])
    shot = np.array([0, 0, 0, 0, 0, 0, 1, 1])
    conf = np.array([4, 4, 4, 4, 0, 0, 4, 0], np.int8)
    s = SimpleNamespace(shot=shot, conf=conf, order=np.arange(8),
                        res=SimpleNamespace(h_m=h, n_shots=2),
                        inst=SimpleNamespace(channels=4))
    full, near = s.saturated = beam._saturated_pulses(s)   # (what a _Section keeps)
    assert full.tolist() == [True, False] and near.tolist() == [False, False]
    assert beam._quality(s).tolist() == [0, 0, 0, 0, 1, 2, 0, 0]
