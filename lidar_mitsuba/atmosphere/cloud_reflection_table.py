"""The cloud's nadir reflectance factor from a table, made once by Monte Carlo. Pure numpy.

:func:`~lidar_mitsuba.atmosphere.cloud_reflection.nadir_reflectance_factor` costs 0.1-1.6 s a
``mu0`` (2^15 photons; more for thick layers), paid once per process and cloud: a campaign
worker would pay it for every granule's cloud. Its inputs are the layer's optical depth
``tau``, asymmetry ``g``, single-scattering albedo ``a``, the sun's ``mu0`` and the surface's
albedo ``A``. The surface enters in closed form: a layer over a Lambertian surface reflects
toward the zenith (the "planetary problem", Chandrasekhar 1960, *Radiative Transfer*, ch. IX;
the adding of a layer and a Lambertian reflector)

    rho(mu0, A) = rho_0(mu0) + A t(mu0) t(1) / (1 - A s),                            (1)

``rho_0`` the layer's nadir reflectance factor over a black surface, ``t(mu)`` the total
(direct + diffuse) transmittance of a collimated beam at ``mu`` (the surface's irradiance
per ``mu0 E0`` on the first pass; by reciprocity also the transmittance of the surface's
isotropic radiance into the zenith, the layer being symmetric under ``z -> -z``), ``s`` the
layer's spherical albedo seen from below (the share of the surface's Lambertian light sent
back down; each bounce multiplies by ``A s``). So the table holds, for the clouds a run
makes (``g`` 0.75 ice, 0.85 water; ``a`` = 1), ``rho_0`` and ``t`` on a grid of ``tau`` x
``mu0`` and ``s`` on ``tau``, each from one walk of
:func:`~lidar_mitsuba.atmosphere.hg_walk.walk` scored two ways
(:mod:`lidar_mitsuba.studies.cloud_reflection_table` makes it:
``data/cloud_reflection_table.json``, 62 kB).

Between the nodes: linear in ``mu0`` (0.02 apart, as the Monte Carlo's own grid was) and
linear in ``ln tau`` (nodes a factor sqrt(2) apart from 0.01 to 20; linear in ``tau`` from the
exact ``tau = 0``: ``rho_0 = 0``, ``t = 1``, ``s = 0``). :func:`covers` says where the table
holds; elsewhere (another ``g`` or ``a``) the caller runs the Monte Carlo. The same ``t`` gives a
conservative layer's plane albedo ``R(mu0) = 1 - t(mu0)`` (:func:`reflectance`: the shade a
broken deck casts, :mod:`~lidar_mitsuba.atmosphere.cloud_shade`).
"""
from __future__ import annotations

import functools
import json
import math
import pathlib

import numpy as np

from ..constants import ParameterError

TABLE = pathlib.Path(__file__).resolve().parents[1] / "data" / "cloud_reflection_table.json"
"""The table (:mod:`lidar_mitsuba.studies.cloud_reflection_table` writes it)."""


@functools.lru_cache(maxsize=1)
def load() -> dict:
    """The table as arrays: ``optical_depths`` (n_tau,), ``mu0s`` (n_mu,), ``gs`` (n_g,);
    ``rho_black``, ``rho_black_se``, ``transmittance`` (n_g, n_tau, n_mu) and
    ``spherical_albedo`` (n_g, n_tau), ``photons`` per walk."""
    with open(TABLE) as f:
        doc = json.load(f)
    out = {k: np.asarray(v, np.float64) for k, v in doc.items()
           if k in ("optical_depths", "mu0s", "gs", "rho_black", "rho_black_se",
                    "transmittance", "spherical_albedo")}
    out["photons"] = int(doc["photons"])
    out["single_scattering_albedo"] = float(doc["single_scattering_albedo"])
    return out


def _g_index(g: float) -> int | None:
    gs = load()["gs"]
    hit = np.flatnonzero(np.abs(gs - float(g)) < 1e-9)
    return int(hit[0]) if hit.size else None


def covers(*, optical_depth: float, g: float, single_scattering_albedo: float) -> bool:
    """Whether the table holds a layer: its ``g`` one of the table's, its ``a`` the table's
    (1) and ``0 <= tau <=`` the last node (20, the largest a :class:`.cloud_layer.Cloud`
    allows)."""
    tab = load()
    return (_g_index(g) is not None
            and float(single_scattering_albedo) == tab["single_scattering_albedo"]
            and 0.0 <= float(optical_depth) <= float(tab["optical_depths"][-1]))


