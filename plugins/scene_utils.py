"""Scene queries the integrators need before tracing: the one participating medium of a scene
and the scene's bounds from its geometry (Mitsuba merges meshes that share a BSDF and keeps a
stale box). Shared by ``pathlength`` and ``volpathlength``; ``lidar_mitsuba.trace.scene`` re-exports
them.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np


def scene_medium(scene: mi.Scene):
    """The one participating medium of a scene (the interior medium of its shapes), or
    ``None``. Raises ``ValueError`` for more than one medium, a medium that is not
    ``homogeneous``, or a shape bounding it whose BSDF is not ``null`` (index-matched)."""
    found = []
    for shape in scene.shapes():
        for med in (shape.interior_medium(), shape.exterior_medium()):
            if med is None:
                continue
            if not med.is_homogeneous():
                raise ValueError(f"shape '{shape.id()}': only homogeneous media are supported "
                                 f"(got {med.class_name()})")
            if not mi.has_flag(shape.bsdf().flags(), mi.BSDFFlags.Null):
                raise ValueError(f"shape '{shape.id()}' bounds a medium: give it "
                                 f'<bsdf type="null"/> (an index-matched surface)')
            if not any(med is m for m in found):
                found.append(med)
    if len(found) > 1:
        raise ValueError(f"the scene has {len(found)} media; one (the snow) is supported")
    return found[0] if found else None


def scene_bounds(scene: mi.Scene) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) corners [m] of the union of the scene's shapes, as float64 (3,) arrays.

    Meshes are bounded by their vertex buffers: when Mitsuba merges meshes that share a BSDF,
    the merged mesh keeps the bounding box of the first one. Other shapes use ``bbox()``.
    Raises ``ValueError`` for a scene without shapes, or whose shapes all have non-finite
    coordinates (e.g. a NaN in a transform).
    """
    shapes = scene.shapes()
    if len(shapes) == 1 and shapes[0].is_mesh() and shapes[0].vertex_count():
        lo, hi = _vertex_bounds(shapes[0])          # one mesh (a corridor tile): its own
        if np.isfinite(lo).all() and np.isfinite(hi).all() and (lo <= hi).all():
            return lo, hi                           # bounds, as the loop below gives them
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    n_bad = 0
    for shape in shapes:
        if shape.is_mesh():
            if not shape.vertex_count():
                continue
            blo, bhi = _vertex_bounds(shape)
        else:
            b = shape.bbox()
            blo = np.array([float(c) for c in b.min])
            bhi = np.array([float(c) for c in b.max])
        if np.all(np.isfinite(blo)) and np.all(np.isfinite(bhi)) and np.all(blo <= bhi):
            lo, hi = np.minimum(lo, blo), np.maximum(hi, bhi)
        else:
            n_bad += 1
    if not np.all(np.isfinite(lo)):
        if n_bad:
            raise ValueError(f"the scene's {n_bad} shape(s) have non-finite coordinates "
                             "(a NaN or inf in a transform or a vertex?)")
        raise ValueError("the scene has no shapes to trace")
    return lo, hi


#: meshes of at most this many vertices are bounded on the host on the CPU backend
#: (:func:`_vertex_bounds`). ESTIMATE: a corridor tile has ~1 000 vertices (0.05 ms in numpy
#: against ~0.2 ms of Dr.Jit's reductions and their host reads, every launch); from ~1 M
#: vertices Dr.Jit's parallel reduction wins
HOST_BOUNDS_MAX_VERTICES = 2 ** 20


def _vertex_bounds(shape) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) of a mesh's vertices, reduced on the device (only six numbers cross to the
    host; on the CPU backend a small mesh's buffer is read by numpy instead: no kernels, the
    same float32 extremes); NaN corners when any vertex is not finite."""
    buf = shape.vertex_positions_buffer()
    if (dr.backend_v(buf) == dr.JitBackend.LLVM
            and shape.vertex_count() <= HOST_BOUNDS_MAX_VERTICES):
        v = buf.numpy().reshape(-1, 3).T.copy()      # (3, n): a reduction along (n, 3)'s
        if not np.isfinite(v).all():                    # short axis took ~10x as long
            return np.full(3, np.nan), np.full(3, np.nan)
        return v.min(axis=1).astype(np.float64), v.max(axis=1).astype(np.float64)
    p = dr.unravel(mi.Point3f, buf)
    finite = dr.all(dr.isfinite(p.x) & dr.isfinite(p.y) & dr.isfinite(p.z))
    lo = [dr.min(c) for c in (p.x, p.y, p.z)]
    hi = [dr.max(c) for c in (p.x, p.y, p.z)]
    dr.eval(finite, lo, hi)
    if not bool(finite[0]):
        return np.full(3, np.nan), np.full(3, np.nan)
    return np.array([float(c[0]) for c in lo]), np.array([float(c[0]) for c in hi])


def bsdf_group_index(bsdf, default: float | None = None) -> float:
    """Group index of the interior of a transmissive BSDF (the region a refraction against
    its normal enters): the ``water`` BSDF's own, else ``default`` when given, else the phase
    index ``int_ior / ext_ior`` of a ``dielectric`` or ``roughdielectric`` (its ``eta``);
    1 for a BSDF that transmits nothing."""
    import sys
    water = sys.modules.get(f"lidar_mitsuba_plugins._{mi.variant()}_water")
    if water is not None and isinstance(bsdf, water.WaterBSDF):
        return float(bsdf.group_index)
    params = mi.traverse(bsdf)
    if "eta" not in params:
        return 1.0
    if default is not None:
        return float(default)
    return float(np.asarray(params["eta"]).ravel()[0])


def group_index_table(scene: mi.Scene, default: float | None = None) -> np.ndarray:
    """(n,) float32 group index per BSDF registry id (``dr.reinterpret_array(UInt32, bsdf)``)
    of the scene's shapes (:func:`bsdf_group_index`); 1 for ids the scene does not use."""
    found = {}
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        if bsdf is None:
            continue
        bid = int(dr.reinterpret_array(mi.UInt32, mi.BSDFPtr(bsdf))[0])
        found[bid] = bsdf_group_index(bsdf, default)
    table = np.ones(max(found, default=0) + 1, np.float32)
    for bid, n_g in found.items():
        table[bid] = n_g
    return table
