"""Mitsuba scenes: in-memory meshes, bounds and vertical ray casts. Everything here needs the
renderer; surfaces and their meshes are in :mod:`..ground.surface`, the pure-numpy terrain in
:mod:`..ground.terrain`.

Coordinates are scene coordinates in metres, z up.
"""
from __future__ import annotations

import math
import pathlib
import re

import numpy as np

from .variant import ensure_renderer

mi = ensure_renderer()        # the renderer, set up on first use
import drjit as dr  # noqa: E402  (after the libLLVM check)

from lidar_mitsuba_plugins.scene_utils import scene_bounds, scene_medium  # noqa: F401

from ..ground.brdf import ward_bsdf_dict


def mitsuba_mesh(vertices: np.ndarray, faces: np.ndarray, *, bsdf: dict | mi.BSDF | None = None,
                 name: str = "terrain", interior: mi.Medium | None = None) -> mi.Mesh:
    """An in-memory Mitsuba mesh (no file written).

    Args:
        vertices: (n_vertices, 3) positions [m].
        faces: (n_faces, 3) vertex indices, counter-clockwise seen from the side the normal
            points to.
        bsdf: a Mitsuba BSDF or its dict (default: Mitsuba's default diffuse).
        interior: the medium inside (below) the mesh, e.g. snow (:mod:`lidar_mitsuba.ground.snow`).
    """
    props = mi.Properties()
    if bsdf is not None:
        props["bsdf"] = bsdf if isinstance(bsdf, mi.BSDF) else mi.load_dict(bsdf)
    if interior is not None:
        props["interior"] = interior
    v = np.ascontiguousarray(vertices, dtype=np.float32)
    f = np.ascontiguousarray(faces, dtype=np.uint32)
    mesh = mi.Mesh(name, v.shape[0], f.shape[0], props=props)
    _set_buffers(mesh, {"vertex_positions": mi.Float(v.ravel()), "faces": mi.UInt32(f.ravel())})
    return mesh


class _MeshBuffers(mi.TraversalCallback):
    """The named buffers of one object's own parameters (not its children's)."""

    def __init__(self, names):
        super().__init__()
        self.names, self.found = names, {}

    def put(self, name, value, flags, cpptype=None):
        if name in self.names and not isinstance(value, mi.Object):
            self.found[name] = (value, cpptype)


def _set_buffers(mesh: mi.Mesh, values: dict) -> None:
    """``mi.traverse(mesh)``, ``params[k] = v`` for each of ``values`` and
    ``params.update()``, without the traversal of the mesh's BSDF and the parameter map
    (~0.1 ms a corridor tile): the same buffers set, the same ``parameters_changed`` call
    on the mesh alone (the only object they dirty), then the same evaluation."""
    cb = _MeshBuffers(values.keys())
    mesh.traverse(cb)
    for key, value in values.items():
        target, cpptype = cb.found[key]
        if cpptype is None:
            mi.set_property(target, value)
        else:
            mi.set_property(target, cpptype, value)
    mesh.parameters_changed(list(values))
    dr.eval()


def scene_from_mesh(vertices: np.ndarray, faces: np.ndarray, *, bsdf=None) -> mi.Scene:
    """A Mitsuba scene holding one terrain mesh. ``bsdf``: its BSDF dict (default: the paper's
    Ward snow), or a :class:`~lidar_mitsuba.ground.snow.SnowVolume`: the terrain then bounds a snow
    volume (an index-matched surface; a finite layer's base is the integrator's, not a mesh)."""
    if hasattr(bsdf, "shapes"):                                   # a snow volume
        return mi.load_dict({"type": "scene", **bsdf.shapes(vertices, faces)})
    mesh = mitsuba_mesh(vertices, faces, bsdf=bsdf if bsdf is not None else ward_bsdf_dict())
    return mi.load_dict({"type": "scene", "terrain": mesh})


