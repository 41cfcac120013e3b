"""The explicit representation of a stand: every leaf a facet, every stem a bark frustum.

A :class:`~.stand.Stand`'s trees are drawn as instances of a few prototype trees (Mitsuba
``shapegroup`` + ``instance``): the trees are sorted into ``classes`` height classes; each
class has one prototype (the class's mean height, the crown base and radius in the class's
mean proportion to height) holding

* its leaves: triangles of area ``leaf_width_m^2``, centres uniform in the crown volume
  (random foliage: Poisson within the crown), normals drawn from the stand's leaf angle
  distribution (inclination by :func:`~.stand.sample_leaf_inclination`, azimuth uniform),
  each turned at random in its own plane; the bi-Lambertian leaf BSDF
  (``plugins/bilambertian.py``) with the leaf's or needle's optics;
* its stem: an 8-sided frustum from 0.5 m below the ground (a stem on a slope stays in the
  ground) to the tree top, radius ``stem_radius_m`` at the ground, tapering to nothing;
  bark optics (``diffuse``).

Each tree is the prototype of its class scaled by ``s = height / class height`` about its
stem foot, turned about the vertical at random and placed at its stem on the ground. Leaf
area scales as ``s^2``: each class's leaf count is set so that the class's total leaf area is
the stand's exactly (``LAD * sum(V_crown)`` over the class), so the stand's LAI holds; a
single tree's leaf area is off by ``s^2 / s^3``-scaling, at most the class's height spread
(a few percent with 8 classes).

Within-crown clumping: leaves are placed independently (Omega = 1 inside a crown); the stand's
clumping index is what the turbid and gap representations apply, and the crowns' own
grouping of foliage (between-crown gaps) comes out of the geometry here.
"""
from __future__ import annotations

import math

import numpy as np

from ..constants import check
from .stand import Stand, sample_leaf_inclination

#: the stem is sunk this far below the ground at its foot [m] (ESTIMATE: covers the ground's
#: rise across a stem of radius 0.3 m on slopes up to ~60 degrees)
STEM_SINK_M = 0.5
STEM_SIDES = 8


# --------------------------------------------------------------------------- geometry
def sample_in_crown(stand: Stand, n: int, *, height_m: float, base_m: float, radius_m: float,
                    rng: np.random.Generator) -> np.ndarray:
    """``(n, 3)`` points [m] uniform in one crown of the stand's shape, stem foot at the
    origin (rejection from the crown's bounding cylinder)."""
    length = height_m - base_m
    out = np.empty((0, 3))
    while out.shape[0] < n:
        m = int(1.3 * (n - out.shape[0]) / {"cone": 1 / 3, "ellipsoid": 2 / 3,
                                             "cylinder": 1.0}[stand.crown_shape]) + 16
        rho = radius_m * np.sqrt(rng.random(m))
        phi = 2.0 * np.pi * rng.random(m)
        s = rng.random(m)
        if stand.crown_shape == "cone":
            ok = rho <= radius_m * (1.0 - s)
        elif stand.crown_shape == "ellipsoid":
            ok = rho * rho <= radius_m * radius_m * (1.0 - (2.0 * s - 1.0) ** 2)
        else:
            ok = np.ones(m, bool)
        pts = np.column_stack([rho * np.cos(phi), rho * np.sin(phi), base_m + s * length])
        out = np.concatenate([out, pts[ok]])
    return out[:n]


