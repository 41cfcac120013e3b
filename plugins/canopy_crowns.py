"""The crowns of the ``canopy`` integrator (``canopy.py``) in the kernel: the chord of a ray
through a crown, the integrator's table of a canopy table and its grid, and a stand's crowns
over a DEM's corridor tiles (one grid for every tile: a tile's photons wrapped into the
stand's square, each crown on the tile's ground under its image).

Imported as a plain module (it registers nothing): its functions take the arrays of the
variant active when they are called, as the ``canopy`` plugin's kernels do.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from lidar_mitsuba_plugins import canopy_table
from lidar_mitsuba_plugins.constants import REFERENCE_ALBEDO


def tables(t: dict, grid: tuple, *, tiled: bool) -> dict:
    """The integrator's table of ``t`` (``canopy_table.check``) and its ``grid``
    (``canopy_table.grid``); ``tiled``: a stand's crowns over tiles (``set_stand``)."""
    x0, y0, nx, ny, off, trees = grid
    # the grid's place and size as opaque values (kernel inputs, not constants): a new
    # table of the same stand reuses the compiled kernels
    line = (dr.opaque(mi.Float, x0), dr.opaque(mi.Float, y0), dr.opaque(mi.Int32, nx),
            dr.opaque(mi.Int32, ny), canopy_table.CELL_M, mi.UInt32(off), mi.UInt32(trees))
    per_cell = max(1, int(np.diff(off).max())) if off.size > 1 else 1
    return dict(
        crowns=[mi.Float(t[k]) for k in canopy_table.ARRAYS], shape=t["shape"],
        leaf_angle=canopy_table.LEAF_ANGLES.index(t["leaf_angle"]),
        sigma_g=mi.Float(t["g"] * np.float32(t["clumping"] * t["lad"])),
        n_g=int(t["g"].size), rho=t["rho"], tau=t["tau"], omega=t["rho"] + t["tau"],
        line=line, n=int(t["cx"].size), tiled=tiled,
        # (a power of two: the gap kernel's local buffers, a compile-time size)
        max_per_cell=1 << (per_cell - 1).bit_length(),
        sigma_nadir=float(t["g"][-1] * t["clumping"] * t["lad"]),
        # the gap layer's leaf return: pi Gamma_b / (G 0.9) at nadir, from the table's G
        # and <cos^2> (Ross; lidar_mitsuba.vegetation.ross.leaf_return_weight)
        leaf_nadir=t["rho"] * COS2[t["leaf_angle"]] / float(t["g"][-1]) / REFERENCE_ALBEDO)


def grid_of(t: dict) -> tuple:
    """The crowns of ``t`` binned into a grid (``canopy_table.grid``, ``CELL_M`` cells)."""
    return canopy_table.grid(t["cx"], t["cy"], t["r"], cell_m=canopy_table.CELL_M, pad_m=0.0)


def stand_tables(crowns: dict) -> dict:
    """The integrator's table of a stand's crowns over a DEM's tiles
    (:meth:`CanopyIntegrator.set_stand`), no tile yet."""
    t = canopy_table.check(crowns)
    tab = tables(t, crowns.get("grid") or grid_of(t), tiled=True)
    period = crowns["period_m"]
    tab.update(key=mi.UInt32(np.asarray(crowns["key"], np.uint32)),
               period=None if period is None else tuple(dr.opaque(mi.Float, float(v))
                                                        for v in period),
               tile=None, top=dr.opaque(mi.Float, -1e30))
    return tab


def tile_local(tab: dict, x: mi.Float, y: mi.Float):
    """``(x, y, image)``: the point (x, y) [m] in the grid's coordinates and the image of
    the stand it lies in, counted from the tile's first (a stand over a DEM's tiles: the
    tile's coordinates shifted to the stand's and wrapped into its square); a plain table:
    as it is, ``image`` None."""
    if not tab["tiled"]:
        return x, y, None
    shx, shy, bx, by = tab["tile"][:4]
    gx, gy = x + shx, y + shy
    if tab["period"] is None:
        return gx, gy, (bx, by)
    lx, ly = tab["period"]
    wx, wy = dr.floor(gx / lx), dr.floor(gy / ly)
    return gx - wx * lx, gy - wy * ly, (mi.Int32(wx) + bx, mi.Int32(wy) + by)


