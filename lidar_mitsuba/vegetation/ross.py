"""Leaf-canopy radiative transfer in closed form: the leaf angle distributions, Ross's
G-function and the area scattering phase function of bi-Lambertian leaves (pure numpy).

A canopy of flat leaves, randomly placed, with leaf area density ``u_L`` [m^2/m^3] and a leaf
normal distribution ``g_L`` is a turbid medium whose extinction depends on the direction of
travel ``Omega`` (Ross 1981, *The Radiation Regime and Architecture of Plant Stands*, ch. 2;
Myneni, Ross & Asrar 1989, *Agric. For. Meteorol.* 45, 1-153, Sec. 2):

.. math::

    \\sigma_t(\\Omega) = G(\\Omega)\\,\\Omega_c\\,u_L, \\qquad
    G(\\Omega) = \\frac{1}{2\\pi}\\int_{2\\pi^+} g_L(\\Omega_L)\\,|\\Omega\\cdot\\Omega_L|\\,
    d\\Omega_L,

with ``Omega_c`` the clumping index (Nilson 1971) and the normalisation
``(1/2pi) int g_L dOmega_L = 1``. The leaf normals' inclination ``theta_L`` has the pdf
``f(theta_L)`` on ``[0, pi/2]`` (azimuth uniform): de Wit's (1965, *Photosynthesis of Leaf
Canopies*, Agric. Res. Rep. 663) types, as reviewed by Myneni et al. (1989, Sec. 2):

=========== ======================================
spherical   ``sin theta_L``
planophile  ``(2/pi) (1 + cos 2 theta_L)``
erectophile ``(2/pi) (1 - cos 2 theta_L)``
uniform     ``2/pi``
=========== ======================================

The azimuthal average of ``|Omega . Omega_L|`` is Ross's kernel :func:`psi`; ``G`` integrates it
against ``f`` (:func:`g_function`, Gauss-Legendre split at the kernel's kink). Closed forms
(:data:`G_NADIR`, :data:`G_HORIZON`): spherical 1/2 everywhere; at nadir ``G = <cos theta_L>``,
at the horizon ``G = (2/pi) <sin theta_L>``; and for every distribution
``int_0^1 G(mu) dmu = 1/2`` (Ross 1981).

A bi-Lambertian leaf reflects ``rho`` and transmits ``tau`` (each Lambertian). The area
scattering phase function (Ross 1981; Shultis & Myneni 1988, *JQSRT* 39, 115-129) is

.. math::

    \\Gamma(\\Omega'\\to\\Omega) = \\frac{1}{2\\pi}\\int_{2\\pi^+} g_L(\\Omega_L)
    |\\Omega'\\cdot\\Omega_L|\\,f_L(\\Omega'\\to\\Omega;\\Omega_L)\\,d\\Omega_L,\\quad
    f_L = \\tfrac{\\rho}{\\pi}|\\Omega\\cdot\\Omega_L|\\ \\text{(reflection)},\\
    \\tfrac{\\tau}{\\pi}|\\Omega\\cdot\\Omega_L|\\ \\text{(transmission)},

so that ``int Gamma dOmega = (rho + tau) G(Omega')``; the phase function normalised over
the sphere is ``p = Gamma / ((rho + tau) G)``. For spherical leaves it depends only on the
scattering angle ``gamma`` between ``Omega'`` and ``Omega`` (``gamma = pi``: backscatter):

.. math::

    \\Gamma(\\gamma) = \\frac{1}{3\\pi^2}\\Big[\\rho\\,(\\sin\\gamma - \\gamma\\cos\\gamma)
    + \\tau\\,(\\sin\\gamma + (\\pi - \\gamma)\\cos\\gamma)\\Big]

(the Shultis-Myneni form, written with the scattering angle; derived in docs/physics/canopy.md
from ``int_{ab<0} |ab| dn = (4/3)(sin gamma - gamma cos gamma)`` over the unit sphere).
The lidar needs its backscatter, ``Gamma(Omega -> -Omega) = (rho/pi) <(Omega . Omega_L)^2>``,
and for a direction of cosine ``mu`` to the vertical
``<(Omega . Omega_L)^2> = mu^2 <cos^2> + (1 - mu^2)(1 - <cos^2>)/2`` (:func:`backscatter`).
"""
from __future__ import annotations

import math

import numpy as np

from .leaf_angles import LEAF_ANGLES, check_leaf_angle, leaf_angle_pdf  # noqa: F401

#: G at nadir, <cos theta_L> of each distribution (closed forms, integrated by hand:
#: int_0^{pi/2} (1 +- cos 2t) cos t dt = 1 +- 1/3)
G_NADIR = {"spherical": 0.5, "planophile": 8.0 / (3.0 * math.pi),
           "erectophile": 4.0 / (3.0 * math.pi), "uniform": 2.0 / math.pi}
#: G at the horizon, (2/pi) <sin theta_L> (int_0^{pi/2} (1 +- cos 2t) sin t dt = 1 -+ 1/3)
G_HORIZON = {"spherical": 0.5, "planophile": 8.0 / (3.0 * math.pi ** 2),
             "erectophile": 16.0 / (3.0 * math.pi ** 2), "uniform": 4.0 / math.pi ** 2}
