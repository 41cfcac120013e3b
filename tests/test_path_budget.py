"""``paths_per_shot="auto"`` (:mod:`lidar_mitsuba.trace.path_budget`): its run-out bound against the
sampler it bounds, its weight moments against exact ones, the ladder choice, and simulate's
choice against the fixed 128 paths it replaces."""
import math

import numpy as np
import pytest
from scipy import stats

from closed_forms import Z
from lidar_mitsuba.trace import path_budget as pb
from lidar_mitsuba.detector import pmt


def _run_out_rate(weights_of, *, n_shots, k, signal_photons, rng, exchangeable=True):
    """The fraction of shots whose picks ran out, by the detector's own sampler."""
    shot = np.repeat(np.arange(n_shots), k)
    w = weights_of(shot.size)
    *_, run_out = pmt.sample_arrivals(shot, w, n_shots=n_shots, paths_per_shot=k,
                                      signal_photons=signal_photons, rng=rng,
                                      exchangeable=exchangeable)
    return run_out.mean(), w


def test_run_out_probability_is_exact_for_constant_weights(rng):
    """Constant weights, one return per path: every return is accepted, so a shot runs out
    exactly when Poisson(lam) > N. The sampler's rate matches within its binomial SE."""
    n_shots, k, lam = 40000, 8, 4.0
    rate, _ = _run_out_rate(lambda n: np.ones(n), n_shots=n_shots, k=k, signal_photons=lam,
                            rng=rng)
    p = pb.run_out_probability(kept_mean=np.array([lam]), slots=np.array([k]),
                               accept_p=np.array([1.0]))[0]
    assert p == pytest.approx(stats.poisson.sf(k, lam), rel=1e-12)
    assert abs(rate - p) < Z * math.sqrt(p * (1 - p) / n_shots)


@pytest.mark.parametrize("exchangeable", [True, False])
def test_run_out_probability_bounds_the_sampler(rng, exchangeable):
    """Weights 0.5 or 1.5 at random and some paths with no return (weight 0): the bound
    (binomial acceptances, independent of the count) is at or above the sampler's rate, and
    not far above it (within a factor 3 here)."""
    n_shots, k, lam = 40000, 8, 2.5

    def weights(n):
        return rng.choice([0.0, 0.5, 1.5], n, p=[0.2, 0.4, 0.4])
    rate, w = _run_out_rate(weights, n_shots=n_shots, k=k, signal_photons=lam, rng=rng,
                            exchangeable=exchangeable)
    m = w.mean()                                          # mean weight per path
    p = pb.run_out_probability(kept_mean=np.array([lam * m]), slots=np.array([k]),
                               accept_p=np.array([m / 1.5]))[0]
    se = math.sqrt(p * (1 - p) / n_shots)
    assert rate <= p + Z * se and rate >= p / 3


def test_shot_moments_bound_multi_return_paths(rng):
    """Paths of two returns: m and m1 are exact, m2 bounds the mean of (w1 + w2)**2 from
    above and is close when the second returns are weak; with one return per path m2 is
    exact."""
    n_shots, k = 50, 64
    w1 = rng.uniform(0.8, 1.2, (n_shots, k))
    w2 = np.where(rng.random((n_shots, k)) < 0.1, rng.uniform(0, 0.05, (n_shots, k)), 0.0)
    shot = np.repeat(np.arange(n_shots), 2 * k)
    weight = np.stack([w1, w2], axis=2).reshape(-1)
    depth = np.tile([1, 2], n_shots * k)
    keep = weight > 0                                        # as a trace: zero weights dropped
    mom = pb.shot_moments(shot[keep], weight[keep], depth[keep], n_shots=n_shots,
                          paths_per_shot=k, max_depth=2)
    W = w1 + w2
    np.testing.assert_allclose(mom["m"], W.mean(axis=1), rtol=1e-12)
    np.testing.assert_allclose(mom["m1"], w1.mean(axis=1), rtol=1e-12)
    exact = (W ** 2).mean(axis=1)
    assert np.all(mom["m2"] >= exact * (1 - 1e-12)) and np.all(mom["m2"] <= exact * 1.05)
    one = pb.shot_moments(np.repeat(np.arange(n_shots), k), w1.ravel(), np.ones(w1.size),
                          n_shots=n_shots, paths_per_shot=k)
    np.testing.assert_allclose(one["m2"], (w1 ** 2).mean(axis=1), rtol=1e-12)
    assert mom["w_max"] == weight.max()