def leaf_normals(leaf_angle: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """``(n, 3)`` unit leaf normals, upper hemisphere: inclination from the leaf angle
    distribution, azimuth uniform."""
    t = sample_leaf_inclination(leaf_angle, rng.random(n))
    phi = 2.0 * np.pi * rng.random(n)
    return np.column_stack([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.cos(t)])


def leaf_triangles(centres: np.ndarray, normals: np.ndarray, *, area_m2: float,
                   rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Equilateral triangles of area ``area_m2`` [m^2] about ``centres`` (n, 3), in the planes
    of ``normals`` (n, 3), each turned at random in its plane. Returns ``(vertices (3n, 3),
    faces (n, 3))``, faces wound counter-clockwise about the normal."""
    n = centres.shape[0]
    side = math.sqrt(4.0 * area_m2 / math.sqrt(3.0))
    circ = side / math.sqrt(3.0)                      # centroid to vertex
    helper = np.where(np.abs(normals[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(normals, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(normals, u)
    a0 = 2.0 * np.pi * rng.random(n)
    verts = np.empty((n, 3, 3))
    for k in range(3):
        a = a0 + k * 2.0 * np.pi / 3.0
        verts[:, k] = centres + circ * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * v)
    faces = np.arange(3 * n, dtype=np.int64).reshape(n, 3)
    return verts.reshape(-1, 3), faces


def stem_frustum(*, radius_m: float, height_m: float, sides: int = STEM_SIDES
                 ) -> tuple[np.ndarray, np.ndarray]:
    """A closed-sided frustum from ``-STEM_SINK_M`` (radius ``radius_m``) to ``height_m``
    (radius 0) about the z axis: ``(vertices, faces)``, normals outward."""
    a = 2.0 * np.pi * np.arange(sides) / sides
    ring = np.column_stack([radius_m * np.cos(a), radius_m * np.sin(a),
                            np.full(sides, -STEM_SINK_M)])
    verts = np.vstack([ring, [[0.0, 0.0, height_m]]])
    top = sides
    faces = np.array([[k, (k + 1) % sides, top] for k in range(sides)], np.int64)
    return verts, faces


# --------------------------------------------------------------------------- prototypes
def height_classes(stand: Stand, classes: int) -> np.ndarray:
    """Each tree's class (n,) int: quantile bins of height (fewer when trees are few)."""
    k = max(1, min(int(classes), stand.n_trees))
    if k == 1:
        return np.zeros(stand.n_trees, int)
    edges = np.quantile(stand.height_m, np.linspace(0, 1, k + 1)[1:-1])
    return np.searchsorted(edges, stand.height_m, side="right")


def prototypes(stand: Stand, *, classes: int = 8, seed: int = 0) -> list[dict]:
    """One prototype tree per height class (see the module): dicts with ``height_m``,
    ``leaves`` (vertices, faces), ``stem`` (vertices, faces), ``members`` (the trees'
    indices) and ``scale`` (each member's height / the class height)."""
    check("classes", classes, isinstance(classes, int) and 1 <= classes <= 64,
          "must be an integer in [1, 64]")
    cls = height_classes(stand, classes)
    rng = np.random.default_rng(np.random.SeedSequence([int(stand.seed or 0), int(seed), 42]))
    leaf_area = stand.leaf_area_m2()
    out = []
    for k in range(int(cls.max()) + 1 if stand.n_trees else 0):
        members = np.flatnonzero(cls == k)
        if members.size == 0:
            continue
        h = float(stand.height_m[members].mean())
        scale = stand.height_m[members] / h
        base = h * float(np.mean(stand.crown_base_m[members] / stand.height_m[members]))
        radius = h * float(np.mean(stand.crown_radius_m[members] / stand.height_m[members]))
        stem_r = h * float(np.mean(stand.stem_radius_m[members] / stand.height_m[members]))
        a = stand.leaf_width_m ** 2
        # the class's leaf area exactly: n a sum(s^2) = sum(LAD V)
        n = int(round(leaf_area[members].sum() / (a * float(np.sum(scale ** 2)))))
        centres = sample_in_crown(stand, n, height_m=h, base_m=base, radius_m=radius, rng=rng)
        leaves = leaf_triangles(centres, leaf_normals(stand.leaf_angle, n, rng), area_m2=a,
                                rng=rng)
        out.append({"height_m": h, "leaves": leaves, "members": members, "scale": scale,
                    "radius_m": radius,
                    "stem": stem_frustum(radius_m=stem_r, height_m=h)})
    return out


def trees_near(stand: Stand, bounds_xy_m: tuple[float, float, float, float] | None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The trees whose crowns reach into ``bounds_xy_m`` (x0, x1, y0, y1) [m] (None: all),
    with the periodic images of a periodic stand: ``(index, x_m, y_m)``."""
    if bounds_xy_m is None:
        return np.arange(stand.n_trees), stand.x_m, stand.y_m
    x0, x1, y0, y1 = bounds_xy_m
    (sx0, sy0), (sx1, sy1) = stand.bounds_m
    w, hgt = sx1 - sx0, sy1 - sy0
    shifts = [(0.0, 0.0)]
    if stand.periodic:
        kx = range(int(math.floor((x0 - sx1) / w)), int(math.ceil((x1 - sx0) / w)) + 1)
        ky = range(int(math.floor((y0 - sy1) / hgt)), int(math.ceil((y1 - sy0) / hgt)) + 1)
        shifts = [(i * w, j * hgt) for i in kx for j in ky]
    r = stand.crown_radius_m
    idx, xs, ys = [], [], []
    for dx, dy in shifts:
        x, y = stand.x_m + dx, stand.y_m + dy
        ok = (x + r >= x0) & (x - r <= x1) & (y + r >= y0) & (y - r <= y1)
        idx.append(np.flatnonzero(ok))
        xs.append(x[ok])
        ys.append(y[ok])
    return np.concatenate(idx), np.concatenate(xs), np.concatenate(ys)
