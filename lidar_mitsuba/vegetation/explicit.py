"""The explicit representation of a stand: every leaf a facet, every stem a bark frustum.

A :class:`~.stand.Stand`'s trees are copies of a few prototype trees, merged into one leaf
mesh and one stem mesh per scene (Mitsuba instancing was measured slower: Dr.Jit traces each
``instance`` into every kernel): the trees are sorted into ``classes`` height classes; each
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

Within-crown clumping: with the stand's clumping index Omega < 1 the facets come in clusters
(shoots) of :data:`CLUSTER_LEAVES`, uniform in balls whose centres are uniform in the crown;
the balls' radius is solved so that the clusters' mean vertical silhouette is Omega times
their facets' summed projection (:func:`cluster_radius`): Nilson's gap probability with
that Omega through the crown at nadir. With Omega 1 the facets are independent. The crowns'
own grouping of foliage (the between-crown gaps) comes out of the geometry either way.
"""
from __future__ import annotations

import functools
import math

import numpy as np

from ..constants import ParameterError, check
from .stand import Stand, periodic_copies, sample_leaf_inclination

#: facets per cluster (a shoot, a leaf cluster) when the stand's clumping index is below 1
#: (ESTIMATE: a conifer shoot holds tens of needles; 16 facets of 10 cm make a ~30-40 cm shoot)
CLUSTER_LEAVES = 16
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
                   rng: np.random.Generator, turn: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Equilateral triangles of area ``area_m2`` [m^2] about ``centres`` (n, 3), in the planes
    of ``normals`` (n, 3), each turned at random in its plane (``turn``: the turns as
    fractions of a full turn, (n,), instead). Returns ``(vertices (3n, 3), faces (n, 3))``,
    faces wound counter-clockwise about the normal."""
    n = centres.shape[0]
    side = math.sqrt(4.0 * area_m2 / math.sqrt(3.0))
    circ = side / math.sqrt(3.0)                      # centroid to vertex
    helper = np.where(np.abs(normals[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(normals, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(normals, u)
    a0 = 2.0 * np.pi * (rng.random(n) if turn is None else turn)
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


# --------------------------------------------------------------------------- clumping
def _unit_ball(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) points uniform in the unit ball."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * rng.random((n, 1)) ** (1.0 / 3.0)


def _silhouette_ratio(verts: np.ndarray, *, grid: int = 32) -> float:
    """Vertical silhouette area of clusters of triangles / the sum of their vertical
    projections: ``verts`` (clusters, m, 3, 3). The silhouette by point sampling on a
    ``grid`` x ``grid`` lattice over each cluster's box (a point is covered when inside
    any triangle's projection)."""
    xy = verts[..., :2]                                       # (c, m, 3, 2)
    lo, hi = xy.min(axis=(1, 2)), xy.max(axis=(1, 2))         # (c, 2)
    u = (np.arange(grid) + 0.5) / grid
    px = np.repeat(lo[:, None, 0] + (hi - lo)[:, None, 0] * u[None, :], grid, axis=1)
    py = np.tile(lo[:, None, 1] + (hi - lo)[:, None, 1] * u[None, :], (1, grid))

    def side(p, q, x, y):              # cross((q - p), (point - p)) for each lattice point
        return ((q[:, 0] - p[:, 0])[:, None] * (y - p[:, 1][:, None])
                - (q[:, 1] - p[:, 1])[:, None] * (x - p[:, 0][:, None]))
    covered = np.zeros(px.shape, bool)
    proj = 0.0
    for j in range(xy.shape[1]):
        a, b, c = xy[:, j, 0], xy[:, j, 1], xy[:, j, 2]
        s1, s2, s3 = side(a, b, px, py), side(b, c, px, py), side(c, a, px, py)
        covered |= ((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))
        proj += 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                             - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])).sum()
    sil = covered.mean(axis=1) * np.prod(hi - lo, axis=1)
    return float(sil.sum() / proj)


def cluster_radius(stand: Stand) -> float:
    """The radius [m] of ball-shaped clusters (shoots) of :data:`CLUSTER_LEAVES` facets that
    gives the stand's within-crown clumping index at nadir (:func:`cluster_radius_per_width`
    times the facet size); 0 for Omega 1 (independent facets)."""
    if stand.clumping >= 1.0:
        return 0.0
    return stand.leaf_width_m * cluster_radius_per_width(stand.leaf_angle,
                                                         float(stand.clumping))


