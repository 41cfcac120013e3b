"""Closed forms and references shared by the detector and first-photon-bias tests.

Tolerances. Every Monte Carlo estimate is compared with its truth within Z = 4.5 standard
errors (two-sided p ~ 7e-6 each), the standard error taken from the sample: binomial for
fractions, sd / sqrt(n) for means, sd * sqrt((kurtosis - 1) / (4 n)) for standard deviations,
and batch means (20 independent blocks of shots) for the dead-time-weighted estimators, whose
terms are correlated within a block.
"""
import math

import numpy as np
from scipy import integrate, stats

from lidar_mitsuba.constants import C_M_PER_NS
from lidar_mitsuba.detector.records import Returns

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


def chandrasekhar_h(omega, mu, n=400):
    """Chandrasekhar's H-function of isotropic scattering with single-scattering albedo
    ``omega`` < 1 at ``mu``: the fixed point of 1/H(mu) = 1 - (omega/2) mu int_0^1 H(mu') /
    (mu + mu') dmu' on an n-point Gauss-Legendre grid (converged to 1e-12; H(1) = 1.8502 at
    omega = 0.9 as tabulated by Chandrasekhar, Radiative Transfer, table XIII)."""
    x, w = np.polynomial.legendre.leggauss(n)
    x, w = 0.5 * (x + 1.0), 0.5 * w
    H = np.ones(n)
    for _ in range(10000):
        H_new = 1.0 / (1.0 - 0.5 * omega * x * np.sum(w * H / (x[:, None] + x), axis=1))
        if np.max(np.abs(H_new - H)) < 1e-13:
            break
        H = H_new
    mu = np.asarray(mu, float)
    return 1.0 / (1.0 - 0.5 * omega * mu * np.sum(w * H / (mu[..., None] + x), axis=-1))