def tile_chord(tab: dict, k, o, d, active, image, crown):
    """:meth:`CanopyIntegrator._chord` of a stand's crown ``k`` (``crown``: cx, cy, zb, zt,
    r, heights above its ground) from the stand's ``image`` (:func:`tile_local`): on the
    tile's ground under that image of its tree (none there, or out of the tile: a miss)."""
    cx, cy, zb, zt, r = crown
    mx, my, n, ground = tab["tile"][4:]
    key = dr.gather(mi.UInt32, tab["key"], k, active)
    ix = image[0] + mi.Int32((key >> 4) & 15) - 8
    iy = image[1] + mi.Int32(key & 15) - 8
    ok = active & (ix >= 0) & (ix < mx) & (iy >= 0) & (iy < my)
    z = dr.gather(mi.Float, ground, mi.UInt32(iy * mx + ix) * n + (key >> 8), ok)
    ok &= dr.isfinite(z)
    t0, t1 = crown_chord(tab["shape"], o, d, cx, cy, zb + z, zt + z, r)
    return dr.select(ok, t0, dr.inf), dr.select(ok, t1, -dr.inf)


#: <cos^2 theta_L> of each leaf angle distribution (lidar_mitsuba.vegetation.ross.COS2_MEAN)
COS2 = {"spherical": 1.0 / 3.0, "planophile": 0.75, "erectophile": 0.25, "uniform": 0.5}


def crown_chord(shape: str, o: mi.Point3f, d: mi.Vector3f, cx, cy, zb, zt, r):
    """Entry and exit distances ``(t0, t1)`` of the ray ``o + t d`` (``d`` unit) through a
    crown of axis (cx, cy) between heights ``zb`` and ``zt``, widest radius ``r``
    (``t0 >= t1`` where it misses): the slab ``zb <= z <= zt`` intersected with the cylinder
    (``x^2 + y^2 <= r^2``), the ellipsoid (semi-axes r, r, (zt - zb)/2) or the cone (apex
    at ``zt``, radius ``r`` at ``zb``). Each is convex, so the ray's part inside is one
    interval: the roots of a quadratic, clipped to the slab."""
    px, py = o.x - cx, o.y - cy
    inv_dz = dr.rcp(dr.select(dr.abs(d.z) > 1e-12, d.z, 1e-12))
    ta, tb = (zb - o.z) * inv_dz, (zt - o.z) * inv_dz
    s0, s1 = dr.minimum(ta, tb), dr.maximum(ta, tb)
    if shape == "ellipsoid":          # scaled to the sphere of radius r
        k = r / (0.5 * (zt - zb))
        pz, dz = (o.z - 0.5 * (zb + zt)) * k, d.z * k
        a = dr.square(d.x) + dr.square(d.y) + dr.square(dz)
        b = px * d.x + py * d.y + pz * dz
        c = dr.square(px) + dr.square(py) + dr.square(pz) - r * r
    elif shape == "cylinder":
        a = dr.square(d.x) + dr.square(d.y)
        b = px * d.x + py * d.y
        c = dr.square(px) + dr.square(py) - r * r
    else:                             # cone: x^2 + y^2 <= k^2 (z - zt)^2, z <= zt
        k = r / (zt - zb)
        pz = o.z - zt
        a = dr.square(d.x) + dr.square(d.y) - dr.square(k * d.z)
        b = px * d.x + py * d.y - k * k * pz * d.z
        c = dr.square(px) + dr.square(py) - dr.square(k * pz)
    disc = dr.square(b) - a * c
    root = dr.sqrt(dr.maximum(disc, 0.0))
    tiny = dr.abs(a) <= 1e-12
    safe_a = dr.select(tiny, 1e-12, a)
    q0, q1 = (-b - root) / safe_a, (-b + root) / safe_a
    r0, r1 = dr.minimum(q0, q1), dr.maximum(q0, q1)
    if shape == "cone":
        # a < 0 (steeper than the cone's side, e.g. a vertical line): the quadratic is <= 0
        # outside its roots; the piece below the apex is the later one going down
        steep = a < 0.0
        down = d.z < 0.0
        e0 = dr.select(steep, dr.select(down, r1, -dr.inf), r0)
        e1 = dr.select(steep, dr.select(down, dr.inf, r0), r1)
        miss = ~steep & (disc < 0.0)
    elif shape == "cylinder":         # along the axis: inside throughout or never
        e0 = dr.select(tiny, -dr.inf, r0)
        e1 = dr.select(tiny, dr.inf, r1)
        miss = dr.select(tiny, c > 0.0, disc < 0.0)
    else:
        e0, e1, miss = r0, r1, disc < 0.0
    t0 = dr.maximum(e0, s0)
    t1 = dr.minimum(e1, s1)
    return dr.select(miss, dr.inf, t0), dr.select(miss, -dr.inf, t1)
