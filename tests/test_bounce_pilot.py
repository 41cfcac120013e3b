"""``max_depth="auto"``: a two-bounce pilot decides whether single bounce keeps a run's answer.

The decision rule (:func:`single_bounce_error`) is pure numpy and is checked against closed
forms; the Monte Carlo error it compares with (standard errors of a mean and of a standard
deviation) is checked against the spread of repeated samples; the pilot is checked to choose
single bounce where nothing bounces twice and two bounces on the default rough fractal, and
to leave the run's own photons untouched.
"""
import math

import numpy as np
import pytest
from scipy import stats

from lidar_mitsuba.constants import ParameterError
from lidar_mitsuba.instrument import Instrument
from lidar_mitsuba.trace.pilot import single_bounce_error
from lidar_mitsuba.run import simulate
from lidar_mitsuba.ground.surface import SurfaceSpec


def _gaussian_nodes(n, sigma):
    """n equal-weight points with the quantiles of N(0, sigma^2), centred exactly."""
    x = sigma * stats.norm.ppf((np.arange(n) + 0.5) / n)
    return x - x.mean()


def test_single_bounce_error_closed_form():
    """Depth-1 returns x_i (weight 1 each, mean 0, variance s^2) and depth-2 returns all at
    height error D with total weight W: the full model's mean is m = W D / (n + W), its
    variance v = (n s^2 + W D^2) / (n + W) - m^2 and its fourth central moment
    (sum (x_i - m)^4 + W (D - m)^4) / (n + W); the Monte Carlo errors are sqrt(v / N) and
    sqrt(v (k - 1) / (4 N)) with k that moment over v^2. Deterministic input, so the
    comparison is to rounding."""
    n, D, W, N = 20001, -3.0, 40.0, 1500.0
    x = _gaussian_nodes(n, 0.14)
    s2 = np.mean(x ** 2)
    dh = np.concatenate([x, np.full(8, D)])
    w = np.concatenate([np.ones(n), np.full(8, W / 8)])
    depth = np.concatenate([np.ones(n, np.uint8), np.full(8, 2, np.uint8)])
    out = single_bounce_error(dh_m=dh, weight=w, depth=depth, n_photons=N)
    mean = W * D / (n + W)
    var = (n * s2 + W * D ** 2) / (n + W) - mean ** 2
    k = (np.sum((x - mean) ** 4) + W * (D - mean) ** 4) / (n + W) / var ** 2
    assert out["d_bias_m"] == pytest.approx(mean, rel=1e-9)
    assert out["d_std_m"] == pytest.approx(math.sqrt(var) - math.sqrt(s2), rel=1e-9)
    assert out["mc_bias_m"] == pytest.approx(math.sqrt(var / N), rel=1e-9)
    assert out["mc_std_m"] == pytest.approx(math.sqrt(var * (k - 1) / (4 * N)), rel=1e-9)
    assert out["depth2_weight_fraction"] == pytest.approx(W / (n + W), rel=1e-12)
    # the second bounce moves the bias by -0.60 cm against a Monte Carlo error of 0.50 cm
    assert not out["single_bounce_enough"]
    # zero-weight and non-finite returns are ignored; a tiny far tail is below the threshold
    w_small = np.concatenate([np.ones(n), np.full(8, 1e-4)])
    dh_bad = np.concatenate([dh, [np.nan, 5.0]])
    out = single_bounce_error(dh_m=dh_bad, weight=np.concatenate([w_small, [1.0, 0.0]]),
                              depth=np.concatenate([depth, [2, 2]]), n_photons=N)
    assert out["single_bounce_enough"] and abs(out["d_bias_m"]) < 1e-6
    with pytest.raises(ValueError, match="first-surface"):
        single_bounce_error(dh_m=[1.0], weight=[1.0], depth=[2], n_photons=10)


