"""A forest as a surface: a :class:`~.stand.Stand` over any ground surface.

:class:`ForestSurface` answers the :class:`~lidar_mitsuba.ground.surface.Surface` questions by
asking its ground (heights, reference elevations, folding: the truth a forest run is measured
against is the ground's) and adds the vegetation to every scene the ground yields (one scene
for a plane or a heightfield tile, a corridor tile per chunk for a DEM). How the stand is
traced is its ``representation``; :data:`REPRESENTATIONS` maps each name to the function
that builds its Mitsuba shapes, the one place a new representation plugs in:

* ``"explicit"``: leaves and needles as instanced triangles, stems as bark frustums
  (:mod:`.explicit`), the bi-Lambertian leaf BSDF.
* ``"turbid"``, ``"gap"``: the crowns as a turbid medium of leaves, traced by Monte Carlo or
  as a gap-probability layer by the ``canopy`` integrator (:mod:`.turbid`); the scene is the
  ground's.

>>> import lidar_mitsuba as lm
>>> f = lm.forest(species="conifer", height_m=18, cover=0.6, lai=3,
...               ground=lm.Plane(size_m=200.0), seed=1)             # doctest: +SKIP
>>> res = lm.simulate(instrument=lm.Instrument.atlas("strong"), surface=f, shots=200,
...                   seed=1)                                          # doctest: +SKIP
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..constants import ParameterError, check
from ..ground.surface import OneTile, Plane, Surface, Tiling
from . import explicit, turbid
from .optics import OPTICS, Optics
from .stand import Stand, stand as make_stand


def explicit_shapes(forest: "ForestSurface", *, bounds_xy_m, shift_m) -> tuple[dict, int]:
    """The explicit representation's Mitsuba shapes for the trees whose crowns reach into
    ``bounds_xy_m`` (x0, x1, y0, y1) [m, stand coordinates; None: all], placed at stand
    coordinates minus ``shift_m`` (dx, dy, dz) [m] (a corridor tile's origin). Returns
    ``(shapes, triangles)``: shapegroups and instances for ``mi.load_dict``, and the
    triangles the instances stand for."""
    from ..trace.scene import mitsuba_mesh
    from ..trace.variant import ensure_renderer
    mi = ensure_renderer()
    protos = forest.prototypes()
    idx, x, y = explicit.trees_near(forest.stand, bounds_xy_m)
    if idx.size == 0:
        return {}, 0
    z = forest.stand.ground_z_m[idx].copy()
    moved = (x != forest.stand.x_m[idx]) | (y != forest.stand.y_m[idx])
    if moved.any():                   # periodic images stand on the ground where they are
        zg = np.asarray(forest.ground.height_m(x[moved], y[moved]), float)
        z[moved] = np.where(np.isfinite(zg), zg, z[moved])
    leaf_bsdf = mi.load_dict(forest.leaf.bsdf_dict())
    bark_bsdf = mi.load_dict(forest.bark.bsdf_dict())
    turn = forest.turns_deg()
    cls_of, scale_of = np.empty(forest.stand.n_trees, int), np.empty(forest.stand.n_trees)
    for k, p in enumerate(protos):
        cls_of[p["members"]], scale_of[p["members"]] = k, p["scale"]
    shapes, triangles = {}, 0
    for k, p in enumerate(protos):
        sel = np.flatnonzero(cls_of[idx] == k)
        if sel.size == 0:
            continue
        group = mi.load_dict({
            "type": "shapegroup",
            "leaves": mitsuba_mesh(*p["leaves"], bsdf=leaf_bsdf, name=f"leaves_{k}"),
            "stem": mitsuba_mesh(*p["stem"], bsdf=bark_bsdf, name=f"stem_{k}")})
        shapes[f"prototype_{k}"] = group          # the scene holds what it instances
        per_tree = len(p["leaves"][1]) + len(p["stem"][1])
        for j in sel:
            t = idx[j]
            shapes[f"tree_{k}_{j}"] = {
                "type": "instance", "shapegroup": group,
                "to_world": mi.ScalarTransform4f().translate(
                    [float(x[j] - shift_m[0]), float(y[j] - shift_m[1]),
                     float(z[j] - shift_m[2])]).rotate([0, 0, 1], float(turn[t])).scale(
                    float(scale_of[t]))}
        triangles += per_tree * sel.size
    return shapes, triangles


#: representation name -> function(forest, bounds_xy_m=..., shift_m=...) -> (shapes, triangles)
#: (``turbid`` and ``gap`` add no shapes: their crowns are the ``canopy`` integrator's table,
#: :meth:`ForestSurface.integrator_dict`)
REPRESENTATIONS: dict[str, Callable] = {"explicit": explicit_shapes, "turbid": turbid.no_shapes,
                                        "gap": turbid.no_shapes}


@dataclass(frozen=True, eq=False)
class ForestSurface(Surface):
    """A :class:`~.stand.Stand` over a ground :class:`Surface` (module docstring).

    Attributes:
        ground: the surface the trees stand on (a plane, a heightfield, a DEM).
        stand: the trees, in the ground's scene coordinates (a plane's or a tile's: the
            folded ones; a DEM's: the frame's).
        representation: how the stand is traced (:data:`REPRESENTATIONS`).
        leaf: the foliage's optics (default: needles for conifers, leaves otherwise).
        bark: the stems' optics.
        floor: the ground's optics (the default BSDF of the ground mesh: litter); a ``bsdf``
            given to ``simulate`` replaces it.
        classes: prototype trees of the explicit representation (height classes).
    """
    ground: Surface
    stand: Stand
    representation: str = "explicit"
    leaf: Optics | None = None
    bark: Optics = OPTICS["bark"]
    floor: Optics = OPTICS["litter"]
    classes: int = 8
    _cache: dict = field(default_factory=dict, repr=False)

    takes_bsdf = True

    def __post_init__(self):
        check("ground", type(self.ground).__name__,
              isinstance(self.ground, Surface) and not isinstance(self.ground, ForestSurface)
              and self.ground.takes_bsdf, "must be a plane, a heightfield or a DEM surface")
        check("stand", type(self.stand).__name__, isinstance(self.stand, Stand),
              "must be a Stand (lm.stand)")
        check("representation", self.representation,
              self.representation in REPRESENTATIONS,
              f"must be one of {', '.join(REPRESENTATIONS)}")
        if self.leaf is None:
            object.__setattr__(self, "leaf", OPTICS["needle" if self.stand.species == "conifer"
                                                     else "leaf"])

    # ------------------------------------------------------------ the ground's answers
    def centre_xy_m(self):
        return self.ground.centre_xy_m()

    def fold(self, x_m, y_m, *, margin_m: float):
        return self.ground.fold(x_m, y_m, margin_m=margin_m)

    def height_m(self, x_m, y_m):
        """The ground's height [m] (the truth a forest run is measured against)."""
        return self.ground.height_m(x_m, y_m)

    def reference_elevation_m(self, x_m, y_m, *, sigma_m: float):
        return self.ground.reference_elevation_m(x_m, y_m, sigma_m=sigma_m)

    def default_bsdf(self) -> dict:
        return self.floor.bsdf_dict()

    # ------------------------------------------------------------ the vegetation
    def prototypes(self) -> list[dict]:
        """The explicit representation's prototype trees (built once)."""
        if "prototypes" not in self._cache:
            self._cache["prototypes"] = explicit.prototypes(self.stand, classes=self.classes)
        return self._cache["prototypes"]

    def turns_deg(self) -> np.ndarray:
        """Each tree's turn about the vertical [deg] (n,), seeded by the stand."""
        if "turns" not in self._cache:
            rng = np.random.default_rng(np.random.SeedSequence([int(self.stand.seed or 0), 7]))
            self._cache["turns"] = 360.0 * rng.random(self.stand.n_trees)
        return self._cache["turns"]

    def vegetation_shapes(self, *, bounds_xy_m, shift_m=(0.0, 0.0, 0.0)) -> tuple[dict, int]:
        """The stand's shapes in the chosen representation (:data:`REPRESENTATIONS`)."""
        return REPRESENTATIONS[self.representation](self, bounds_xy_m=bounds_xy_m,
                                                     shift_m=shift_m)

    def integrator_dict(self, base: dict) -> dict:
        """The integrator the forest is traced with, from the material's dict ``base``:
        explicit leaves the material's own; ``turbid`` and ``gap`` the ``canopy`` integrator
        (:func:`.turbid.forest_integrator`)."""
        if self.representation == "explicit":
            return base
        return turbid.forest_integrator(self, base)

    def with_vegetation(self, scene, *, shift_m=(0.0, 0.0, 0.0)):
        """A ground scene with the stand added over its extent: ``(scene, triangles)``
        (``shift_m``: the ground scene's origin in stand coordinates)."""
        from ..trace.scene import scene_bounds
        from ..trace.variant import ensure_renderer
        mi = ensure_renderer()
        lo, hi = scene_bounds(scene)
        bounds = (float(lo[0]) + shift_m[0], float(hi[0]) + shift_m[0],
                  float(lo[1]) + shift_m[1], float(hi[1]) + shift_m[1])
        shapes, triangles = self.vegetation_shapes(bounds_xy_m=bounds, shift_m=shift_m)
        ground = {f"ground_{k}": s for k, s in enumerate(scene.shapes())}
        return mi.load_dict({"type": "scene", **ground, **shapes}), triangles

    def mitsuba_scene(self, *, bsdf, margin_m, bounds_m):
        scene, triangles = self.ground.mitsuba_scene(bsdf=bsdf, margin_m=margin_m,
                                                     bounds_m=bounds_m)
        scene, veg = self.with_vegetation(scene)
        return scene, int(triangles) + veg

    def tiles(self, x_m, y_m, *, x_local_m, y_local_m, dz_m, reach_m: float, bsdf,
              crop: bool, chunk_shots: int) -> Tiling:
        """One scene (the ground's mesh and the stand) for a ground that has one; a DEM's
        corridor tiles each with the stand's trees over them (:class:`ForestTiles`)."""
        if type(self.ground).tiles is Surface.tiles:
            return Surface.tiles(self, x_m, y_m, x_local_m=x_local_m, y_local_m=y_local_m,
                                 dz_m=dz_m, reach_m=reach_m, bsdf=bsdf, crop=crop,
                                 chunk_shots=chunk_shots)
        inner = self.ground.tiles(x_m, y_m, x_local_m=x_local_m, y_local_m=y_local_m,
                                  dz_m=dz_m, reach_m=reach_m, bsdf=bsdf, crop=crop,
                                  chunk_shots=chunk_shots)
        return ForestTiles(self, inner)

    # ------------------------------------------------------------ words
    def config(self) -> dict:
        return {"kind": "forest", "representation": self.representation,
                "ground": self.ground.config(), "stand": self.stand.config(),
                "canopy_cover": self.stand.canopy_cover(),
                "optics_532nm": {name: {"R": o.reflectance, "T": o.transmittance,
                                        "source": o.source}
                                 for name, o in (("leaf", self.leaf), ("bark", self.bark),
                                                 ("floor", self.floor))}}

    def notes(self, *, instrument, max_depth, crop, triangles) -> list[str]:
        s = self.stand
        out = [f"forest ({self.representation}): {s.n_trees} {s.species} trees over "
               f"{s.area_m2 / 1e4:.3g} ha, mean height {float(s.height_m.mean()):.3g} m, "
               f"{s.crown_shape} crowns, LAI {s.lai():.3g}, leaf angles {s.leaf_angle}; "
               f"{triangles} triangles traced (instances of {len(self.prototypes())} "
               f"prototype trees)"]
        out.append(f"optics at 532 nm: {self.leaf.name} R {self.leaf.reflectance:g} "
                   f"T {self.leaf.transmittance:g}, bark {self.bark.reflectance:g}, floor "
                   f"{self.floor.reflectance:g}")
        return out + self.ground.notes(instrument=instrument, max_depth=max_depth, crop=crop,
                                       triangles=triangles)

    def warnings(self, *, instrument) -> list[str]:
        return self.ground.warnings(instrument=instrument)