@functools.lru_cache(maxsize=64)
def cluster_radius_per_width(leaf_angle: str, clumping: float, *,
                             leaves: int = CLUSTER_LEAVES, samples: int = 64) -> float:
    """Cluster radius / facet size giving the clumping index ``clumping`` (< 1) at nadir.

    For clusters placed independently, P_gap = exp(-n_c E[S] L), so Omega = E[silhouette S]
    / (``leaves`` x the mean vertical projection of a facet) (Nilson 1971; the shoot's
    silhouette to total area ratio of Oker-Blom & Smolander 1988, Forest Sci. 34, 894).
    E[S] by Monte Carlo over ``samples`` clusters with common random numbers (a fixed seed:
    one answer per leaf angle distribution and Omega, ~1-2 % Monte Carlo error in Omega),
    the radius by bisection on it (monotone in the radius). Scale-free: the ratio holds for
    any facet size."""
    rng = np.random.default_rng(np.random.SeedSequence([13, leaves, samples]))
    n = samples * leaves
    offsets = _unit_ball(n, rng)
    normals = leaf_normals(leaf_angle, n, rng)
    turn = rng.random(n)

    def omega(radius: float) -> float:
        v, _ = leaf_triangles(radius * offsets, normals, area_m2=1.0,
                              rng=np.random.default_rng(1), turn=turn)
        return _silhouette_ratio(v.reshape(samples, leaves, 3, 3))

    lo, hi = 0.05, 50.0
    if omega(lo) > clumping or omega(hi) < clumping:
        raise ParameterError("clumping", f"{clumping:g} cannot be realised by clusters of "
                             f"{leaves} leaves")
    for _ in range(16):                          # bisection in log radius: 1e-4 relative
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if omega(mid) < clumping else (lo, mid)
    return math.sqrt(lo * hi)


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
    cluster_m = cluster_radius(stand)
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
        centres = _leaf_centres(stand, n, height_m=h, base_m=base, radius_m=radius,
                                cluster_m=cluster_m, rng=rng)
        leaves = leaf_triangles(centres, leaf_normals(stand.leaf_angle, n, rng), area_m2=a,
                                rng=rng)
        out.append({"height_m": h, "leaves": leaves, "members": members, "scale": scale,
                    "radius_m": radius,
                    "stem": stem_frustum(radius_m=stem_r, height_m=h)})
    return out


