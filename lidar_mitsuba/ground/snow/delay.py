"""How much later a snowpack returns the laser, in closed form: the apparent depth of the
photons that the snow's volume scatters back. Pure numpy (and ``scipy.special``).

A photon that enters snow at 532 nm is scattered thousands of times before it leaves (the
single-scattering albedo is 1 - 4e-6); its path inside, ``L``, delays it by ``n_g L / c``
(``n_g`` the pack's group index), so ATLAS places it ``d = n_g L / 2`` below the surface. For
a half-space under a pencil beam, diffusion theory gives the distribution of ``L`` of all the
light that comes back, whatever point of the surface it leaves from
(:class:`~lidar_mitsuba.ground.snow.DiffusionHalfSpace`: Patterson, Chance & Wilson 1989,
Appl. Opt. 28, 2331; the extrapolated boundary of Farrell, Patterson & Wilson 1992). The
footprint (11 m) and the field of view (42 m) are far wider than the distance a returned
photon wanders sideways (``sqrt(L / mu_s')``: 0.15 m for L = 20 m), so all of it is seen.

Its tail is long: beyond a few transport mean free paths the returned power falls as
``L^(-3/2)``, so the share returned from more than ``d`` below falls only as
``(5 / 3) sqrt(3 n_g / (2 pi mu_s' d))`` until absorption cuts it off near ``d ~ n_g / (2 mu_a)``
(tens of metres at 532 nm). For wind-packed snow a few per cent of the light comes back from
more than half a metre below, and some from tens of metres: the surface photons' lower tail,
and counts that ATL03's 50-shot background histogram (a band 5 km tall) takes for
background. ``docs/physics/night-floor.md`` has the derivation.

This is the lidar equation's volume part; the twin's flat surface (a Ward BRDF) returns its
diffuse lobe at once. :func:`delay_heights` moves a share of the twin's surface photons down
by draws from this law, after the detector (dead time saw them undelayed: ESTIMATE, it
overstates the tail by at most the dead-time loss of the returns it moves, a few per cent).
"""
from __future__ import annotations

import math

import numpy as np

from . import DiffusionHalfSpace, SnowVolume

DEPTH_GRID_M = np.concatenate([[0.0], np.geomspace(1e-5, 2000.0, 1200)])
"""Apparent depths [m] on which the law is tabulated for sampling (log-spaced: the law spans
sub-millimetre to kilometres; linear interpolation between nodes)."""


def apparent_depth_sf(vol: SnowVolume, depth_m) -> np.ndarray:
    """The share of the light the snow returns that ATLAS places more than ``depth_m`` [m]
    below its surface (the survival function of ``d = n_g L / 2``; closed form,
    :meth:`~lidar_mitsuba.ground.snow.DiffusionHalfSpace.path_cdf` normalised by the total).
    The half-space has ``vol``'s reduced scattering and absorption (its depth is ignored)."""
    half: DiffusionHalfSpace = vol.diffusion()
    path = 2.0 * np.asarray(depth_m, np.float64) / vol.group_index
    return 1.0 - half.path_cdf(path) / half.total_reflectance()


def sample_apparent_depth_m(vol: SnowVolume, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n,) apparent depths [m] drawn from the law (inverse CDF on :data:`DEPTH_GRID_M`)."""
    cdf = 1.0 - apparent_depth_sf(vol, DEPTH_GRID_M)
    cdf[0] = 0.0
    cdf = np.maximum.accumulate(cdf)
    u = rng.random(int(n)) * cdf[-1]
    return np.interp(u, cdf, DEPTH_GRID_M)


def volume_share(*, rho_d: float, rho_s: float, alpha: float) -> float:
    """The share of a Ward surface's nadir return carried by its diffuse lobe (the light the
    volume scatters back; the specular lobe is the grains' first surface): ``(rho_d / pi) /
    (rho_d / pi + rho_s / (4 pi alpha^2))``."""
    diffuse = rho_d / math.pi
    return diffuse / (diffuse + rho_s / (4.0 * math.pi * alpha ** 2))


def delay_heights(dh_m, vol: SnowVolume, *, share: float,
                  rng: np.random.Generator) -> np.ndarray:
    """Heights [m] of surface photons ``dh_m`` with a ``share`` of them (drawn at random)
    lowered by the snow's apparent depth (:func:`sample_apparent_depth_m`)."""
    dh = np.array(dh_m, np.float64, copy=True)
    pick = rng.random(dh.size) < share
    dh[pick] -= sample_apparent_depth_m(vol, int(pick.sum()), rng)
    return dh


def averaged_pack(vol: SnowVolume) -> SnowVolume:
    """One half-space for a pack with a crust over it: the reduced scattering, absorption and
    group index averaged over the pack's depth, weighted by each layer's thickness (ESTIMATE:
    the photons that come back from more than a few centimetres below have crossed both
    layers; the layered walk, :mod:`lidar_mitsuba.studies.sea_ice`, traces them apart). A pack
    without a crust is returned as it is."""
    if not vol.crust_m or vol.crust is None or not math.isfinite(vol.depth_m):
        return vol
    w = vol.crust_m / vol.depth_m
    c = vol.crust

    def mean(a, b):
        return w * a + (1.0 - w) * b
    mus = mean(c.reduced_scattering_per_m, vol.reduced_scattering_per_m)
    return SnowVolume(sigma_s_per_m=mus / (1.0 - vol.g), g=vol.g,
                      sigma_a_per_m=mean(c.sigma_a_per_m, vol.sigma_a_per_m),
                      group_index=mean(c.group_index, vol.group_index))
