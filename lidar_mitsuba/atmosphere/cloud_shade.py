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
low at grazing incidence (0.50 against 0.60 for tau 1.1, g 0.85 at mu0 0.07).
"""
from __future__ import annotations

import functools
import math

import numpy as np

from ..constants import ParameterError

PHOTONS = 1 << 15
"""Photons per :func:`layer_reflectance` estimate: a standard error of at most
``0.5 / sqrt(2^15)`` = 0.003 (binomial)."""
MAX_EVENTS = 3000
"""Scattering events followed per photon (a photon still inside after them is counted as
transmitted: at tau <= 10, g 0.85 fewer than 1e-4 of them)."""


def check_layer(*, optical_depth: float, g: float, mu0: float) -> None:
    """Refuses (:class:`~lidar_mitsuba.constants.ParameterError`) a plane-parallel layer's
    ``optical_depth`` outside [0, inf), Henyey-Greenstein ``g`` outside (-1, 1) or a beam's
    ``mu0`` outside (0, 1]."""
    if not (0.0 < mu0 <= 1.0):
        raise ParameterError("mu0", f"must be in (0, 1] (got {mu0})")
    if not (optical_depth >= 0.0 and math.isfinite(optical_depth)):
        raise ParameterError("optical_depth", f"must be >= 0 (got {optical_depth})")
    if not (-1.0 < g < 1.0):
        raise ParameterError("g", f"must be in (-1, 1) (got {g})")


def _hg_cosine(g: float, u: np.ndarray) -> np.ndarray:
    """Henyey-Greenstein scattering-angle cosines from uniforms ``u`` (its inverse CDF;
    isotropic for ``g = 0``)."""
    if abs(g) < 1e-6:
        return 2.0 * u - 1.0
    s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u)
    return (1.0 + g * g - s * s) / (2.0 * g)


def _turn(d: np.ndarray, cos_t: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Unit directions ``d`` (n, 3) turned by polar angles of cosine ``cos_t`` and azimuths
    ``phi`` about themselves."""
    sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
    helper = np.where(np.abs(d[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]),
                      np.array([[1.0, 0.0, 0.0]]))
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(d, e1)
    return (d * cos_t[:, None] + e1 * (sin_t * np.cos(phi))[:, None]
            + e2 * (sin_t * np.sin(phi))[:, None])


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
    rng = np.random.default_rng(seed)
    d = np.zeros((photons, 3))
    d[:, 0], d[:, 2] = math.sqrt(1.0 - mu0 * mu0), -mu0          # z up, going down
    depth = np.zeros(photons)                                    # optical depth below the top
    alive = np.ones(photons, bool)
    up = 0
    for _ in range(MAX_EVENTS):
        idx = np.flatnonzero(alive)
        if idx.size == 0:
            break
        new = depth[idx] - np.log(rng.random(idx.size)) * (-d[idx, 2])
        out_top, out_bottom = new < 0.0, new > optical_depth
        up += int(out_top.sum())
        alive[idx[out_top | out_bottom]] = False
        inside = ~out_top & ~out_bottom
        s = idx[inside]
        depth[s] = new[inside]
        d[s] = _turn(d[s], _hg_cosine(g, rng.random(s.size)), 2.0 * np.pi * rng.random(s.size))
    return up / photons


def shade_factor(*, cover: float, optical_depth: float, g: float,
                 solar_elevation_deg: float) -> float:
    """The sunlight below a broken deck in its gaps, relative to clear sky [1]:
    ``1 - cover R(mu0)`` (module docstring), ``mu0`` the sine of the sun's apparent
    elevation (Saemundsson's refraction added to the geometric ``solar_elevation_deg``).
    1 with the sun at or below the horizon (the twilight sky's light comes down from high
    above any deck: no shade modelled) or no cover."""
    from ..sky import saemundsson_refraction_deg
    if not (0.0 <= cover <= 1.0):
        raise ParameterError("cover", f"must be in [0, 1] (got {cover})")
    h = float(solar_elevation_deg)
    if cover == 0.0 or optical_depth <= 0.0 or h <= 0.0:
        return 1.0
    h_app = h + float(saemundsson_refraction_deg(h))
    mu0 = round(math.sin(math.radians(min(h_app, 90.0))), 3)   # 0.001 steps: the cache's key
    return 1.0 - cover * layer_reflectance(optical_depth=round(float(optical_depth), 3),
                                           g=float(g), mu0=max(mu0, 1e-3))
