"""How much of the direct sun a cloud over a surface sends to a nadir-looking receiver: the
nadir reflectance factor of a plane-parallel Henyey-Greenstein layer over a Lambertian
surface, by Monte Carlo. Pure numpy.

A cloud lit at grazing incidence does not reflect like a Lambertian surface of its albedo: its
light is scattered forward (g 0.85 for water droplets), away from the nadir. The quantity a
nadir receiver sees is the reflectance factor

    rho(mu0) = pi L(mu = 1) / (mu0 E0)                                              (1)

(``L`` the radiance leaving the top toward the zenith, ``mu0 E0`` the direct irradiance on the
horizontal). A Lambertian system of albedo ``A`` has ``rho = A`` at every ``mu0``; a cloud of
optical depth 1.1 over sea ice (0.83) at a 4 deg sun has 0.46 against its two-stream
system albedo's 0.80 (:meth:`~lidar_mitsuba.atmosphere.cloud_layer.Cloud.system_albedo`).

The Monte Carlo (:func:`nadir_reflectance_factor`) follows photons from a collimated beam at
``mu0`` through the layer (free paths ``-ln u`` in optical depth, Henyey-Greenstein turns,
absorption by Russian roulette at the single-scattering albedo ``a``) and onto a Lambertian
surface below it (absorbed with probability ``1 - A``, re-emitted cosine-weighted). It scores
the *local estimate* (Marchuk et al. 1980, *The Monte Carlo Methods in Atmospheric Optics*,
Springer; recalled, not re-read here: the expected radiance each event sends straight to the
detector direction):
a collision at optical depth ``t`` below the top, going in direction ``d``, adds

    a p(d . z) exp(-t) / 4

(``p`` the phase function normalised to 4 pi, ``z`` the zenith), and a surface hit adds
``A exp(-tau)``; ``rho`` is their mean over the photons, its standard error their standard
deviation over ``sqrt(photons)``. Exact in expectation. Checked (``tests/test_cloud_reflection``)
against the single-scattering limit of a thin layer,

    rho_1 = a p(-mu0) (1 - exp(-tau (1 + 1 / mu0))) / (4 (1 + mu0)),                (2)

against Chandrasekhar's exact reflection of a semi-infinite isotropically scattering layer
(Chandrasekhar 1960, *Radiative Transfer*, Dover, ch. IV, for isotropic scattering),

    rho_inf(mu, mu0) = a H(mu) H(mu0) / (4 (mu + mu0)),                              (3)

``H`` Chandrasekhar's H-function (:func:`h_function`), and against ``rho = A`` with no layer.

How it enters the sky (:func:`direct_sun_factor`): under a cloud the sky model sees the cloud
over the surface as a Lambertian surface of the system albedo ``A_s`` (its two-stream value);
the surface's radiance is ``A_s (E_dir + E_dif) T / pi``. The direct sun's share of it is
reflected with ``rho(mu0)`` instead, the diffuse sky's as before (ESTIMATE: the diffuse light,
itself from all of the sky, is reflected as by a Lambertian surface): the solar background
times

    1 + (rho(mu0) / A_s - 1) (S / (P + S)) E_dir / (E_dir + E_dif),                  (4)

``S``, ``P`` the sky model's surface and path radiance (:func:`lidar_mitsuba.sky.sky`).

The walk is :func:`.hg_walk.walk`, the one :func:`.cloud_shade.layer_reflectance` also takes,
scored with the local estimate (:class:`.hg_walk.LocalEstimate`). A run takes ``rho`` from a
table made once by the same Monte Carlo
(:mod:`~lidar_mitsuba.atmosphere.cloud_reflection_table`: water and ice clouds, the surface's
albedo in closed form; 0.1 s a cloud against 6-8 s), and runs the Monte Carlo itself for
other clouds.
"""
from __future__ import annotations

import functools
import math

import numpy as np

from ..constants import ParameterError
from ..sky import hg_phase
from . import cloud_reflection_table
from .hg_walk import LocalEstimate, check_layer, collimated, walk

PHOTONS = 1 << 15
"""Photons per :func:`nadir_reflectance_factor` estimate (standard error 0.005-0.01 at the
polar clouds' tau 1-2, g 0.85, over sea ice: reported with each value)."""
MAX_EVENTS = 4000
"""Events followed per photon (collisions and surface hits). A photon still alive after them
is dropped, its remaining contribution lost: at tau <= 10, g 0.85, A 0.96 fewer than 1e-4 of
them (the loop stops as soon as none is alive)."""
MU0_STEP = 0.02
"""Grid of ``mu0`` on which :func:`direct_sun_factor` evaluates ``rho`` by Monte Carlo where
the table does not hold the cloud (the table's own grid too; linear in between;
``rho`` is smooth in ``mu0``: linear between nodes 0.02 apart is within 0.01 of it at a
grazing sun, where it bends most)."""


