"""The shade a broken cloud deck casts on the clear gaps between its clouds. Pure numpy.

A beam whose segments are partly cloudy (a real file's own flags: a fraction ``c`` of them
under a layer of optical depth ``tau``) has clear segments *in the gaps of a deck*. The
sunlight that lights such a gap's surface, and the air below the deck above it, crossed the
deck's height sunward of it: ``d = z / tan(h)`` away, 55-70 km for a deck 4-5 km up at a
4 deg sun. Whether that slant ray met a cloud is independent of the gap being clear at nadir
when ``d`` is much longer than the clouds and gaps; the tilted independent pixel
approximation (Varnai & Davies 1999, J. Atmos. Sci. 56, 4206: each sunlit column traced
along the sun's slant path, the columns independent) then gives the expected sunlight below
the deck as::

    E_below = (1 - c) E_clear + c (1 - R(mu0)) E_clear = (1 - c R(mu0)) E_clear,

``R(mu0)`` the fraction of a collimated beam at ``mu0`` (the sun's apparent elevation's
sine) the layer reflects; a conservative layer (water droplets at 532 nm) transmits the rest,
forward-scattered, onward to the region below (:func:`shade_factor`). The air above the deck
is lit as in clear sky. ESTIMATE: the deck's cover sunward is its cover along the track (the
track's clouds are the only sample of the field the file gives), random in position.

``R(mu0)`` is computed by Monte Carlo for a plane-parallel Henyey-Greenstein layer
(:func:`layer_reflectance`): exact in expectation, unlike the delta-Eddington closed form
(Joseph, Wiscombe & Weinman 1976, J. Atmos. Sci. 33, 2452), which is good at a high sun
(within 0.01 of it at normal incidence for tau 1-10, ``tests/test_cloud_shade.py``) and 15-30 %
low at grazing incidence (0.50 against 0.60 for tau 1.1, g 0.85 at mu0 0.07). The walk is
:func:`.hg_walk.walk` (the one the nadir reflectance factor of :mod:`.cloud_reflection`
takes), scored by counting the photons that leave the top (:class:`.hg_walk.Escape`). For
the clouds a run makes (water and ice, ``tau`` <= 20) and a sun above ``mu0`` 0.02 (1.1 deg)
:func:`shade_factor` reads ``R`` from the table that walk made once
(:mod:`lidar_mitsuba.atmosphere.cloud_reflection_table`: ``R = 1 - t`` for a conservative
layer, ``t`` its total transmittance; ``tests/test_cloud_shade.py`` checks the two agree
within their sampling errors) and runs the Monte Carlo only for other layers and a lower
sun.
"""
from __future__ import annotations

import functools

import numpy as np

from ..constants import ParameterError
from . import cloud_reflection_table
from .hg_walk import Escape, check_layer, collimated, walk

PHOTONS = 1 << 15
"""Photons per :func:`layer_reflectance` estimate: a standard error of at most
``0.5 / sqrt(2^15)`` = 0.003 (binomial)."""
MAX_EVENTS = 3000
"""Scattering events followed per photon (a photon still inside after them is counted as
transmitted: at tau <= 10, g 0.85 fewer than 1e-4 of them)."""


@functools.lru_cache(maxsize=256)
def layer_reflectance(*, optical_depth: float, g: float, mu0: float,
                      photons: int = PHOTONS, seed: int = 0) -> float:
    """Fraction [1] of a collimated beam incident at ``mu0`` (cosine of its zenith angle, in
    (0, 1]) that a plane-parallel, non-absorbing layer of ``optical_depth`` with a
    Henyey-Greenstein phase function of asymmetry ``g`` reflects (leaves through its top),
    with nothing below it. Monte Carlo, ``photons`` photons, seeded: exact in expectation,
    binomial standard error ``sqrt(R (1 - R) / photons)``."""
    check_layer(optical_depth=optical_depth, g=g, mu0=mu0)
    if optical_depth == 0.0:
        return 0.0
    escape = Escape()
    walk(optical_depth=optical_depth, g=g, d=collimated(photons, mu0),
         rng=np.random.default_rng(seed), scorings=(escape,), max_events=MAX_EVENTS)
    return escape.top / photons


def shade_factor(*, cover: float, optical_depth: float, g: float,
                 solar_elevation_deg: float) -> float:
    """The sunlight below a broken deck in its gaps, relative to clear sky [1]:
    ``1 - cover R(mu0)`` (module docstring), ``mu0`` the sine of the sun's apparent
    elevation (:func:`lidar_mitsuba.sky.apparent_mu0` of the geometric
    ``solar_elevation_deg``). ``R`` from the shipped table where it holds the layer (its
    water and ice ``g``, ``optical_depth`` up to 20, ``mu0`` >= 0.02:
    :func:`lidar_mitsuba.atmosphere.cloud_reflection_table.reflectance`, ``1 - t(mu0)``), else by
    :func:`layer_reflectance`. 1 with the sun at or below the horizon (the twilight sky's
    light comes down from high above any deck: no shade modelled) or no cover."""
    from ..sky import apparent_mu0
    if not (0.0 <= cover <= 1.0):
        raise ParameterError("cover", f"must be in [0, 1] (got {cover})")
    h = float(solar_elevation_deg)
    if cover == 0.0 or optical_depth <= 0.0 or h <= 0.0:
        return 1.0
    mu0, tau = float(apparent_mu0(h)), float(optical_depth)
    if (cloud_reflection_table.covers(optical_depth=tau, g=g, single_scattering_albedo=1.0)
            and mu0 >= cloud_reflection_table.load()["mu0s"][0]):
        r = float(cloud_reflection_table.reflectance(optical_depth=tau, g=g, mu0=mu0)[0])
    else:                                     # 0.001 steps: the cache's key
        r = layer_reflectance(optical_depth=round(tau, 3), g=float(g),
                              mu0=max(round(mu0, 3), 1e-3))
    return 1.0 - cover * r