#: <cos^2 theta_L> of each distribution (int_0^{pi/2} (1 +- cos 2t) cos^2 t dt = pi/4 +- pi/8)
COS2_MEAN = {"spherical": 1.0 / 3.0, "planophile": 0.75, "erectophile": 0.25,
             "uniform": 0.5}


def psi(mu: np.ndarray, theta_l: np.ndarray) -> np.ndarray:
    """Ross's kernel, the leaf-azimuth mean of ``|Omega dot Omega_L|``, for a direction of
    cosine ``mu`` to the vertical and leaf inclination ``theta_l`` [rad] (broadcast).
    With ``a = |mu| cos theta_l``, ``b = sin theta sin theta_l``: ``a`` where ``a >= b``, else
    ``a (2 phi/pi - 1) + (2/pi) b sin phi``, ``cos phi = -a/b`` (Ross 1981, ch. 2)."""
    mu = np.abs(np.asarray(mu, float))
    t = np.asarray(theta_l, float)
    a = mu * np.cos(t)
    b = np.sqrt(np.maximum(1.0 - mu * mu, 0.0)) * np.sin(t)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.arccos(np.clip(-a / np.where(b > 0, b, 1.0), -1.0, 1.0))
    mixed = a * (2.0 * phi / math.pi - 1.0) + 2.0 / math.pi * b * np.sin(phi)
    return np.where(a >= b, a, mixed)


def g_function(mu: np.ndarray, leaf_angle: str, *, nodes: int = 48) -> np.ndarray:
    """Ross's G for directions of cosine ``mu`` to the vertical (any shape), by Gauss-Legendre
    quadrature of :func:`psi` against the leaf inclination's pdf
    (:func:`.leaf_angles.leaf_angle_pdf`), split at the kernel's kink
    ``theta_L = pi/2 - theta`` (each side smooth: 48 nodes give ~1e-12)."""
    check_leaf_angle(leaf_angle)
    mu = np.asarray(mu, float)
    x, w = np.polynomial.legendre.leggauss(nodes)
    kink = math.pi / 2 - np.arccos(np.clip(np.abs(mu), 0.0, 1.0))
    out = np.zeros(mu.shape)
    for lo, hi in ((np.zeros_like(kink), kink), (kink, np.full_like(kink, math.pi / 2))):
        half = (hi - lo)[..., None] / 2.0
        t = lo[..., None] + half * (x + 1.0)
        out += np.sum(w * half * leaf_angle_pdf(leaf_angle, t) * psi(mu[..., None], t), -1)
    return out


def backscatter(mu: np.ndarray | float, leaf_angle: str, *, rho: float) -> np.ndarray:
    """``Gamma(Omega -> -Omega)`` [1/sr] for a direction of cosine ``mu`` to the vertical:
    ``(rho/pi) (mu^2 <cos^2> + (1 - mu^2)(1 - <cos^2>)/2)`` (module docstring)."""
    c2 = COS2_MEAN[check_leaf_angle(leaf_angle)]
    mu2 = np.square(np.asarray(mu, float))
    return rho / math.pi * (mu2 * c2 + (1.0 - mu2) * (1.0 - c2) / 2.0)


def leaf_return_weight(leaf_angle: str, *, rho: float, mu: float = 1.0,
                       reference_albedo: float = 0.9) -> float:
    """Return weight of one leaf collision seen back along the way in, in the integrators'
    unit (a Lambertian 0.9 plate weighs 1): ``pi Gamma_back / (G 0.9)``; at nadir
    ``rho <cos^2 theta_L> / (<cos theta_L> 0.9)``. A dense canopy of horizontal leaves
    (``<cos> = <cos^2> = 1``) returns as a Lambertian plate of albedo ``rho``."""
    g = G_NADIR[leaf_angle] if mu == 1.0 else float(g_function(np.array(mu), leaf_angle))
    return float(math.pi * backscatter(mu, leaf_angle, rho=rho) / g / reference_albedo)


def phase_spherical(gamma_rad: np.ndarray, *, rho: float, tau: float) -> np.ndarray:
    """The phase function [1/sr] of bi-Lambertian leaves with a spherical leaf angle
    distribution against the scattering angle ``gamma_rad`` (0: forward, pi: back),
    normalised over the sphere: ``Gamma(gamma) / ((rho + tau) / 2)`` (module docstring)."""
    g = np.asarray(gamma_rad, float)
    s, c = np.sin(g), np.cos(g)
    gamma = (rho * (s - g * c) + tau * (s + (math.pi - g) * c)) / (3.0 * math.pi ** 2)
    return gamma / ((rho + tau) * 0.5)


def gap_probability(*, lai: float, leaf_angle: str, clumping: float = 1.0,
                    mu: float = 1.0) -> float:
    """Gap probability through a horizontally homogeneous layer of leaf area index ``lai``
    along a direction of cosine ``mu`` to the vertical, ``exp(-G(mu) Omega LAI / mu)``
    (Nilson 1971; Ross 1981).

    Nilson 1971: *Agric. Meteorol.* 8, 25-38."""
    g = G_NADIR[leaf_angle] if mu == 1.0 else float(g_function(np.array(mu), leaf_angle))
    return math.exp(-g * clumping * lai / mu)
