"""Surfaces, meshes and Mitsuba scenes.

Coordinates are local scene coordinates in metres, z up. A built-in surface is a square *tile*
``[0, size_m)^2``; the ground track runs along +x through ``y = size_m / 2`` and is wrapped into
the tile (a fractal tile is periodic; a plane is extended exactly by adding its height offset),
so tracks of any length trace against one small mesh. The mesh covers the tile plus a margin so
that footprints near the seam never fall off it.
"""
from __future__ import annotations

import math
import pathlib
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np
import trimesh

from .terrain import Heightfield


def ward_bsdf_dict(*, rho_d: float = 0.9, rho_s: float = 0.05, alpha: float = 0.3,
                   normalization: str = "ward1992") -> dict:
    """Mitsuba dict of our Ward BSDF (the paper's snow by default)."""
    return {"type": "ward", "rho_d": float(rho_d), "rho_s": float(rho_s),
            "alpha": float(alpha), "normalization": normalization}


# --------------------------------------------------------------------------- surfaces
@dataclass(frozen=True)
class Plane:
    """Plane through ``(size_m/2, size_m/2, 0)`` rising at ``slope_deg`` toward ``azimuth_deg``
    (0 = +x, the along-track direction; 90 = +y)."""
    slope_deg: float = 0.0
    azimuth_deg: float = 0.0
    size_m: float = 1024.0

    def __post_init__(self):
        if not (math.isfinite(self.slope_deg) and 0 <= self.slope_deg < 90):
            raise ValueError(f"slope_deg must be in [0, 90) (got {self.slope_deg})")
        if not (math.isfinite(self.size_m) and self.size_m > 0):
            raise ValueError(f"size_m must be > 0 (got {self.size_m})")

    @property
    def gradient(self) -> tuple[float, float]:
        """(dz/dx, dz/dy)."""
        t = math.tan(math.radians(self.slope_deg))
        a = math.radians(self.azimuth_deg)
        return t * math.cos(a), t * math.sin(a)

    def height_m(self, x_m, y_m) -> np.ndarray:
        gx, gy = self.gradient
        c = self.size_m / 2.0
        return gx * (np.asarray(x_m, float) - c) + gy * (np.asarray(y_m, float) - c)

    def reference_elevation_m(self, x_m, y_m, *, sigma_m: float) -> np.ndarray:
        """Gaussian-weighted mean height: for a plane, the height at the centre (exact)."""
        return self.height_m(x_m, y_m)

    def wrap(self, x_m, y_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions folded into the tile, and the height offset [m] to add back (exact)."""
        xl = np.mod(x_m, self.size_m)
        yl = np.mod(y_m, self.size_m)
        return xl, yl, self.height_m(x_m, y_m) - self.height_m(xl, yl)

    def to_trimesh(self, *, margin_m: float,
                   bounds_m: tuple[float, float, float, float] | None = None) -> trimesh.Trimesh:
        """Two triangles covering the tile plus ``margin_m``, or ``bounds_m`` (x0, x1, y0, y1)."""
        lo, hi = -margin_m, self.size_m + margin_m
        x0, x1, y0, y1 = bounds_m if bounds_m is not None else (lo, hi, lo, hi)
        xy = np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]])
        v = np.column_stack([xy, self.height_m(xy[:, 0], xy[:, 1])])
        return trimesh.Trimesh(v, np.array([[0, 1, 3], [0, 3, 2]]), process=False)


def heightfield_to_trimesh(hf: Heightfield, *, margin_m: float = 0.0,
                           bounds_m: tuple[float, float, float, float] | None = None
                           ) -> trimesh.Trimesh:
    """Triangulate a heightfield (two triangles per grid cell, normals up).

    Args:
        hf: the heightfield.
        margin_m: extension beyond the tile on every side [m] (a periodic heightfield repeats
            itself there; otherwise the edge heights are repeated).
        bounds_m: ``(x0, x1, y0, y1)`` [m] to mesh instead of the whole tile plus margin, e.g.
            the corridor around a ground track; may reach outside the tile (periodic wrap).

    Vertices: one per grid node of the covered area, at x = ix * grid_m (ix may be negative);
    triangles: twice the cells.
    """
    g = hf.grid_m
    if bounds_m is None:
        bounds_m = (-margin_m, hf.size_x_m + margin_m - g, -margin_m, hf.size_y_m + margin_m - g)
        if margin_m == 0:
            bounds_m = (0.0, hf.size_x_m - g, 0.0, hf.size_y_m - g)
    x0, x1, y0, y1 = bounds_m
    ix = np.arange(int(np.floor(x0 / g)), int(np.ceil(x1 / g)) + 1)
    iy = np.arange(int(np.floor(y0 / g)), int(np.ceil(y1 / g)) + 1)
    if hf.periodic:
        z = hf.z_m[np.ix_(iy % hf.ny, ix % hf.nx)]
    else:
        z = hf.z_m[np.ix_(np.clip(iy, 0, hf.ny - 1), np.clip(ix, 0, hf.nx - 1))]
    ny, nx = z.shape
    X, Y = np.meshgrid(ix * g, iy * g)
    vertices = np.column_stack([X.ravel(), Y.ravel(), z.ravel()])
    i = (np.arange(ny - 1)[:, None] * nx + np.arange(nx - 1)[None, :]).ravel()
    a, b, c, d = i, i + 1, i + nx, i + nx + 1        # (x,y), (x+1,y), (x,y+1), (x+1,y+1)
    faces = np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    return trimesh.Trimesh(vertices, faces, process=False)


def heightfield_wrap(hf: Heightfield, x_m, y_m):
    """Positions folded into a periodic tile (offset 0), like :meth:`Plane.wrap`."""
    x_m, y_m = np.asarray(x_m, float), np.asarray(y_m, float)
    return (np.mod(x_m, hf.size_x_m), np.mod(y_m, hf.size_y_m), np.zeros(np.broadcast(x_m, y_m).shape))


# --------------------------------------------------------------------------- Mitsuba
def scene_bounds(scene: mi.Scene) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) corners [m] of the union of the scene's shape bounds, as float64 (3,) arrays.

    (``Scene.bbox()`` and a shape's ``bbox()`` can be invalid after Mitsuba merges meshes that
    share a BSDF; the vertex buffer is used then.)
    Raises ``ValueError`` for a scene without shapes.
    """
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for shape in scene.shapes():
        b = shape.bbox()
        if b.valid():
            lo = np.minimum(lo, [float(v) for v in b.min])
            hi = np.maximum(hi, [float(v) for v in b.max])
        elif shape.is_mesh() and shape.vertex_count():   # e.g. meshes Mitsuba merged
            v = np.asarray(shape.vertex_positions_buffer(), np.float64).reshape(-1, 3)
            lo, hi = np.minimum(lo, v.min(0)), np.maximum(hi, v.max(0))
    if not np.all(np.isfinite(lo)):
        raise ValueError("the scene has no shapes to trace")
    return lo, hi


def mitsuba_mesh(tm: trimesh.Trimesh, *, bsdf: dict | mi.BSDF | None = None,
                 name: str = "terrain") -> mi.Mesh:
    """A ``trimesh.Trimesh`` as an in-memory Mitsuba mesh (no file written)."""
    props = mi.Properties()
    if bsdf is not None:
        props["bsdf"] = bsdf if isinstance(bsdf, mi.BSDF) else mi.load_dict(bsdf)
    v = np.ascontiguousarray(tm.vertices, dtype=np.float32)
    f = np.ascontiguousarray(tm.faces, dtype=np.uint32)
    mesh = mi.Mesh(name, v.shape[0], f.shape[0], props=props)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(v.ravel())
    params["faces"] = mi.UInt32(f.ravel())
    params.update()
    return mesh


def scene_from_trimesh(tm: trimesh.Trimesh, *, bsdf: dict | None = None) -> mi.Scene:
    """A Mitsuba scene holding one mesh (default BSDF: the paper's Ward snow)."""
    mesh = mitsuba_mesh(tm, bsdf=bsdf if bsdf is not None else ward_bsdf_dict())
    return mi.load_dict({"type": "scene", "terrain": mesh})


def export_ply(tm: trimesh.Trimesh, path: str | pathlib.Path) -> None:
    """Write a binary PLY that ``<shape type="ply">`` loads."""
    tm.export(str(path), file_type="ply", encoding="binary")


def cast_heights_m(scene: mi.Scene, x_m, y_m) -> np.ndarray:
    """Height [m] of the first surface below each (x, y) (NaN where a vertical ray misses).

    ``x_m``, ``y_m``: arrays of the same shape [m]; returns float64 of that shape.
    """
    x = np.asarray(x_m, np.float32)
    y = np.asarray(y_m, np.float32)
    shape = np.broadcast(x, y).shape
    x, y = np.broadcast_to(x, shape).ravel(), np.broadcast_to(y, shape).ravel()
    top = float(scene_bounds(scene)[1][2]) + 1.0
    ray = mi.Ray3f(mi.Point3f(mi.Float(x), mi.Float(y), top), mi.Vector3f(0, 0, -1))
    si = scene.ray_intersect(ray)
    z = dr.select(si.is_valid(), si.p.z, dr.nan)
    return z.numpy().astype(np.float64).reshape(shape)


def raycast_reference_elevation_m(scene: mi.Scene, x_m, y_m, *, sigma_m: float,
                                  step_sigma: float = 0.25, radius_sigma: float = 3.5,
                                  max_rays: int = 2 ** 22) -> np.ndarray:
    """Gaussian-footprint-weighted mean height around each (x, y) for any scene.

    Deterministic midpoint quadrature: vertical rays on a square grid of spacing
    ``step_sigma * sigma_m`` within ``radius_sigma * sigma_m``, weighted by
    ``exp(-r^2 / (2 sigma^2))``; misses are left out of the average. Shapes as inputs.
    """
    x_m, y_m = np.broadcast_arrays(np.asarray(x_m, float), np.asarray(y_m, float))
    if sigma_m <= 0:
        return cast_heights_m(scene, x_m, y_m)
    k = int(math.ceil(radius_sigma / step_sigma))
    g = np.arange(-k, k + 1) * step_sigma
    gx, gy = np.meshgrid(g, g)
    inside = gx ** 2 + gy ** 2 <= radius_sigma ** 2
    ox, oy = gx[inside] * sigma_m, gy[inside] * sigma_m
    w = np.exp(-0.5 * (gx[inside] ** 2 + gy[inside] ** 2))
    xs, ys = x_m.ravel(), y_m.ravel()
    out = np.empty(xs.size)
    per = max(1, max_rays // ox.size)
    for s in range(0, xs.size, per):
        z = cast_heights_m(scene, xs[s:s + per, None] + ox, ys[s:s + per, None] + oy)
        ok = np.isfinite(z)
        out[s:s + per] = (np.where(ok, z, 0.0) * w).sum(1) / np.maximum((ok * w).sum(1), 1e-300)
        out[s:s + per][~ok.any(1)] = np.nan
    return out.reshape(x_m.shape)