def _check(optical_depth: float, g: float, mu0: float, surface_albedo: float,
           single_scattering_albedo: float) -> None:
    check_layer(optical_depth=optical_depth, g=g, mu0=mu0)
    if not (0.0 <= surface_albedo <= 1.0):
        raise ParameterError("surface_albedo", f"must be in [0, 1] (got {surface_albedo})")
    if not (0.0 < single_scattering_albedo <= 1.0):
        raise ParameterError("single_scattering_albedo",
                             f"must be in (0, 1] (got {single_scattering_albedo})")


@functools.lru_cache(maxsize=512)
def nadir_reflectance_factor(*, optical_depth: float, g: float, mu0: float,
                             surface_albedo: float, single_scattering_albedo: float = 1.0,
                             photons: int = PHOTONS, seed: int = 0,
                             max_collisions: int = 0) -> tuple[float, float]:
    """``(rho, standard error)`` [1]: the nadir reflectance factor ``pi L(mu=1) / (mu0 E0)``
    of a plane-parallel layer (``optical_depth``, Henyey-Greenstein ``g``,
    ``single_scattering_albedo``) over a Lambertian surface of ``surface_albedo``, lit by a
    collimated beam at ``mu0`` (cosine of its zenith angle, (0, 1]). Monte Carlo with the
    local estimate (module docstring), ``photons`` photons, seeded; ``max_collisions`` > 0
    follows only that many orders of scattering (1: eq. (2), for checking)."""
    _check(optical_depth, g, mu0, surface_albedo, single_scattering_albedo)
    tau, a_s, ssa = float(optical_depth), float(surface_albedo), float(single_scattering_albedo)
    local = LocalEstimate(int(photons), optical_depth=tau, g=float(g), surface_albedo=a_s,
                          single_scattering_albedo=ssa)
    walk(optical_depth=tau, g=float(g), d=collimated(int(photons), float(mu0)),
         rng=np.random.default_rng(int(seed)), scorings=(local,), surface_albedo=a_s,
         single_scattering_albedo=ssa, max_events=MAX_EVENTS,
         max_collisions=int(max_collisions))
    s = local.score
    return float(s.mean()), float(s.std(ddof=1) / math.sqrt(s.size))


def h_function(mu, *, single_scattering_albedo: float = 1.0, nodes: int = 64):
    """Chandrasekhar's H-function for isotropic scattering of single-scattering albedo ``a``
    at ``mu`` [cosines, array], from its non-linear integral equation in the form
    ``H(mu) = 1 / (1 - (a / 2) mu int_0^1 H(mu') / (mu + mu') dmu')``
    (Chandrasekhar 1960, ch. V, with the characteristic function ``Psi = a / 2``), iterated
    from ``H = 1``, each step rescaled to the exact zeroth moment
    ``int_0^1 H dmu = 2 (1 - sqrt(1 - a)) / a`` (from ``int Psi H dmu = 1 - sqrt(1 - 2 Psi_0)``,
    his ch. V; without it the conservative case converges slowly), to 1e-11 on ``nodes``
    Gauss-Legendre points. Conservative (``a = 1``): H(0.5) = 2.0128, H(1) = 2.9078 (his
    tabulated values)."""
    a = float(single_scattering_albedo)
    x, w = np.polynomial.legendre.leggauss(nodes)
    x, w = 0.5 * (x + 1.0), 0.5 * w
    h = np.ones(nodes)
    zeroth = 2.0 * (1.0 - math.sqrt(max(1.0 - a, 0.0))) / a     # int_0^1 H dmu, exact
    for _ in range(5000):
        new = 1.0 / (1.0 - 0.5 * a * x * np.sum(w * h / (x[:, None] + x[None, :]), axis=1))
        new *= zeroth / np.sum(w * new)          # the slow (conservative) mode removed
        done = np.max(np.abs(new - h)) < 1e-11
        h = new
        if done:
            break
    m = np.asarray(mu, np.float64)
    return 1.0 / (1.0 - 0.5 * a * m * np.sum(w * h / (m[..., None] + x), axis=-1))