class ForestTiles(Tiling):
    """A ground's own tiling (a DEM's corridor tiles) with the stand's trees added to each
    tile: shifted by the tile's origin (its offsets are the same for all its shots)."""

    def __init__(self, forest: ForestSurface, inner: Tiling):
        self.forest, self.inner = forest, inner
        self.chunk_shots = inner.chunk_shots
        self.x_local_m, self.y_local_m = inner.x_local_m, inner.y_local_m
        self.scene, self.triangles = None, inner.triangles
        if inner.scene is not None:
            n = inner.chunk_shots
            *_, offsets = inner.tile(0, min(n, len(inner.x_local_m)))
            self._first_offsets = offsets
            self.scene, veg = forest.with_vegetation(inner.scene,
                                                     shift_m=_shift(offsets))
            self.triangles += veg

    def tile(self, a: int, b: int):
        if a == 0 and self.scene is not None:
            out = (self.scene, self.x_local_m[: b - a], self.y_local_m[: b - a],
                   self._first_offsets)
            return out
        scene, xl, yl, offsets = self.inner.tile(a, b)
        scene, _ = self.forest.with_vegetation(scene, shift_m=_shift(offsets))
        return scene, xl, yl, offsets

    def release(self) -> None:
        self.scene = None
        self.inner.release()

    def first_scene(self):
        if self.scene is not None:
            return self.scene
        n = self.chunk_shots
        scene, *_rest, offsets = self.inner.tile(0, n)
        return self.forest.with_vegetation(scene, shift_m=_shift(offsets))[0]

    def narrow(self, reach_m: float) -> bool:
        return self.inner.narrow(reach_m)

    def stats(self) -> dict:
        return self.inner.stats()


