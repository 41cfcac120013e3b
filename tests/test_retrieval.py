"""Elevation retrieval (lidar_mitsuba.products.retrieval): photon heights, bias and precision with their
standard errors, the per-window / per-channel report and its text table. Pure numpy.

Tolerances: exact arithmetic is compared exactly (or to float64 rounding); the one Monte Carlo
check (the standard errors against the spread of many Gaussian samples) uses Z = 4.5 standard
errors of that spread, plus the known error of the normal approximation (stated there).
"""
import math

import numpy as np
import pytest
from scipy.special import gammaln

from lidar_mitsuba.constants import ALTITUDE_M
from lidar_mitsuba.products.retrieval import (ElevationStats, elevation_report, elevation_stats,
                                              format_report, photon_heights_m)

Z = 4.5
C_M_PER_S = 299_792_458.0            # SI definition, independent of lidar_mitsuba.constants


# ---------------------------------------------------------------------- photon_heights_m

def test_photon_heights_are_altitude_minus_half_the_light_path():
    """h = altitude - c t / 2, with c written out independently (m/s, t in ns)."""
    h = np.array([-12.5, 0.0, 1.234, 8848.86])
    t_ns = 2.0 * (ALTITUDE_M - h) / C_M_PER_S * 1e9
    got = photon_heights_m(t_ns, altitude_m=ALTITUDE_M)
    assert got.dtype == np.float64 and got.shape == h.shape
    # float64 at 3.3e6 ns carries ~5e-10 ns (7e-11 m): a round trip is exact to < 1 um
    np.testing.assert_allclose(got, h, rtol=0, atol=1e-6)
    assert photon_heights_m([0.0], altitude_m=123.0)[0] == 123.0       # t = 0: at the spacecraft


def test_photon_heights_resolve_a_millimetre_at_orbital_range():
    """At 496 km a 1 mm height change is 6.7 ps of round trip out of 3.3 ms: float64 keeps it
    (to ~1e-10 m), float32 could not (its spacing at 3.3e6 ns is 0.25 ns = 3.7 cm)."""
    h = 1.234 + 1e-3 * np.arange(5)                  # five heights, 1 mm apart
    t_ns = 2.0 * (ALTITUDE_M - h) / C_M_PER_S * 1e9
    got = photon_heights_m(t_ns, altitude_m=ALTITUDE_M)
    np.testing.assert_allclose(np.diff(got), 1e-3, rtol=0, atol=1e-8)
    # the float32 round trip of the same times collapses the millimetres
    assert np.unique(t_ns.astype(np.float32)).size < h.size
    # integer nanoseconds are promoted, not truncated to an integer height
    assert photon_heights_m(np.array([3_308_859], np.int64), altitude_m=ALTITUDE_M).dtype == np.float64


# ------------------------------------------------------------------------ elevation_stats

def test_elevation_stats_on_known_arrays():
    s = elevation_stats(np.array([1.0, 2.0, 3.0, 4.0]), shots=8)
    std = math.sqrt(5.0 / 3.0)                       # ddof = 1: sum of squares 5 over n - 1 = 3
    assert isinstance(s, ElevationStats)
    assert s.bias_m == 2.5
    assert s.std_m == pytest.approx(std, rel=1e-15)
    assert s.bias_se_m == pytest.approx(std / 2.0, rel=1e-15)              # std / sqrt(4)
    # kurtosis: central moments m2 = 1.25, m4 = 2.5625, g2 = m4 / m2^2 - 3 = -1.36; the
    # estimator G2 = ((n + 1) g2 + 6) (n - 1) / ((n - 2) (n - 3)) = -1.2, kappa = 1.8, and
    # SE = std sqrt((kappa - (n - 3) / (n - 1)) / (4 n)) = std sqrt((1.8 - 1/3) / 16)
    assert s.std_se_m == pytest.approx(std * math.sqrt((1.8 - 1.0 / 3.0) / 16.0), rel=1e-12)
    assert (s.n_photons, s.shots, s.photons_per_shot) == (4, 8, 0.5)
    assert s.to_dict() == {"bias_m": s.bias_m, "bias_se_m": s.bias_se_m, "std_m": s.std_m,
                           "std_se_m": s.std_se_m, "n_photons": 4, "shots": 8,
                           "photons_per_shot": 0.5}
    assert type(s.n_photons) is int and type(s.shots) is int


def test_elevation_stats_nan_rules():
    """No photon: everything NaN but the counts. One photon: a bias, no spread, no errors.
    No shot: photons per shot NaN."""
    s0 = elevation_stats(np.array([]), shots=10)
    assert all(math.isnan(v) for v in (s0.bias_m, s0.bias_se_m, s0.std_m, s0.std_se_m))
    assert (s0.n_photons, s0.shots, s0.photons_per_shot) == (0, 10, 0.0)
    s1 = elevation_stats(np.array([0.25]), shots=4)
    assert s1.bias_m == 0.25 and s1.n_photons == 1 and s1.photons_per_shot == 0.25
    assert all(math.isnan(v) for v in (s1.bias_se_m, s1.std_m, s1.std_se_m))
    assert math.isnan(elevation_stats(np.array([1.0, 2.0]), shots=0).photons_per_shot)