def semi_infinite_isotropic_rho(*, mu: float, mu0: float,
                                single_scattering_albedo: float = 1.0) -> float:
    """Eq. (3): the exact reflectance factor ``a H(mu) H(mu0) / (4 (mu + mu0))`` of a
    semi-infinite isotropically scattering layer."""
    a = float(single_scattering_albedo)
    hh = h_function(np.array([mu, mu0]), single_scattering_albedo=a)
    return float(a * hh[0] * hh[1] / (4.0 * (mu + mu0)))


def _rho_on_grid(cloud, surface_albedo: float, mu0: np.ndarray, *,
                 tabulated: bool = True) -> np.ndarray:
    """``rho`` of ``cloud`` over ``surface_albedo`` at ``mu0``: from the table
    (:mod:`~lidar_mitsuba.atmosphere.cloud_reflection_table`) where it holds the cloud and
    ``tabulated``, else by Monte Carlo at the :data:`MU0_STEP` nodes that bracket them,
    linear between."""
    tau, a_s = round(float(cloud.optical_depth), 3), round(float(surface_albedo), 3)
    g, ssa = float(cloud.g), float(cloud.single_scattering_albedo)
    if tabulated and cloud_reflection_table.covers(optical_depth=tau, g=g,
                                                   single_scattering_albedo=ssa):
        return cloud_reflection_table.rho(optical_depth=tau, g=g, mu0=mu0,
                                          surface_albedo=a_s)[0]
    lo = max(MU0_STEP, math.floor(float(mu0.min()) / MU0_STEP) * MU0_STEP)
    hi = max(lo, math.ceil(float(mu0.max()) / MU0_STEP) * MU0_STEP)
    nodes = np.round(np.arange(lo, min(hi, 1.0) + MU0_STEP / 2, MU0_STEP), 6)
    nodes = nodes[nodes <= 1.0]
    rho = [nadir_reflectance_factor(optical_depth=tau, g=g, mu0=float(m), surface_albedo=a_s,
                                    single_scattering_albedo=ssa)[0]
           for m in nodes]
    return np.interp(mu0, nodes, rho)


def direct_sun_factor(cloud, *, surface_albedo: float, solar_elevation_deg, z_m: float,
                      atmosphere, wavelength_nm: float = 532.0,
                      tabulated: bool = True) -> np.ndarray:
    """Eq. (4): the factor [1] on the solar background [Hz] of a nadir receiver over
    ``cloud`` (a :class:`~lidar_mitsuba.atmosphere.cloud_layer.Cloud`) over a surface of
    ``surface_albedo``, when the direct sun's share of the cloud-over-surface's light is
    reflected with the layer's nadir reflectance factor instead of its Lambertian system
    albedo. ``solar_elevation_deg`` geometric [deg] (array), ``z_m`` the surface's height
    [m], ``atmosphere`` a :class:`~lidar_mitsuba.radiometry.Atmosphere`. 1 where the sun is
    down (no direct beam). ``rho`` from the table where it holds the cloud (``tabulated``,
    the default: :mod:`~lidar_mitsuba.atmosphere.cloud_reflection_table`), else by Monte
    Carlo."""
    from .. import sky
    from ..radiometry import isa_pressure_hpa, rayleigh_optical_depth
    elev = np.atleast_1d(np.asarray(solar_elevation_deg, np.float64))
    out = np.ones(elev.shape)
    up = elev > 0.0
    if cloud is None or cloud.clear or not up.any():
        return out
    a_sys = float(cloud.system_albedo(surface_albedo))
    nodes = np.unique(np.round(elev[up], 1))            # 0.1 deg nodes: many shots, few skies
    nodes = nodes[nodes > 0.0] if np.any(nodes > 0.0) else np.array([float(elev[up].max())])
    sk = sky.sky(solar_elevation_deg=nodes, z_m=float(z_m), albedo=a_sys,
                 tau_rayleigh=float(rayleigh_optical_depth(wavelength_nm,
                                                           isa_pressure_hpa(float(z_m)))),
                 aerosol_optical_depth=atmosphere.aerosol_optical_depth,
                 aerosol_scale_height_m=atmosphere.aerosol_scale_height_m,
                 aerosol_ssa=atmosphere.aerosol_single_scattering_albedo)
    rho = _rho_on_grid(cloud, surface_albedo, sky.apparent_mu0(nodes), tabulated=tabulated)
    glob = np.maximum(sk.direct + sk.diffuse, 1e-300)
    share = sk.surface_radiance / np.maximum(sk.toa_radiance, 1e-300) * sk.direct / glob
    factor = 1.0 + (rho / a_sys - 1.0) * share
    out[up] = np.interp(elev[up], nodes, factor)
    return out
