"""The turbid and gap-probability representations of a stand: its crowns as a canopy table for
the ``canopy`` integrator (``plugins/canopy.py``), and the integrator's parameters.

Both representations trace the same table; they differ in the integrator's ``mode``:

* ``turbid``: Monte Carlo through the crowns filled with a turbid medium of leaves
  (extinction ``G Omega LAD``, bi-Lambertian leaves scattering, up to ``max_depth`` vertices);
* ``gap``: per photon the gap probability of its vertical line through the crowns, a canopy
  return at a height drawn from the collision density and the ground's return weighted by
  the gap probability (single scattering; the cost of a ray cast to the ground).

Both carry the monostatic hot spot (the way back is the way in): see ``plugins/canopy.py``
and docs/physics/canopy.md.

A periodic stand (a torus over its bounds) lists, besides its crowns, their images shifted
by the bounds' size wherever a crown lies within ``pad_m`` of an edge, so that the lines of
a track folded into the tile (up to a footprint's 5 sigma and a field of view outside it)
see the crowns across the edge.
"""
from __future__ import annotations

import hashlib
import os
import pathlib
import tempfile

import numpy as np

from ..constants import ParameterError, check
from . import ross

#: nodes of the G table handed to the integrator (mu = k / (G_NODES - 1); linear between
#: them: G varies smoothly, < 1e-4 between nodes)
G_NODES = 129
MODES = ("turbid", "gap")


def canopy_table(stand, *, rho: float, tau: float, pad_m: float = 40.0) -> dict:
    """The canopy table (``lidar_mitsuba_plugins.canopy_table``) of ``stand`` (a
    :class:`~lidar_mitsuba.vegetation.stand.Stand`): crowns as absolute heights, with the
    periodic images within ``pad_m`` [m] of the bounds when the stand is periodic; leaves
    of reflectance ``rho`` and transmittance ``tau``; Ross's G on :data:`G_NODES` nodes."""
    check("rho", rho, 0 <= rho <= 1, "must be in [0, 1]")
    check("tau", tau, 0 <= tau <= 1 - rho, "must be in [0, 1 - rho]")
    cx, cy = np.asarray(stand.x_m, float), np.asarray(stand.y_m, float)
    zb = np.asarray(stand.ground_z_m, float) + np.asarray(stand.crown_base_m, float)
    zt = np.asarray(stand.ground_z_m, float) + np.asarray(stand.height_m, float)
    r = np.asarray(stand.crown_radius_m, float)
    if getattr(stand, "periodic", False) and cx.size:
        (x0, y0), (x1, y1) = stand.bounds_m
        lx, ly = x1 - x0, y1 - y0
        idx, qx, qy = [], [], []
        for dx in (-lx, 0.0, lx):
            for dy in (-ly, 0.0, ly):
                keep = ((cx + dx + r > x0 - pad_m) & (cx + dx - r < x1 + pad_m)
                        & (cy + dy + r > y0 - pad_m) & (cy + dy - r < y1 + pad_m))
                k = np.arange(cx.size) if dx == dy == 0.0 else np.flatnonzero(keep)
                idx.append(k)
                qx.append(cx[k] + dx)
                qy.append(cy[k] + dy)
        idx, cx, cy = np.concatenate(idx), np.concatenate(qx), np.concatenate(qy)
        zb, zt, r = zb[idx], zt[idx], r[idx]
    return crowns_table(stand, cx=cx, cy=cy, zb=zb, zt=zt, r=r, rho=rho, tau=tau)


def crowns_table(stand, *, cx, cy, zb, zt, r, rho: float, tau: float) -> dict:
    """A canopy table of the crowns (cx, cy) [m], bottoms and tops ``zb``, ``zt`` [m]
    (absolute), radii ``r`` [m] (each (n,)), with ``stand``'s shape and foliage and leaves of
    reflectance ``rho`` and transmittance ``tau``; Ross's G on :data:`G_NODES` nodes."""
    mu = np.linspace(0.0, 1.0, G_NODES)
    g = ross.g_function(mu, stand.leaf_angle)
    g[-1] = ross.G_NADIR[stand.leaf_angle]
    return {"cx": cx, "cy": cy, "zb": zb, "zt": zt, "r": r, "shape": stand.crown_shape,
            "leaf_angle": stand.leaf_angle, "g": g,
            "lad": float(stand.leaf_area_density_m2_m3), "clumping": float(stand.clumping),
            "rho": float(rho), "tau": float(tau)}