def _shift(offsets) -> tuple[float, float, float]:
    """A tile's origin in stand coordinates: its shots' common offset (dx, dy, dz) [m]."""
    return tuple(float(np.asarray(d)[0]) if np.size(d) else 0.0 for d in offsets)


def forest(*, species: str = "conifer", ground: Surface | None = None,
           representation: str = "explicit", leaf: Optics | None = None,
           floor: Optics | None = None, classes: int = 8, **stand_kwargs) -> ForestSurface:
    """A forest over ``ground`` in one call: :func:`~.stand.stand` (``species`` and every
    other keyword: height_m, cover or stems_per_ha, lai, leaf_angle, clumping, crown_ratio,
    crown_radius_m, crown_shape, leaf_width_m, bounds_m, seed) over the ground's tile, as a
    :class:`ForestSurface`. ``ground`` default: a flat 1024 m plane.

    >>> import lidar_mitsuba as lm
    >>> f = lm.forest(species="broadleaf", height_m=20, cover=0.7, lai=4,
    ...               ground=lm.Plane(size_m=100.0), seed=3)
    >>> f.stand.species, round(f.stand.lai(), 3)
    ('broadleaf', 4.0)
    """
    if ground is None:
        ground = Plane()
    from ..ground.surface import SurfaceSpec, resolve
    if isinstance(ground, SurfaceSpec):
        ground = resolve(ground)[0]
    s = make_stand(species=species, surface=ground, **stand_kwargs)
    kw = {} if floor is None else {"floor": floor}
    return ForestSurface(ground=ground, stand=s, representation=representation, leaf=leaf,
                         classes=classes, **kw)


