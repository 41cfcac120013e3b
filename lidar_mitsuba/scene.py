"""Mitsuba scenes: in-memory meshes, bounds and vertical ray casts. Everything here needs the
renderer; surfaces and their meshes are in :mod:`.surface`, the pure-numpy terrain in
:mod:`.terrain`.

Coordinates are scene coordinates in metres, z up.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np


def ward_bsdf_dict(*, rho_d: float = 0.9, rho_s: float = 0.05, alpha: float = 0.3,
                   normalization: str = "ward1992") -> dict:
    """Mitsuba dict of our Ward BSDF (the paper's snow by default)."""
    return {"type": "ward", "rho_d": float(rho_d), "rho_s": float(rho_s),
            "alpha": float(alpha), "normalization": normalization}


def mitsuba_mesh(vertices: np.ndarray, faces: np.ndarray, *, bsdf: dict | mi.BSDF | None = None,
                 name: str = "terrain") -> mi.Mesh:
    """An in-memory Mitsuba mesh (no file written).

    Args:
        vertices: (n_vertices, 3) positions [m].
        faces: (n_faces, 3) vertex indices, counter-clockwise seen from the side the normal
            points to.
        bsdf: a Mitsuba BSDF or its dict (default: Mitsuba's default diffuse).
    """
    props = mi.Properties()
    if bsdf is not None:
        props["bsdf"] = bsdf if isinstance(bsdf, mi.BSDF) else mi.load_dict(bsdf)
    v = np.ascontiguousarray(vertices, dtype=np.float32)
    f = np.ascontiguousarray(faces, dtype=np.uint32)
    mesh = mi.Mesh(name, v.shape[0], f.shape[0], props=props)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(v.ravel())
    params["faces"] = mi.UInt32(f.ravel())
    params.update()
    return mesh


def scene_from_mesh(vertices: np.ndarray, faces: np.ndarray, *, bsdf: dict | None = None
                    ) -> mi.Scene:
    """A Mitsuba scene holding one mesh (default BSDF: the paper's Ward snow)."""
    mesh = mitsuba_mesh(vertices, faces, bsdf=bsdf if bsdf is not None else ward_bsdf_dict())
    return mi.load_dict({"type": "scene", "terrain": mesh})


def scene_bounds(scene: mi.Scene) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) corners [m] of the union of the scene's shapes, as float64 (3,) arrays.

    Meshes are bounded by their vertex buffers: when Mitsuba merges meshes that share a BSDF,
    the merged mesh keeps the bounding box of the first one. Other shapes use ``bbox()``.
    Raises ``ValueError`` for a scene without (finite) shapes.
    """
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for shape in scene.shapes():
        if shape.is_mesh():
            if not shape.vertex_count():
                continue
            v = np.asarray(shape.vertex_positions_buffer(), np.float64).reshape(-1, 3)
            blo, bhi = v.min(0), v.max(0)
        else:
            b = shape.bbox()
            if not b.valid():
                continue
            blo = np.array([float(c) for c in b.min])
            bhi = np.array([float(c) for c in b.max])
        if np.all(np.isfinite(blo)) and np.all(np.isfinite(bhi)):
            lo, hi = np.minimum(lo, blo), np.maximum(hi, bhi)
    if not np.all(np.isfinite(lo)):
        raise ValueError("the scene has no shapes to trace (none, or only ones with "
                         "non-finite coordinates)")
    return lo, hi


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
