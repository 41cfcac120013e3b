"""The detector's compiled binomial thinning (lidar_mitsuba.detector.draws) against numpy's
``Generator.binomial``, its reference: the same draws and the same stream after them, for
counts as the detector's Poisson arrivals give them, both sides of p = 1/2, zeros, and
counts past inversion's range (numpy's own draws)."""
import numpy as np
import pytest

from lidar_mitsuba.detector import draws


@pytest.mark.parametrize("mean", [0.0, 0.3, 2.3, 9.4, 30.0])
@pytest.mark.parametrize("p", [1e-3, 0.1, 0.4, 0.5, 0.6, 0.9, 0.999])
def test_binomial_is_numpy_s_draws(mean, p):
    counts = np.random.default_rng(11).poisson(mean, 4096)
    a, b = np.random.default_rng([5, 17]), np.random.default_rng([5, 17])
    want, got = a.binomial(counts, p), draws.binomial(b, counts, p)
    assert got.dtype == want.dtype and np.array_equal(got, want)
    assert a.integers(0, 2 ** 62) == b.integers(0, 2 ** 62)          # the stream after them
    if mean and 0 < min(p, 1 - p) * counts.max() <= draws.INVERSION_MAX_MEAN:
        assert draws._compiled_ok()          # (this case ran the compiled loop)


def test_binomial_past_inversion_and_odd_inputs_are_numpy_s():
    """Counts with n p > 30 (numpy's BTPE), p of 0 and 1, an empty and a 2-d array: numpy's
    own draws."""
    for n, p in ((np.array([3, 200, 7]), 0.4), (np.array([5, 6]), 0.0),
                 (np.array([5, 6]), 1.0), (np.zeros(0, np.int64), 0.3),
                 (np.full((3, 4), 9), 0.3)):
        a, b = np.random.default_rng(1), np.random.default_rng(1)
        assert np.array_equal(a.binomial(n, p), draws.binomial(b, n, p))
        assert a.random() == b.random()