def forest_from_spec(spec: str) -> ForestSurface:
    """The CLI's ``--forest SPECIES[:key=value,...]``, e.g. ``conifer:height=18,cover=0.6,
    lai=4``: keys ``height`` (m), ``cover``, ``stems`` (per ha), ``lai``, ``leaf_angle``,
    ``clumping``, ``crown_ratio``, ``crown_radius`` (m), ``crown_shape``, ``leaf_width`` (m),
    ``size`` (the flat ground's side, m), ``seed``, ``representation``."""
    species, _, rest = spec.partition(":")
    names = {"height": "height_m", "cover": "cover", "stems": "stems_per_ha", "lai": "lai",
             "leaf_angle": "leaf_angle", "clumping": "clumping", "crown_ratio": "crown_ratio",
             "crown_radius": "crown_radius_m", "crown_shape": "crown_shape",
             "leaf_width": "leaf_width_m", "seed": "seed", "size": "size",
             "representation": "representation"}
    text = {"leaf_angle", "crown_shape", "representation"}
    kw: dict = {}
    for item in filter(None, rest.split(",")):
        key, eq, value = item.partition("=")
        if not eq or key.strip() not in names:
            raise ParameterError("forest", f"{item!r}: expected key=value with key one of "
                                 f"{', '.join(names)}")
        key = key.strip()
        if key in text:
            kw[names[key]] = value.strip()
            continue
        try:
            number = float(value)
        except ValueError:
            raise ParameterError("forest", f"{key}={value!r} is not a number") from None
        kw[names[key]] = int(number) if key == "seed" and number == int(number) else number
    size = kw.pop("size", 1024.0)
    check("forest", size, math.isfinite(size) and 1 <= size <= 1e5,
          "size must be in [1, 1e5] m")
    try:
        return forest(species=species.strip(), ground=Plane(size_m=size), **kw)
    except ParameterError as e:
        raise ParameterError("forest", f"{e.name}: {e.message}") from None