def load_scene(source, *, params: dict | None = None) -> tuple[mi.Scene, str]:
    """Load a Mitsuba scene from an XML file (``str`` or path), a dict or a ``mi.Scene``.

    >>> import lidar_mitsuba as lm
    >>> scene, label = lm.load_scene("scenes/slope.xml", params={"slope_deg": "8"})
    ...                                                               # doctest: +SKIP

    ``params``: values of the XML's ``<default name="...">`` parameters (files only).
    Returns ``(scene, label)``, the label naming the source. Raises ``ValueError`` with one
    line (file, line and column, and Mitsuba's own message) for anything Mitsuba refuses, and
    for a scene without finite shapes.
    """
    if isinstance(source, mi.Scene):
        scene, label = source, "mi.Scene"
        if params:
            raise ValueError("params only apply to an XML scene file")
    elif isinstance(source, dict):
        if params:
            raise ValueError("params only apply to an XML scene file")
        scene, label = _load(lambda: mi.load_dict(source), "the scene dict"), "dict"
    elif isinstance(source, (str, pathlib.PurePath)):
        path = pathlib.Path(source)
        if not path.is_file():
            raise ValueError(f"file {str(path)!r} not found")
        kw = {str(k): str(v) for k, v in (params or {}).items()}
        scene, label = _load(lambda: mi.load_file(str(path), **kw), str(path)), str(path)
    else:
        raise ValueError(f"must be a Mitsuba XML file, a scene dict or a mitsuba.Scene "
                         f"(got {type(source).__name__})")
    if not isinstance(scene, mi.Scene):
        raise ValueError(f"{label} holds a {type(scene).__name__}, not a <scene>")
    scene_bounds(scene)                      # no shapes / non-finite shapes: say so now
    return scene, label


def _load(fn, where: str):
    try:
        return fn()
    except RuntimeError as e:       # Mitsuba's parser: "[parser.cpp:N] At FILE (line L, col C): ..."
        raise ValueError(_one_line(str(e), where)) from None


def _one_line(message: str, where: str) -> str:
    """Mitsuba's (possibly multi-line) error as one line: its location and the innermost
    message (the last line of an embedded Python traceback)."""
    lines = [ln.strip() for ln in message.strip().splitlines() if ln.strip()]
    first = re.sub(r"^\[[\w.]+:\d+\]\s*", "", lines[0]) if lines else "unknown error"
    if "Traceback (most recent call last)" in message:
        first = first.split("Traceback")[0].rstrip(": ") + ": " + lines[-1]
    elif len(lines) > 1:
        first = first.rstrip(":") + ": " + "; ".join(lines[1:])
    first = re.sub(r"^(At|While loading) ", "", first)
    if where not in first and "XML file" not in first:
        first = f"{where}: {first}"
    return first


def first_hits(scene: mi.Scene, x_m, y_m, *, through_null: bool = False):
    """The first surfaces vertical rays down from above the scene meet at each (x, y) [m]
    (``through_null``: going on through ``null`` surfaces, the boundaries of media, to the first
    surface that reflects, up to 16 of them): ``(si, shape)``, the Dr.Jit surface
    interactions of the flattened, broadcast inputs and that shape."""
    x = np.asarray(x_m, np.float32)
    y = np.asarray(y_m, np.float32)
    shape = np.broadcast(x, y).shape
    x, y = np.broadcast_to(x, shape).ravel(), np.broadcast_to(y, shape).ravel()
    top = float(scene_bounds(scene)[1][2]) + 1.0
    ray = mi.Ray3f(mi.Point3f(mi.Float(x), mi.Float(y), top), mi.Vector3f(0, 0, -1))
    si = scene.ray_intersect(ray)
    for _ in range(16 if through_null else 0):
        null = si.is_valid() & mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Null)
        if not null.numpy().any():
            break
        ray = mi.Ray3f(dr.select(null, si.p, ray.o) + mi.Vector3f(0, 0, -1e-3), ray.d)
        si = dr.select(null, scene.ray_intersect(ray, null), si)
    return si, shape