def tile_table(forest, *, x_m, y_m, reach_m: float, shift_m) -> dict:
    """The canopy table of one corridor tile of a forest over a DEM: the crowns that reach
    within ``reach_m`` [m] of the band of the tile's shots (``x_m``, ``y_m`` (n,) [m, the
    forest's frame]: the band about their chord, as the DEM's corridor, where every photon
    of theirs stays), with the periodic stand's images, each standing on the ground where
    it is (:func:`.explicit.placed_trees`), in the tile's coordinates (frame less
    ``shift_m`` (dx, dy, dz) [m]). Only the band: a tile's mesh on a coarse DEM's pixels
    spans hundreds of metres across, and its crowns cost the table's grid."""
    from ..ground.dem.tiles import chord_frame
    from .explicit import placed_trees
    s = forest.stand
    x, y, r = np.asarray(x_m, np.float64), np.asarray(y_m, np.float64), float(reach_m)
    idx, cx, cy, z = placed_trees(forest, (float(x.min()) - r, float(x.max()) + r,
                                           float(y.min()) - r, float(y.max()) + r))
    (ox, oy), (ux, uy), along, across = chord_frame(x, y)
    a = (cx - ox) * ux + (cy - oy) * uy
    c = (cx - ox) * -uy + (cy - oy) * ux
    rc = s.crown_radius_m[idx] + r
    keep = ((a >= along.min() - rc) & (a <= along.max() + rc)
            & (c >= across.min() - rc) & (c <= across.max() + rc))
    idx, cx, cy, z = idx[keep], cx[keep], cy[keep], z[keep] - shift_m[2]
    return crowns_table(s, cx=cx - shift_m[0], cy=cy - shift_m[1], zb=z + s.crown_base_m[idx],
                        zt=z + s.height_m[idx], r=s.crown_radius_m[idx],
                        rho=forest.leaf.reflectance, tau=forest.leaf.transmittance)


def table_file(table: dict) -> pathlib.Path:
    """Write ``table`` once to the cache (``LIDAR_MITSUBA_CACHE`` or the temporary folder),
    named by its content's hash, and return the path (an XML scene or a dict names it)."""
    from lidar_mitsuba_plugins import canopy_table as ct
    checked = ct.check(table)
    h = hashlib.sha256()
    for k in sorted(checked):
        h.update(k.encode())
        h.update(np.asarray(checked[k]).tobytes() if isinstance(checked[k], np.ndarray)
                 else repr(checked[k]).encode())
    folder = pathlib.Path(os.environ.get("LIDAR_MITSUBA_CACHE")
                          or pathlib.Path(tempfile.gettempdir()) / "lidar_mitsuba")
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"canopy_{h.hexdigest()[:20]}.npz"
    if not path.exists():
        tmp = path.with_suffix(f".{os.getpid()}.npz")
        ct.save(tmp, checked)
        os.replace(tmp, path)
    return path


def integrator_dict(stand, *, mode: str, base: dict, rho: float, tau: float,
                    hot_spot: bool = True, max_depth: int | None = None,
                    table: bool = True) -> dict:
    """The ``canopy`` integrator's Mitsuba dict for ``stand`` in representation ``mode``
    (:data:`MODES`), over ``base`` (the instrument's ``pathlength`` parameters:
    ``Instrument.integrator_dict()``). ``max_depth``: ``turbid``'s vertices per path
    (default the plugin's, 3); ``gap`` has two records per photon. ``table`` False: the
    dict names no table (a DEM's corridor tiles set each tile's, :func:`tile_table`)."""
    if mode not in MODES:
        raise ParameterError("representation", f"must be one of explicit, {', '.join(MODES)}"
                                               f" (got {mode!r})")
    pad = float(base.get("fov_radius_m", 20.65)) + 20.0
    d = {k: v for k, v in base.items() if k != "max_depth"}
    d.update(type="canopy", mode=mode, hot_spot=bool(hot_spot))
    if table:
        d["filename"] = str(table_file(canopy_table(stand, rho=rho, tau=tau, pad_m=pad)))
    if mode == "turbid" and max_depth is not None:
        d["max_depth"] = int(max_depth)
    return d


def no_shapes(forest, *, bounds_xy_m, shift_m) -> tuple[dict, int]:
    """The turbid and gap representations' Mitsuba shapes: none (the crowns are the
    ``canopy`` integrator's table, :func:`forest_integrator`); the scene is the ground's."""
    return {}, 0


def forest_integrator(forest, base: dict) -> dict:
    """The integrator a :class:`~lidar_mitsuba.vegetation.forest.ForestSurface` in the
    ``turbid`` or ``gap`` representation is traced with: ``canopy`` over ``base`` (the
    material's ``pathlength`` dict, whose ``max_depth`` the turbid medium keeps), the leaves'
    optics the forest's. Over one scene in the stand's coordinates (a plane or a
    heightfield) the table is the whole stand's; over a DEM's corridor tiles each tile sets
    its own (:func:`tile_table`, the forest's tiling)."""
    return integrator_dict(forest.stand, mode=forest.representation, base=base,
                           rho=forest.leaf.reflectance, tau=forest.leaf.transmittance,
                           max_depth=base.get("max_depth"),
                           table=not hasattr(forest.ground, "corridor_tile"))