@pytest.mark.parametrize("dist,kurtosis", [("normal", 3.0), ("laplace", 6.0)])
def test_monte_carlo_errors_match_repeated_samples(rng, dist, kurtosis):
    """The rule's Monte Carlo errors are the standard errors of the mean and of the sample
    standard deviation of N photons. Over R = 4000 repeated samples of N = 1000 their spread
    is estimated to a relative standard error of ~1/sqrt(2 R) = 1.1 % (the sample std of R
    near-normal values); the tolerance is 5 of those plus 1.5 % for the O(1/N) bias of the
    asymptotic std formula at this N."""
    N, R = 1000, 4000
    sigma = 0.14
    draw = {"normal": lambda size: rng.normal(0, sigma, size),
            "laplace": lambda size: rng.laplace(0, sigma / math.sqrt(2), size)}[dist]
    samples = draw((R, N))
    x_big = draw(400_000)                 # the "pilot": weights 1, all single bounce
    out = single_bounce_error(dh_m=x_big, weight=np.ones_like(x_big),
                              depth=np.ones(x_big.size, np.uint8), n_photons=N)
    tol = 5 / math.sqrt(2 * R) + 0.015
    assert samples.mean(axis=1).std(ddof=1) == pytest.approx(out["mc_bias_m"], rel=tol)
    assert samples.std(axis=1, ddof=1).std(ddof=1) == pytest.approx(out["mc_std_m"], rel=tol)
    assert out["mc_std_m"] == pytest.approx(sigma * math.sqrt((kurtosis - 1) / (4 * N)), rel=0.05)


def test_auto_picks_single_bounce_on_planes_and_smooth_terrain():
    """A plane is single bounce without a pilot; on a smooth fractal (p = 3) the pilot finds
    no second-bounce weight, picks single bounce, and the run's photons are exactly those of
    an explicit max_depth 1 run (the pilot draws its own random numbers)."""
    flat = simulate(surface=SurfaceSpec(kind="slope", slope_deg=30.0), shots=50, seed=1,
                    progress=False)
    assert flat.config["max_depth"] == 1 and flat.config["bounce_pilot"] is None
    kw = dict(instrument=Instrument(beam="weak"), surface=SurfaceSpec(p=3.0),
              shots=400, seed=3, progress=False)
    auto = simulate(**kw)
    one = simulate(max_depth=1, **kw)
    pilot = auto.config["bounce_pilot"]
    assert auto.config["max_depth"] == 1 and pilot["single_bounce_enough"]
    assert pilot["depth2_weight_fraction"] < 1e-4 and pilot["pilot_shots"] == 400
    np.testing.assert_array_equal(auto.detections.time_ns, one.detections.time_ns)
    assert "keeps the answer" in auto.config["choices"][0]


def test_auto_picks_two_bounces_on_the_default_fractal():
    """On the default p = 1.8 snow the second bounce (~0.15 % of the weight, delayed by
    metres) moves the bias by ~-0.4 cm, more than half a 1000-shot run's Monte Carlo error
    (the bench's simplification table measures -0.5 cm over paired seeds)."""
    res = simulate(instrument=Instrument(beam="weak"), shots=1000, seed=1, progress=False)
    pilot = res.config["bounce_pilot"]
    assert res.config["max_depth"] == 2 and not pilot["single_bounce_enough"]
    assert -pilot["d_bias_m"] > 0.5 * pilot["mc_bias_m"] > 0 and pilot["d_std_m"] > 0
    assert 1e-4 < pilot["depth2_weight_fraction"] < 0.02
    assert (res.returns.depth == 2).any()


@pytest.mark.parametrize("bad", [0, 65, 1.5, True, "two"])
def test_bad_max_depth(bad):
    with pytest.raises(ParameterError, match="max_depth"):
        simulate(surface=SurfaceSpec(kind="flat"), shots=5, max_depth=bad, progress=False)


def test_pilot_without_returns_in_the_gate_traces_two_bounces(monkeypatch):
    """If the pilot has nothing to judge (no first-surface return in the gate), auto takes the
    fuller model and says so instead of failing."""
    import lidar_mitsuba.trace.pilot as sim

    def nothing(**kw):
        raise ValueError("the pilot has no first-surface returns")
    monkeypatch.setattr(sim, "single_bounce_error", nothing)
    res = simulate(surface=SurfaceSpec(p=3.0, size_m=128.0), shots=50, seed=1, progress=False)
    assert res.config["max_depth"] == 2 and not res.config["bounce_pilot"]["single_bounce_enough"]
    assert "no first-surface return" in res.config["choices"][0]