def _tau_weights(optical_depth: float) -> tuple[int, int, float]:
    """The two tau nodes around ``optical_depth`` (index -1: the exact tau = 0) and the
    weight of the upper one."""
    taus = load()["optical_depths"]
    tau = float(optical_depth)
    if tau <= taus[0]:
        return -1, 0, tau / taus[0]
    j = min(int(np.searchsorted(taus, tau)), taus.size - 1)
    w = (math.log(tau) - math.log(taus[j - 1])) / (math.log(taus[j]) - math.log(taus[j - 1]))
    return j - 1, j, w


def _at_tau(field: np.ndarray, exact_zero: float, i: int, j: int, w: float) -> np.ndarray:
    lo = np.full(field.shape[1:], exact_zero) if i < 0 else field[i]
    return (1.0 - w) * lo + w * field[j]


def _check_covered(optical_depth: float, g: float) -> None:
    if not covers(optical_depth=optical_depth, g=g, single_scattering_albedo=1.0):
        raise ParameterError("cloud", f"the table holds g {list(load()['gs'])} and optical "
                             f"depths 0-{load()['optical_depths'][-1]:g} (got g {g}, "
                             f"tau {optical_depth})")


def reflectance(*, optical_depth: float, g: float, mu0) -> tuple[np.ndarray, np.ndarray]:
    """``(R, standard error)`` [1]: the fraction of a collimated beam at ``mu0`` (array,
    clamped to the table's 0.02-1) that a layer the table :func:`covers` reflects with
    nothing below it (its flux through the top, what
    :func:`~lidar_mitsuba.atmosphere.cloud_shade.layer_reflectance` counts): ``1 - t(mu0)``,
    the layer being conservative (``a`` = 1: what it does not transmit it reflects; the
    walk's photons still inside after its last event, fewer than 1e-4, counted reflected
    here and transmitted there), linear between nodes as :func:`rho`; the standard error
    the nodes' binomial one."""
    _check_covered(optical_depth, g)
    tab = load()
    i, j, w = _tau_weights(optical_depth)
    t = np.interp(np.asarray(mu0, np.float64), tab["mu0s"],
                  _at_tau(tab["transmittance"][_g_index(g)], 1.0, i, j, w))
    return 1.0 - t, np.sqrt(t * (1.0 - t) / tab["photons"])


def rho(*, optical_depth: float, g: float, mu0, surface_albedo: float
        ) -> tuple[np.ndarray, np.ndarray]:
    """``(rho, standard error)`` [1] of eq. (1) at ``mu0`` (array, clamped to the table's
    0.02-1) for a layer the table :func:`covers`; the standard error from the nodes' own
    (the local estimate's for ``rho_0``, binomial for ``t`` and ``s``), propagated to first
    order, before interpolation."""
    _check_covered(optical_depth, g)
    tab = load()
    k = _g_index(g)
    i, j, w = _tau_weights(optical_depth)
    rho0 = _at_tau(tab["rho_black"][k], 0.0, i, j, w)
    rho0_se = _at_tau(tab["rho_black_se"][k], 0.0, i, j, w)
    t = _at_tau(tab["transmittance"][k], 1.0, i, j, w)
    s = float(_at_tau(tab["spherical_albedo"][k][:, None], 0.0, i, j, w)[0])
    m = np.asarray(mu0, np.float64)
    mus = tab["mu0s"]
    t_mu, t_1 = np.interp(m, mus, t), float(t[-1])
    a = float(surface_albedo)
    den = 1.0 - a * s
    out = np.interp(m, mus, rho0) + a * t_mu * t_1 / den
    n = tab["photons"]

    def var_t(p):                                            # binomial
        return p * (1.0 - p) / n

    se = np.sqrt(np.interp(m, mus, rho0_se) ** 2
                 + (a * t_1 / den) ** 2 * var_t(t_mu) + (a * t_mu / den) ** 2 * var_t(t_1)
                 + (a * a * t_mu * t_1 / den ** 2) ** 2 * var_t(s))
    return out, se