def test_standard_errors_match_the_spread_of_many_samples(rng):
    """M = 20000 samples of n = 50 Gaussian residuals (sd 0.3 m): the spread over samples of
    std_m is what std_se_m claims, and the spread of bias_m what bias_se_m claims.

    Tolerance: the sd of M nearly normal values has relative standard error ~1/sqrt(2 (M - 1))
    (0.5 %; taken from the sample's kurtosis below), times Z; plus the known bias of the
    formulas' mean: E[s] = c4 sigma, so mean(bias_se_m) is c4 sigma / sqrt(n) (0.5 % low);
    sigma / sqrt(2 (n - 1)) is the normal approximation of the exact sd of s,
    sigma sqrt(1 - c4^2) (0.25 % low at n = 50); and std_se_m takes the square root of a
    noisy kurtosis estimate, which by Jensen is low by Var(X) / (8 E[X]^2) with X = kappa -
    (n - 3) / (n - 1), E[X] = 2 n / (n - 1) and Var(X) = Var(G2) = 24 n (n - 1)^2 / ((n - 3)
    (n - 2) (n + 3) (n + 5)) for normal data (1.3 % at n = 50). A wrong formula
    (std / sqrt(n) for std_se_m, std / sqrt(n - 1) or std / sqrt(2 n) for bias_se_m) would
    be off by 41 %."""
    m, n, sigma = 20000, 50, 0.3
    x = 0.05 + sigma * rng.standard_normal((m, n))
    st = [elevation_stats(row, shots=n) for row in x]
    std = np.array([s.std_m for s in st])
    bias = np.array([s.bias_m for s in st])
    c4 = math.sqrt(2.0 / (n - 1)) * math.exp(gammaln(n / 2) - gammaln((n - 1) / 2))
    var_g2 = 24.0 * n * (n - 1) ** 2 / ((n - 3) * (n - 2) * (n + 3) * (n + 5))
    jensen = var_g2 / (8.0 * (2.0 * n / (n - 1)) ** 2)
    for values, claimed, formula_bias in (
            (std, np.array([s.std_se_m for s in st]),
             math.sqrt(1 - c4 ** 2) / (c4 / math.sqrt(2 * (n - 1))) - 1 + jensen),
            (bias, np.array([s.bias_se_m for s in st]), 1 / c4 - 1)):
        spread = values.std(ddof=1)
        d = values - values.mean()
        kurt = np.mean(d ** 4) / np.mean(d ** 2) ** 2
        rel_se = math.sqrt((kurt - 1) / (4 * m))            # relative SE of the spread
        assert abs(spread / claimed.mean() - 1) < Z * rel_se + formula_bias
    assert abs(bias.mean() - 0.05) < Z * sigma / math.sqrt(m * n)


def test_std_standard_error_follows_a_heavy_tail(rng):
    """Residuals with a tail like twice-scattered photons: 99.5 % N(0, 0.15 m), 0.5 % N(0, 3 m)
    (kurtosis ~ 400). Over M = 2000 samples of n = 4000, the spread of std_m is what
    std_se_m claims, where the normal-theory std / sqrt(2 (n - 1)) claims ~11x too little.

    Tolerance: the claimed SE comes from each sample's own kurtosis, itself noisy and skewed
    with so rare a tail, so the mean claim is compared with the spread to within 25 %: far
    tighter than the factor the normal formula is off by; the spread's own relative SE
    (~sqrt((kurtosis of s - 1) / (4 M)), a few per cent) is inside that."""
    m, n = 2000, 4000
    tail = rng.random((m, n)) < 0.005
    x = np.where(tail, 3.0, 0.15) * rng.standard_normal((m, n))
    st = [elevation_stats(row, shots=n) for row in x]
    std = np.array([s.std_m for s in st])
    claimed = np.array([s.std_se_m for s in st])
    spread = std.std(ddof=1)
    assert abs(claimed.mean() / spread - 1) < 0.25
    normal = std.mean() / math.sqrt(2 * (n - 1))
    assert spread / normal > 8


# ----------------------------------------------------------------------- elevation_report

@pytest.fixture
def photons(rng):
    """2500 shots, 4 channels, ~3 photons a shot, sorted by shot; shot 2000-2099 empty."""
    n_shots, n_channels = 2500, 4
    shot = np.sort(rng.integers(0, n_shots, 7500))
    shot = shot[(shot < 2000) | (shot >= 2100)]
    channel = rng.integers(0, n_channels, shot.size)
    dh = 0.02 + 0.1 * rng.standard_normal(shot.size)
    return {"dh_m": dh, "shot": shot, "channel": channel, "n_shots": n_shots,
            "n_channels": n_channels}