def cast_down(scene: mi.Scene, x_m, y_m, *,
              through_null: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Cast vertical rays down from above the scene at each (x, y) [m].

    Returns ``(z_m, normal_z)``, float64 arrays of the inputs' broadcast shape: the height of
    the first surface hit and the z component of its geometric normal (NaN where the ray
    misses; a negative ``normal_z`` means the surface faces down, away from the lidar).
    ``through_null``: go on through ``null`` surfaces (the boundaries of layers in the air)
    to the first surface that reflects (:func:`first_hits`).
    """
    si, shape = first_hits(scene, x_m, y_m, through_null=through_null)
    z = dr.select(si.is_valid(), si.p.z, dr.nan)
    nz = dr.select(si.is_valid(), si.n.z, dr.nan)
    return (z.numpy().astype(np.float64).reshape(shape),
            nz.numpy().astype(np.float64).reshape(shape))


def sunlit_albedo(scene: mi.Scene, x_m, y_m, *, solar_elevation_deg: float,
                  solar_azimuth_deg: float = 180.0, samples: int = 4096) -> float:
    """The directional-hemispherical albedo of the surfaces under (x_m, y_m) [m] for light
    from the sun (elevation and azimuth [deg], azimuth clockwise from north, y north, x east):
    the mean of the BSDF's sampled weight for that incident direction (Monte Carlo over
    ``samples`` directions at each point, fixed seed; a Lambertian BSDF gives its albedo
    exactly), averaged over the points a vertical ray hits. The solar background treats the
    surface as Lambertian with this albedo. NaN when no ray hits a reflecting surface (e.g. a
    snow volume's index-matched boundary)."""
    z, _ = cast_down(scene, x_m, y_m)
    x = np.asarray(x_m, np.float32).ravel()[np.isfinite(z.ravel())]
    y = np.asarray(y_m, np.float32).ravel()[np.isfinite(z.ravel())]
    if x.size == 0:
        return float("nan")
    el = math.radians(max(float(solar_elevation_deg), 1.0))   # at night: the sun's low angle
    az = math.radians(float(solar_azimuth_deg))
    sun = mi.Vector3f(math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el))
    n = x.size * int(samples)
    top = float(scene_bounds(scene)[1][2]) + 1.0
    ray = mi.Ray3f(mi.Point3f(mi.Float(np.repeat(x, samples)), mi.Float(np.repeat(y, samples)),
                              top), mi.Vector3f(0, 0, -1))
    si = scene.ray_intersect(ray)
    si.wi = si.to_local(sun)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(12345, n)
    bsdf = si.bsdf()
    reflecting = si.is_valid() & ~mi.has_flag(bsdf.flags(), mi.BSDFFlags.Null)
    _, weight = bsdf.sample(mi.BSDFContext(), si, sampler.next_1d(), sampler.next_2d(),
                            reflecting)
    w = dr.select(reflecting & (si.wi.z > 0), weight[0], 0.0)
    hits = dr.count(reflecting)
    dr.eval(w, hits)
    if int(hits[0]) == 0:
        return float("nan")
    return float(dr.sum(w)[0]) / int(hits[0])


def cast_heights_m(scene: mi.Scene, x_m, y_m, *, through_null: bool = False) -> np.ndarray:
    """Height [m] of the first surface below each (x, y) (NaN where a vertical ray misses;
    ``through_null``: as :func:`cast_down`).

    ``x_m``, ``y_m``: arrays of the same shape [m]; returns float64 of that shape.
    """
    return cast_down(scene, x_m, y_m, through_null=through_null)[0]


def raycast_reference_elevation_m(scene: mi.Scene, x_m, y_m, *, sigma_m: float,
                                  step_sigma: float = 0.25, radius_sigma: float = 5.0,
                                  max_rays: int = 2 ** 22,
                                  through_null: bool = False) -> np.ndarray:
    """Gaussian-footprint-weighted mean height around each (x, y) for any scene.

    Deterministic midpoint quadrature: vertical rays on a square grid of spacing
    ``step_sigma * sigma_m`` within ``radius_sigma * sigma_m``, weighted by
    ``exp(-r^2 / (2 sigma^2))``; misses are left out of the average. Shapes as inputs. The
    disc leaves out exp(-radius_sigma^2 / 2) of the footprint's weight (4e-6 at 5 sigma: at
    3.5 sigma the 0.2 % left out moved the mean of a 45-degree ridge by up to 1 cm).
    """
    x_m, y_m = np.broadcast_arrays(np.asarray(x_m, float), np.asarray(y_m, float))
    if sigma_m <= 0:
        return cast_heights_m(scene, x_m, y_m, through_null=through_null)
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
        z = cast_heights_m(scene, xs[s:s + per, None] + ox, ys[s:s + per, None] + oy,
                           through_null=through_null)
        ok = np.isfinite(z)
        out[s:s + per] = (np.where(ok, z, 0.0) * w).sum(1) / np.maximum((ok * w).sum(1), 1e-300)
        out[s:s + per][~ok.any(1)] = np.nan
    return out.reshape(x_m.shape)