def _moments(m, cv, w_max, n=200):
    m = np.full(n, float(m))
    return {"m": m, "m1": m, "m2": m * m * (1 + cv * cv), "w_max": float(w_max)}


def test_choose_takes_the_smallest_count_that_meets_both_targets():
    """The choice meets both targets and the count below it does not; heavier weight
    spreads, brighter returns and peakier weights need more paths; nothing lit needs the
    fewest."""
    def check(mom, lam):
        out = pb.choose(moments=mom, kept_per_weight=lam)
        k = out["paths_per_shot"]
        assert out["met"] and out["run_out_fraction"] <= pb.RUN_OUT_MAX
        assert out["extra_variance"] <= pb.EXTRA_VARIANCE_MAX
        if k > pb.LADDER[0]:
            below = pb.choose(moments=mom, kept_per_weight=lam, ladder=(k // 2, k))
            assert below["paths_per_shot"] == k
        return k
    base = check(_moments(1.0, 0.05, 1.1), 3.3)
    assert base == 16                               # strong beam on near-Lambertian snow
    assert check(_moments(1.0, 0.05, 1.1), 0.8) == 8    # weak beam
    assert check(_moments(1.0, 1.0, 1.1), 3.3) > base   # spread weights: noisier means
    assert check(_moments(1.0, 0.05, 1.1), 30.0) > base  # bright: more picks per shot
    assert check(_moments(1.0, 0.05, 5.0), 3.3) > base   # rare heavy weights: more rejections
    dark = pb.choose(moments=_moments(0.0, 0.0, 0.0), kept_per_weight=3.3)
    assert dark["paths_per_shot"] == pb.LADDER[0] and dark["met"]
    top = pb.choose(moments=_moments(1.0, 20.0, 1.1), kept_per_weight=3.3)
    assert top["paths_per_shot"] == pb.LADDER[-1] and not top["met"]
    assert "--paths-per-shot sets more" in pb.explain(top)


def test_simulate_auto_matches_128_paths_single_bounce():
    """The default snow, single bounce: auto traces 16 (strong) and 8 (weak) paths per shot,
    no shot runs out, and bias and precision agree with 128 paths per shot within 4.5
    combined standard errors (independent runs: seeds differ; the single-bounce return is
    near-Gaussian, so the normal-theory SE of the std holds)."""
    from lidar_mitsuba.instrument import Instrument
    from lidar_mitsuba.run import simulate
    for beam, expect in (("strong", 16), ("weak", 8)):
        runs = [simulate(instrument=Instrument(beam=beam), shots=20000, seed=seed,
                         max_depth=1, paths_per_shot=pps, progress=False)
                for seed, pps in ((1, "auto"), (2, 128))]
        assert runs[0].config["paths_per_shot"] == expect
        assert runs[0].config["path_budget"]["met"]
        assert runs[0].detections.run_out_shots.size == 0
        a, b = (r.report().overall for r in runs)
        assert abs(a.bias_m - b.bias_m) < Z * math.hypot(a.bias_se_m, b.bias_se_m)
        assert abs(a.std_m - b.std_m) < Z * math.hypot(a.std_se_m, b.std_se_m)
        assert abs(a.photons_per_shot - b.photons_per_shot) < Z * math.sqrt(
            (a.photons_per_shot + b.photons_per_shot) / 20000)


def test_binomial_and_poisson_functions_equal_scipy_stats_to_the_bit(rng):
    """path_budget computes scipy.stats' binom.pmf, poisson.sf and poisson.isf from the
    scipy.special kernels they call (scipy.stats' import is half a second of every run):
    the same numbers, bit for bit, over the arguments the scout gives (k up to 1024 paths,
    acceptance probabilities in [0, 1] including both ends, Poisson means 1e-6 .. 200)."""
    k = np.arange(0, 1100)[None, :]
    n = np.array([8, 16, 64, 1024, 0])[:, None]
    p = np.array([0.0, 0.3, 0.97, 1.0, 0.5])[:, None]
    assert np.array_equal(pb.binom_pmf(k, n, p), stats.binom.pmf(k, n, p))
    mu = np.concatenate([10 ** rng.uniform(-6, np.log10(200), 50), [1.0, 8.0]])[:, None]
    assert np.array_equal(pb.poisson_sf(k, mu), stats.poisson.sf(k, mu))
    for m in mu[:, 0]:
        for q in (1e-16, 1e-4, 0.5):
            assert pb.poisson_isf(q, m) == stats.poisson.isf(q, m)