def test_report_windows_and_channels_partition_the_photons(photons):
    rep = elevation_report(**photons, window_shots=1000)
    dh, shot, channel = photons["dh_m"], photons["shot"], photons["channel"]
    assert rep.overall == elevation_stats(dh, shots=2500)
    assert rep.window_shots == 1000
    # windows: 0-999, 1000-1999, 2000-2499 (the last one short)
    assert [(w["window"], w["first_shot"], w["last_shot"], w["shots"]) for w in rep.windows] == \
        [(0, 0, 999, 1000), (1, 1000, 1999, 1000), (2, 2000, 2499, 500)]
    assert sum(w["n_photons"] for w in rep.windows) == dh.size
    assert sum(c["n_photons"] for c in rep.channels) == dh.size
    for w in rep.windows:
        sel = (shot >= w["first_shot"]) & (shot <= w["last_shot"])
        expect = elevation_stats(dh[sel], shots=w["shots"]).to_dict()
        assert {k: w[k] for k in expect} == expect
    assert [c["channel"] for c in rep.channels] == [0, 1, 2, 3]
    for c in rep.channels:
        expect = elevation_stats(dh[channel == c["channel"]], shots=2500).to_dict()
        assert {k: c[k] for k in expect} == expect
    d = rep.to_dict()
    assert d["bias_m"] == rep.overall.bias_m and d["window_shots"] == 1000
    assert d["windows"] == rep.windows and d["channels"] == rep.channels


def test_report_window_edges(photons):
    """One window when it spans the track; a window per shot at window_shots = 1; a window
    with no photon has NaN statistics; windows < 1 shot are refused."""
    rep = elevation_report(**photons, window_shots=10_000)
    assert len(rep.windows) == 1 and rep.windows[0]["n_photons"] == photons["dh_m"].size
    small = {k: (v[:40] if isinstance(v, np.ndarray) else v) for k, v in photons.items()}
    small["n_shots"] = int(small["shot"][-1]) + 1
    rep1 = elevation_report(**small, window_shots=1)
    assert len(rep1.windows) == small["n_shots"]
    assert [w["n_photons"] for w in rep1.windows] == list(
        np.bincount(small["shot"], minlength=small["n_shots"]))
    rep = elevation_report(**photons, window_shots=100)
    gap = rep.windows[20]                               # shots 2000-2099 have no photon
    assert gap["first_shot"] == 2000 and gap["n_photons"] == 0 and math.isnan(gap["bias_m"])
    with pytest.raises(ValueError, match="window"):
        elevation_report(**photons, window_shots=0)


# -------------------------------------------------------------------------- format_report

def test_format_report_prints_the_numbers_in_cm(photons):
    rep = elevation_report(**photons, window_shots=1000)
    text = format_report(rep, title="strong beam, test")
    lines = text.splitlines()
    assert lines[0] == "strong beam, test"
    assert "bias [cm]" in lines[1] and "std [cm]" in lines[1]
    def cells(s):                       # the numbers of a row, as the table prints them
        return [str(s["n_photons"]), f"{s['photons_per_shot']:.3f}", f"{100 * s['bias_m']:.2f}",
                f"{100 * s['bias_se_m']:.2f}", f"{100 * s['std_m']:.2f}"]

    overall = next(line for line in lines if line.startswith("overall"))
    assert overall.split()[1:] == cells(rep.overall.to_dict())
    assert abs(100 * rep.overall.bias_m) > 1.0          # 2 cm: printed 2.xx, not 0.02
    for c in rep.channels:
        row = next(line for line in lines if line.startswith(f"channel {c['channel']}"))
        assert row.split()[2:] == cells(c)
    for w in rep.windows:
        row = next(line for line in lines if line.startswith(f"window {w['window']}"))
        assert row.split()[2:] == cells(w)
    assert sum(line.startswith("window") for line in lines) == 3
    # a single window is not repeated; no title, no title line
    one = format_report(elevation_report(**photons, window_shots=5000))
    assert not any(line.startswith("window") for line in one.splitlines())
    assert one.splitlines()[0].split()[0] == "photons"


def test_report_refuses_photons_outside_its_shots_or_channels():
    """A photon of shot 3 in a 3-shot report would count overall but in no window."""
    with pytest.raises(ValueError, match="shot indices"):
        elevation_report(dh_m=[0.1, 0.2, 0.3], shot=[0, 1, 3], channel=[0, 0, 0],
                           n_shots=3, n_channels=1)
    with pytest.raises(ValueError, match="channels"):
        elevation_report(dh_m=[0.1, 0.2], shot=[0, 1], channel=[0, 2], n_shots=3,
                           n_channels=2)
    rep = elevation_report(dh_m=[0.1, 0.2], shot=[0, 1], channel=[0, 1], n_shots=3,
                             n_channels=2, window_shots=2)           # plain lists work
    assert sum(w["n_photons"] for w in rep.windows) == rep.overall.n_photons == 2