def _leaf_centres(stand: Stand, n: int, *, height_m: float, base_m: float, radius_m: float,
                  cluster_m: float, rng: np.random.Generator) -> np.ndarray:
    """``(n, 3)`` leaf centres in one crown: uniform (``cluster_m`` 0), or in clusters of
    :data:`CLUSTER_LEAVES` uniform in balls of radius ``cluster_m`` [m] whose centres are
    uniform in the crown."""
    if cluster_m <= 0 or n == 0:
        return sample_in_crown(stand, n, height_m=height_m, base_m=base_m,
                               radius_m=radius_m, rng=rng)
    k = -(-n // CLUSTER_LEAVES)
    centres = sample_in_crown(stand, k, height_m=height_m, base_m=base_m, radius_m=radius_m,
                              rng=rng)
    pts = np.repeat(centres, CLUSTER_LEAVES, axis=0)
    pts = pts + cluster_m * _unit_ball(pts.shape[0], rng)
    return pts[:n]


def trees_near(stand: Stand, bounds_xy_m: tuple[float, float, float, float] | None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The trees whose crowns reach into ``bounds_xy_m`` (x0, x1, y0, y1) [m] (None: all),
    with the periodic images of a periodic stand: ``(index, x_m, y_m)``."""
    if bounds_xy_m is None:
        return np.arange(stand.n_trees), stand.x_m, stand.y_m
    x0, x1, y0, y1 = bounds_xy_m
    (sx0, sy0), (sx1, sy1) = stand.bounds_m
    w, hgt = sx1 - sx0, sy1 - sy0
    reach = float(stand.crown_radius_m.max(initial=0.0))
    shifts = [(i * w, j * hgt) for i, j in periodic_copies(stand.bounds_m, bounds_xy_m,
                                                           reach_m=reach,
                                                           periodic=stand.periodic)]
    # candidates from the stems sorted along the bounds' narrower side (a corridor tile is
    # a strip: a few per cent of a stand), then the exact test in stand order
    axis = "x" if x1 - x0 <= y1 - y0 else "y"
    order, sorted_v = _sorted_stems(stand, axis)
    lo, hi = (x0, x1) if axis == "x" else (y0, y1)
    idx, xs, ys = [], [], []
    for dx, dy in shifts:
        d = dx if axis == "x" else dy
        a = np.searchsorted(sorted_v, lo - reach - d - 1e-3, side="left")   # (a mm more:
        b = np.searchsorted(sorted_v, hi + reach - d + 1e-3, side="right")  # no rounding)
        cand = np.sort(order[a:b])
        x, y, r = stand.x_m[cand] + dx, stand.y_m[cand] + dy, stand.crown_radius_m[cand]
        ok = (x + r >= x0) & (x - r <= x1) & (y + r >= y0) & (y - r <= y1)
        idx.append(cand[ok])
        xs.append(x[ok])
        ys.append(y[ok])
    return np.concatenate(idx), np.concatenate(xs), np.concatenate(ys)


def _sorted_stems(stand: Stand, axis: str) -> tuple[np.ndarray, np.ndarray]:
    """``(order, values)``: the stems sorted by their ``axis`` ("x" or "y") coordinate [m]
    (kept in the stand's cache)."""
    key = f"sorted_{axis}"
    if key not in stand._cache:
        v = stand.x_m if axis == "x" else stand.y_m
        order = np.argsort(v, kind="stable")
        stand._cache[key] = (order, v[order])
    return stand._cache[key]


def placed_trees(forest, bounds_xy_m) -> tuple[np.ndarray, ...]:
    """The trees of ``forest`` (a :class:`~.forest.ForestSurface`) whose crowns reach into
    ``bounds_xy_m`` (x0, x1, y0, y1) [m] (None: all), periodic images included
    (:func:`trees_near`), each on the ground where it stands (an image's ground height is
    the ground's there, its stem's own where that is off the ground): ``(index, x_m, y_m,
    ground_z_m)``, each (m,)."""
    idx, x, y = trees_near(forest.stand, bounds_xy_m)
    return idx, x, y, ground_under(forest, idx, x, y)


def ground_under(forest, idx: np.ndarray, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """(m,) the ground's height [m] under the trees ``idx`` (stand indices) placed at
    (``x_m``, ``y_m``) [m]: a tree's own where it stands, an image's the ground's where the
    image is (its stem's own where that is off the ground)."""
    z = forest.stand.ground_z_m[idx].copy()
    moved = (x_m != forest.stand.x_m[idx]) | (y_m != forest.stand.y_m[idx])
    if moved.any():                   # periodic images stand on the ground where they are
        zg = np.asarray(forest.ground.height_m(x_m[moved], y_m[moved]), float)
        z[moved] = np.where(np.isfinite(zg), zg, z[moved])
    return z


def placed_meshes(protos: list[dict], idx: np.ndarray, place_m: np.ndarray, *,
                  turn_deg: np.ndarray) -> tuple[tuple, tuple]:
    """The trees ``idx`` (stand indices, (m,)) as copies of their prototypes, each scaled,
    turned by ``turn_deg`` (m,) about the vertical and moved to ``place_m`` (m, 3) [m]:
    ``((leaf vertices, leaf faces), (stem vertices, stem faces))``, float32 / uint32."""
    out = {"leaves": ([], []), "stem": ([], [])}
    count = {"leaves": 0, "stem": 0}
    member_of = {}
    for k, p in enumerate(protos):
        for j, t in enumerate(p["members"]):
            member_of[int(t)] = (k, float(p["scale"][j]))
    which = np.array([member_of[int(t)][0] for t in idx], int)
    scale = np.array([member_of[int(t)][1] for t in idx])
    a = np.radians(turn_deg)
    for k, p in enumerate(protos):
        sel = np.flatnonzero(which == k)
        if sel.size == 0:
            continue
        c, s_ = np.cos(a[sel]) * scale[sel], np.sin(a[sel]) * scale[sel]
        for part in ("leaves", "stem"):
            v, f = p[part]
            v = v.astype(np.float32)
            xs = c[:, None] * v[None, :, 0] - s_[:, None] * v[None, :, 1]
            ys = s_[:, None] * v[None, :, 0] + c[:, None] * v[None, :, 1]
            zs = scale[sel, None] * v[None, :, 2]
            verts = np.stack([xs, ys, zs], axis=-1) + place_m[sel, None, :]
            faces = (f[None, :, :] + (count[part] + len(v) * np.arange(sel.size))[:, None, None])
            out[part][0].append(verts.reshape(-1, 3).astype(np.float32))
            out[part][1].append(faces.reshape(-1, 3).astype(np.uint32))
            count[part] += len(v) * sel.size
    return tuple(tuple(np.concatenate(x) if x else np.zeros((0, 3)) for x in out[part])
                 for part in ("leaves", "stem"))
