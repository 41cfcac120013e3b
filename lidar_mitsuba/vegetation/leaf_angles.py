"""Leaf angle distributions, Ross's G-function and Nilson's gap probability (pure numpy).

Leaf angle distributions (de Wit 1965, "Photosynthesis of leaf canopies", Agric. Res. Rep.
663, Pudoc, Wageningen; the forms of Goel & Strebel 1984 / Bunnik 1978), densities of the
leaf inclination theta_L in [0, pi/2]:

* spherical  f = sin theta_L (leaf normals uniform over the hemisphere);
* planophile f = 2/pi (1 + cos 2 theta_L);
* erectophile f = 2/pi (1 - cos 2 theta_L);
* uniform    f = 2/pi.

Ross's G-function (Ross 1981, "The Radiation Regime and Architecture of Plant Stands", Junk,
The Hague): the mean projection of unit leaf area on a plane normal to the direction at
zenith theta, for azimuthally uniform leaves,

    G(theta) = int_0^{pi/2} f(theta_L) psi(theta, theta_L) dtheta_L,
    psi = cos theta cos theta_L                                  (theta + theta_L <= pi/2)
    psi = cos theta cos theta_L [1 + 2/pi (tan phi_t - phi_t)],  cos phi_t = cot theta cot theta_L

and G = 0.5 at every angle for the spherical distribution. Gap probability through a random
(Poisson) foliage of leaf area index LAI, clumping index Omega (Nilson 1971, "A theoretical
analysis of the frequency of gaps in plant stands", Agric. Meteorol. 8, 25-38):
``P_gap(theta) = exp(-G(theta) Omega LAI / cos theta)``.
"""
from __future__ import annotations

import math

import numpy as np

from ..constants import ParameterError

#: the leaf angle distributions (the ``Stand.leaf_angle`` names), in the ``canopy`` plugin's
#: code order
LEAF_ANGLES = ("spherical", "planophile", "erectophile", "uniform")


def check_leaf_angle(leaf_angle: str) -> str:
    """``leaf_angle`` if it is one of :data:`LEAF_ANGLES`, else ``ParameterError``."""
    if leaf_angle not in LEAF_ANGLES:
        raise ParameterError("leaf_angle", f"must be one of {', '.join(LEAF_ANGLES)} "
                                           f"(got {leaf_angle!r})")
    return leaf_angle


def leaf_angle_pdf(leaf_angle: str, theta_l_rad) -> np.ndarray:
    """de Wit's density of the leaf inclination ``theta_l_rad`` [rad] in [0, pi/2] (module
    docstring); each integrates to 1 over [0, pi/2]. The one both Ross G's integrate
    (:func:`ross_g`, :func:`.ross.g_function`)."""
    t = np.asarray(theta_l_rad, float)
    check_leaf_angle(leaf_angle)
    if leaf_angle == "spherical":
        return np.sin(t)
    if leaf_angle == "planophile":
        return 2.0 / np.pi * (1.0 + np.cos(2.0 * t))
    if leaf_angle == "erectophile":
        return 2.0 / np.pi * (1.0 - np.cos(2.0 * t))
    return np.full(t.shape, 2.0 / np.pi)


def _quadrature(n: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint nodes and weights over [0, pi/2] (n nodes)."""
    h = 0.5 * np.pi / n
    return (np.arange(n) + 0.5) * h, np.full(n, h)


def sample_leaf_inclination(leaf_angle: str, u) -> np.ndarray:
    """Leaf inclinations [rad] for uniform variates ``u`` in [0, 1), by inverting the CDF of
    :func:`leaf_angle_pdf` (closed forms: spherical ``arccos(1 - u)``, uniform ``u pi/2``,
    planophile / erectophile by Newton's method on ``(2t +- sin 2t) / pi = u``)."""
    u = np.asarray(u, float)
    if leaf_angle == "spherical":
        return np.arccos(1.0 - u)
    if leaf_angle == "uniform":
        return 0.5 * np.pi * u
    sign = {"planophile": 1.0, "erectophile": -1.0}.get(leaf_angle)
    if sign is None:
        leaf_angle_pdf(leaf_angle, 0.0)                 # raises the ParameterError
    t = 0.5 * np.pi * u
    for _ in range(40):   # CDF(t) = (2t + sign sin 2t) / pi, monotone; Newton from the line
        cdf = (2.0 * t + sign * np.sin(2.0 * t)) / np.pi
        pdf = np.maximum(leaf_angle_pdf(leaf_angle, t), 1e-9)
        t = np.clip(t - (cdf - u) / pdf, 0.0, 0.5 * np.pi)
    return t


def ross_g(leaf_angle: str, theta_rad) -> np.ndarray:
    """Ross's G-function [-] at view zenith ``theta_rad`` [rad] (module docstring), by
    midpoint quadrature over the leaf inclination (2000 nodes: 1e-6 of the closed forms)."""
    th = np.atleast_1d(np.asarray(theta_rad, float))
    tl, w = _quadrature()
    f = leaf_angle_pdf(leaf_angle, tl) * w
    ct, tt = np.cos(th)[:, None], np.tan(th)[:, None]
    cl = np.cos(tl)[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        x = 1.0 / (tt * np.tan(tl)[None, :])           # cot theta cot theta_L
        phi = np.arccos(np.clip(x, -1.0, 1.0))
        psi = np.where(x >= 1.0, ct * cl,
                       ct * cl * (1.0 + 2.0 / np.pi * (np.tan(phi) - phi)))
    psi = np.where(np.isfinite(psi), psi, ct * cl)
    g = (psi * f[None, :]).sum(1)
    return g.reshape(np.shape(theta_rad)) if np.ndim(theta_rad) else g[0]


def gap_probability(*, leaf_angle: str, lai: float, clumping: float = 1.0,
                    theta_rad: float = 0.0) -> float:
    """Nilson's gap probability ``exp(-G(theta) Omega LAI / cos theta)`` through a
    horizontally homogeneous foliage layer (module docstring)."""
    return float(np.exp(-ross_g(leaf_angle, theta_rad) * clumping * lai
                        / math.cos(theta_rad)))
