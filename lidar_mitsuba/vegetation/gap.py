"""Gap probability of vertical lines through a stand's crowns, in closed form (pure numpy).

What the gap-probability representation computes per photon on the device (``canopy``
integrator, ``mode="gap"``), here for any set of vertical lines, to test it and to predict
what a run should see:

* the chords of the crowns over a point (:func:`vertical_chords`): a cylinder's whole length
  ``[zb, zt]`` within ``r``; an ellipsoid's ``z_c -+ (L/2) sqrt(1 - d^2/r^2)``; a cone's
  ``[zb, zt - L d / r]`` (``d`` the distance to the axis, ``L = zt - zb``);
* the optical depth down to height ``z``, ``tau(z) = G Omega LAD sum_k |[zlo_k, zhi_k] cap
  [z, inf)|`` (:func:`optical_depth`), and the gap probability ``P_gap = exp(-tau(ground))``;
* with the hot spot, the share of the photons on a line that return from the canopy between
  heights ``z0 < z1`` is ``exp(-tau(z1)) - exp(-tau(z0))`` (first collisions, each seen
  back through its own gaps), and from the ground ``P_gap`` (:func:`return_profile`);
  without the hot spot (the way back sampled independently) ``(exp(-2 tau(z1)) -
  exp(-2 tau(z0)))/2`` and ``P_gap^2``.

The canopy table is the dict of :func:`lidar_mitsuba.vegetation.turbid.canopy_table`.
"""
from __future__ import annotations

import numpy as np

from . import ross


def vertical_chords(table: dict, x_m: np.ndarray, y_m: np.ndarray):
    """``(zlo, zhi)`` [m], each (points, crowns): the heights where the vertical line at each
    point enters and leaves each crown (``zlo > zhi`` where it misses)."""
    x = np.asarray(x_m, float).ravel()[:, None]
    y = np.asarray(y_m, float).ravel()[:, None]
    cx, cy, zb, zt, r = (np.asarray(table[k], float)[None, :]
                         for k in ("cx", "cy", "zb", "zt", "r"))
    d = np.hypot(x - cx, y - cy)
    inside = d <= r
    length = zt - zb
    shape = table["shape"]
    if shape == "cylinder":
        lo, hi = zb + 0 * d, zt + 0 * d
    elif shape == "ellipsoid":
        half = 0.5 * length * np.sqrt(np.clip(1.0 - (d / r) ** 2, 0.0, None))
        lo, hi = 0.5 * (zb + zt) - half, 0.5 * (zb + zt) + half
    else:
        lo, hi = zb + 0 * d, zt - length * d / r
    return np.where(inside, lo, np.inf), np.where(inside, hi, -np.inf)


def sigma_nadir(table: dict) -> float:
    """Extinction [1/m] of the crowns along the vertical: ``G(1) Omega LAD``."""
    return ross.G_NADIR[table["leaf_angle"]] * table["clumping"] * table["lad"]


def optical_depth(table: dict, x_m, y_m, z_m) -> np.ndarray:
    """Vertical optical depth of the crowns above height ``z_m`` at each point (points,)
    (``z_m`` a scalar or one per point)."""
    lo, hi = vertical_chords(table, x_m, y_m)
    z = np.broadcast_to(np.asarray(z_m, float), (lo.shape[0],))[:, None]
    return sigma_nadir(table) * np.clip(hi - np.maximum(lo, z), 0.0, None).sum(1)


def gap_probability(table: dict, x_m, y_m, ground_z_m) -> np.ndarray:
    """``P_gap`` of the vertical line at each point down to the ground at ``ground_z_m``."""
    return np.exp(-optical_depth(table, x_m, y_m, ground_z_m))


def return_profile(table: dict, x_m, y_m, ground_z_m, z_edges_m: np.ndarray, *,
                   hot_spot: bool = True):
    """Expected returns of the lines at the points (averaged over them): ``(canopy, ground)``,
    ``canopy`` (bins,) the share of photons whose first leaf lies in each height bin
    ``z_edges_m`` (bins + 1,), counted by how they return (module docstring), ``ground`` the
    share returned by the ground (times its own reflectance). Heights absolute [m]."""
    edges = np.asarray(z_edges_m, float)
    tau = np.stack([optical_depth(table, x_m, y_m, z) for z in edges], 1)   # (points, E)
    tau_g = optical_depth(table, x_m, y_m, ground_z_m)
    k = 1.0 if hot_spot else 2.0
    t = np.exp(-k * tau) / k
    canopy = (t[:, 1:] - t[:, :-1]).mean(0)        # tau falls with height
    return canopy, float(np.mean(np.exp(-k * tau_g)))
