"""Solar background, dark counts, range gate and the signal_conf_ph classifier.

Tolerances: Z = 4.5 standard errors from the sample (Poisson counts: sqrt(mean / n); binomial
fractions), or a Kolmogorov-Smirnov p-value above 1e-4 for uniform arrival times.
"""
import math

import numpy as np
import pytest
from scipy import stats

from lidar_mitsuba.products import classify
from lidar_mitsuba.detector import pmt
from lidar_mitsuba.detector.records import Returns
from lidar_mitsuba.constants import C_M_PER_NS
from lidar_mitsuba.instrument import Instrument

Z = 4.5
T0 = 2 * 496e3 / C_M_PER_NS


def flat_returns(rng, n_shots, k=32, sigma_ns=0.4247):
    return Returns.at_times(T0 + sigma_ns * rng.standard_normal(n_shots * k), paths_per_shot=k)


def test_background_and_dark_counts_match_rates(rng):
    """No dead time: noise counts per shot are Poisson with the closed-form means, uniform in
    the gate, tagged as noise; dark counts only where asked."""
    n = 40000
    inst = Instrument(beam="strong", signal_photons=0.0, background_mhz=8.0, dark_count_hz=2e5,
                      range_gate_m=60.0, ideal_detector=True)
    det = pmt.detect(flat_returns(rng, n), inst, rng, gate_center_ns=np.full(n, T0))
    assert not det.is_signal.any() and np.all(det.return_index == -1)
    gate_ns = 2 * 60.0 / C_M_PER_NS
    bg = 8e6 * gate_ns * 1e-9 * inst.fill_factor * inst.pde     # detected background per shot
    dc = 2e5 * gate_ns * 1e-9 * inst.channels                    # dark counts per shot
    mean = bg + dc
    assert abs(len(det) / n - mean) < Z * math.sqrt(mean / n)
    u = (det.time_ns - (T0 - gate_ns / 2)) / gate_ns
    assert u.min() >= 0 and u.max() < 1
    assert stats.kstest(u, "uniform").pvalue > 1e-4
    # anodes uniform: chi-square over the 16 anodes
    counts = np.bincount(det.anode, minlength=16)
    assert stats.chisquare(counts).pvalue > 1e-4


def test_gate_drops_signal_outside(rng):
    n = 2000
    inst = Instrument(beam="strong", range_gate_m=1.0, ideal_detector=True)   # +-0.5 m
    ret = flat_returns(rng, n, sigma_ns=5.0)                                  # +-0.75 m spread
    det = pmt.detect(ret, inst, rng, gate_center_ns=np.full(n, T0))
    half_ns = inst.range_gate_ns / 2
    assert np.all(np.abs(det.time_ns - T0) < half_ns + 1e-9)
    frac = len(det) / (n * inst.signal_photons * inst.fill_factor * inst.pde)
    p_in = stats.norm.cdf(half_ns / 5.0) - stats.norm.cdf(-half_ns / 5.0)
    assert abs(frac - p_in) < Z * math.sqrt(p_in / (n * 3.27))


def test_noise_needs_gate(rng):
    with pytest.raises(ValueError, match="range gate"):
        pmt.detect(flat_returns(rng, 10), Instrument(background_mhz=1.0), rng)


@pytest.mark.parametrize("paralyzable", [False, True])
def test_dead_time_models_event_by_event_with_noise(rng, paralyzable):
    """The full detect() with heavy noise against a plain per-channel loop on its own inputs:
    rerun with an ideal detector (same seed), then apply the dead-time rule by hand."""
    n = 300
    kw = dict(beam="strong", background_mhz=300.0, range_gate_m=20.0, paralyzable=paralyzable)
    ideal = pmt.detect(flat_returns(np.random.default_rng(7), n), Instrument(ideal_detector=True, **kw),
                       np.random.default_rng(8), gate_center_ns=np.full(n, T0))
    real = pmt.detect(flat_returns(np.random.default_rng(7), n), Instrument(**kw),
                      np.random.default_rng(8), gate_center_ns=np.full(n, T0))
    last, keep = {}, []
    for s, c, t in zip(ideal.shot, ideal.channel, ideal.time_ns):   # sorted by shot, time
        key = (s, c)
        if key not in last or t - last[key] >= 3.0:
            keep.append(True)
            last[key] = t
        else:
            keep.append(False)
            if paralyzable:
                last[key] = t
    keep = np.array(keep)
    assert np.array_equal(real.time_ns, ideal.time_ns[keep])
    assert np.array_equal(real.channel, ideal.channel[keep])


def test_classifier_separates_signal_from_noise(rng):
    """A synthetic track: a surface line plus uniform noise in a 30 m gate."""
    n_shots, gate = 4000, 30.0
    z = 2.0 * np.sin(np.arange(n_shots) / 300.0)
    s_shot = np.repeat(np.arange(n_shots), 3)
    s_h = z[s_shot] + 0.1 * rng.standard_normal(s_shot.size)
    n_shot = rng.integers(0, n_shots, 2 * n_shots)                 # 2 noise photons per shot
    n_h = z[n_shot] + rng.uniform(-gate / 2, gate / 2, n_shot.size)
    shot = np.concatenate([s_shot, n_shot])
    h = np.concatenate([s_h, n_h])
    truth = np.r_[np.ones(s_shot.size, bool), np.zeros(n_shot.size, bool)]
    conf = classify.signal_confidence(shot=shot, h_m=h, gate_center_h_m=z, range_gate_m=gate)
    r = classify.classification_rates(conf, truth)
    assert r["hit_rate"] > 0.99
    # noise inside +-1 bin of the surface is indistinguishable: about 3 bins of 0.5 m out of 30 m
    assert r["false_alarm_rate"] < 0.12
    # the noise level given (ATL03's way, night.atl03_leak) as the one estimated: the same test
    t = classify.histogram_test(shot=shot, h_m=h, gate_center_h_m=z, range_gate_m=gate)
    given = classify.histogram_test(shot=shot, h_m=h, gate_center_h_m=z, range_gate_m=gate,
                                    noise_per_bin=t.noise_per_bin)
    assert np.array_equal(t.conf, conf) and np.array_equal(given.conf, conf)
    assert np.array_equal(given.tail_p, t.tail_p)
    # and with no noise at all, everything is signal
    conf = classify.signal_confidence(shot=s_shot, h_m=s_h, gate_center_h_m=z, range_gate_m=gate)
    assert np.all(conf == 4)


def test_instrument_noise_fields_validated():
    for field, value in (("background_mhz", -1.0), ("dark_count_hz", -5.0), ("range_gate_m", 0.0)):
        with pytest.raises(ValueError, match=f"^{field}"):
            Instrument(**{field: value})
