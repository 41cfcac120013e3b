"""One photon walker for a plane-parallel Henyey-Greenstein layer, with pluggable scorings.
Pure numpy.

The walk (Marchuk et al. 1980, *The Monte Carlo Methods in Atmospheric Optics*, Springer):
photons enter the top of a homogeneous layer of vertical ``optical_depth`` in given
directions; each takes a free path of ``-ln u`` in optical depth along its direction
(``-ln u * |mu|`` vertically); a photon whose path ends above the top has left it, one whose
path ends at or below the bottom has met what lies below, one whose path ends inside collides
there (absorbed with probability ``1 - a`` by Russian roulette, else turned by a
Henyey-Greenstein angle and a uniform azimuth). Below the layer is either nothing (``surface
None``: the photon is gone, no random number drawn for it) or a Lambertian surface of albedo
``A`` (absorbed with probability ``1 - A``, else re-emitted upward cosine-weighted from the
layer's bottom).

What is counted is the scoring's (:class:`Escape`: how many leave the top and the bottom,
the hemispherical reflectance and transmittance; :class:`LocalEstimate`: the nadir radiance's
local estimate, :mod:`.cloud_reflection`). One walk can feed several scorings: they share the
photons and the random stream. Users: :func:`.cloud_shade.layer_reflectance`,
:func:`.cloud_reflection.nadir_reflectance_factor` and the table of the latter
(:mod:`~lidar_mitsuba.atmosphere.cloud_reflection_table`).

The random numbers are drawn in one fixed order per event (free paths; at the surface its
roulette, then ``mu`` and azimuth of the re-emission; at collisions the roulette where
``a < 1``, then the scattering cosine and azimuth), so a walk is reproducible from its seed.
"""
from __future__ import annotations

import math

import numpy as np

from ..constants import ParameterError
from ..sky import hg_phase


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


def hg_cosine(g: float, u: np.ndarray) -> np.ndarray:
    """Henyey-Greenstein scattering-angle cosines from uniforms ``u`` (its inverse CDF;
    isotropic for ``g = 0``)."""
    if abs(g) < 1e-6:
        return 2.0 * u - 1.0
    s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u)
    return (1.0 + g * g - s * s) / (2.0 * g)


def turn(d: np.ndarray, cos_t: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Unit directions ``d`` (n, 3) turned by polar angles of cosine ``cos_t`` and azimuths
    ``phi`` [rad] about themselves."""
    sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
    helper = np.where(np.abs(d[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]),
                      np.array([[1.0, 0.0, 0.0]]))
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(d, e1)
    return (d * cos_t[:, None] + e1 * (sin_t * np.cos(phi))[:, None]
            + e2 * (sin_t * np.sin(phi))[:, None])


def collimated(photons: int, mu0: float) -> np.ndarray:
    """``photons`` directions (photons, 3) of a beam going down at ``mu0`` (z up)."""
    d = np.zeros((photons, 3))
    d[:, 0], d[:, 2] = math.sqrt(1.0 - mu0 * mu0), -mu0
    return d


def diffuse(photons: int, rng: np.random.Generator) -> np.ndarray:
    """``photons`` directions (photons, 3) going down, cosine-weighted (a Lambertian source
    above the layer: ``mu = sqrt(u)``)."""
    mu = np.sqrt(rng.random(photons))
    phi = 2.0 * np.pi * rng.random(photons)
    s = np.sqrt(1.0 - mu * mu)
    return np.stack([s * np.cos(phi), s * np.sin(phi), -mu], axis=1)


class Escape:
    """Counts photons leaving the top (``top``) and meeting the bottom (``bottom``; with a
    surface, every arrival at it). The rest were absorbed or were still inside after the
    walk's last event."""

    def __init__(self) -> None:
        self.top = 0
        self.bottom = 0

    def exit_top(self, idx: np.ndarray) -> None:
        self.top += int(idx.size)

    def at_surface(self, idx: np.ndarray) -> None:
        self.bottom += int(idx.size)

    def collision(self, idx: np.ndarray, depth: np.ndarray, mu: np.ndarray) -> None:
        pass


class LocalEstimate:
    """Each photon's local estimate of the nadir reflectance factor ``pi L(mu=1) / (mu0
    E0)`` (:mod:`.cloud_reflection`): a collision at depth ``t`` going at cosine ``mu`` adds
    ``a p(mu) exp(-t) / 4``, a surface arrival ``A exp(-tau)``. ``score`` shape
    (photons,)."""

    def __init__(self, photons: int, *, optical_depth: float, g: float,
                 surface_albedo: float, single_scattering_albedo: float) -> None:
        self.score = np.zeros(photons)
        self.g, self.ssa = g, single_scattering_albedo
        self.surface_score = surface_albedo * math.exp(-optical_depth)

    def exit_top(self, idx: np.ndarray) -> None:
        pass

    def at_surface(self, idx: np.ndarray) -> None:
        self.score[idx] += self.surface_score

    def collision(self, idx: np.ndarray, depth: np.ndarray, mu: np.ndarray) -> None:
        self.score[idx] += self.ssa * hg_phase(mu, self.g) * np.exp(-depth) / 4.0


def walk(*, optical_depth: float, g: float, d: np.ndarray, rng: np.random.Generator,
         scorings: tuple, surface_albedo: float | None = None,
         single_scattering_albedo: float = 1.0, max_events: int,
         max_collisions: int = 0) -> None:
    """Walks photons of initial directions ``d`` (n, 3; going down, modified in place) from
    the top of the layer (module docstring) for at most ``max_events`` events, feeding each
    of ``scorings``. ``surface_albedo`` None: nothing below; else a Lambertian surface.
    ``max_collisions`` > 0 ends a photon after that many collisions (1: single
    scattering)."""
    photons = d.shape[0]
    depth = np.zeros(photons)                                    # optical depth below the top
    alive = np.ones(photons, bool)
    collisions = np.zeros(photons, np.int64)
    ssa = single_scattering_albedo
    for _ in range(max_events):
        idx = np.flatnonzero(alive)
        if idx.size == 0:
            break
        new = depth[idx] - np.log(rng.random(idx.size)) * (-d[idx, 2])
        out_top, hit = new < 0.0, new >= optical_depth
        alive[idx[out_top]] = False
        for s in scorings:
            s.exit_top(idx[out_top])
        h = idx[hit]
        for s in scorings:
            s.at_surface(h)
        if surface_albedo is None:                               # nothing below: gone
            alive[h] = False
        else:                                                    # re-emitted or absorbed
            keep = rng.random(h.size) < surface_albedo
            alive[h[~keep]] = False
            h = h[keep]
            mu = np.sqrt(rng.random(h.size))
            phi = 2.0 * np.pi * rng.random(h.size)
            sin_t = np.sqrt(1.0 - mu * mu)
            d[h] = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), mu], axis=1)
            depth[h] = optical_depth
        inside = ~out_top & ~hit
        c = idx[inside]
        depth[c] = new[inside]
        for s in scorings:
            s.collision(c, depth[c], d[c, 2])
        if max_collisions > 0:
            collisions[c] += 1
            last = collisions[c] >= max_collisions
            alive[c[last]] = False
            c = c[~last]
        if ssa < 1.0:
            dead = rng.random(c.size) >= ssa
            alive[c[dead]] = False
            c = c[~dead]
        d[c] = turn(d[c], hg_cosine(g, rng.random(c.size)), 2.0 * np.pi * rng.random(c.size))
