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
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..constants import ParameterError, check
from ..ground.surface import ChunkTiles, Plane, Surface
from . import explicit, turbid
from .optics import OPTICS, Optics
from .stand import DEM_STAND_M, Stand, stand as make_stand


def explicit_shapes(forest: "ForestSurface", *, bounds_xy_m, shift_m) -> tuple[dict, int]:
    """The explicit representation's Mitsuba shapes for the trees whose crowns reach into
    ``bounds_xy_m`` (x0, x1, y0, y1) [m, stand coordinates; None: all], placed at stand
    coordinates minus ``shift_m`` (dx, dy, dz) [m] (a corridor tile's origin). Returns
    ``(shapes, triangles)``: one merged mesh of every leaf (the leaf BSDF) and one of every
    stem (bark), for ``mi.load_dict``. Merged, not instanced: Dr.Jit traces a scene's
    instances one by one into every kernel (measured: a 5-ray cast through 100 instances
    took 7.8 s, through 10 1.0 s; the merged mesh of the same 10 trees 0.2 s)."""
    from ..trace.scene import mitsuba_mesh
    idx, x, y, z = explicit.placed_trees(forest, bounds_xy_m)
    if idx.size == 0:
        return {}, 0
    place = np.column_stack([x - shift_m[0], y - shift_m[1], z - shift_m[2]])
    leaves, stems = explicit.placed_meshes(forest.prototypes(), idx, place,
                                           turn_deg=forest.turns_deg()[idx])
    shapes = {}
    if len(leaves[1]):
        shapes["leaves"] = mitsuba_mesh(*leaves, bsdf=forest.leaf.bsdf_dict(), name="leaves")
    if len(stems[1]):
        shapes["stems"] = mitsuba_mesh(*stems, bsdf=forest.bark.bsdf_dict(), name="stems")
    return shapes, int(len(leaves[1]) + len(stems[1]))


#: most shots per corridor tile: ~350 m of track at ATLAS's 0.7 m spacing; a conifer stand
#: of the preset's density puts ~1700 trees (~6 million triangles) in such a tile
TILE_SHOTS = 500

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
        sunlit_albedo: the albedo the solar background takes for the forest (``None``: the
            scene's own, the first surface a vertical ray meets: the floor's in the ``gap``
            and ``turbid`` representations). Give it where the floor is much brighter than
            the crowns that shade it, e.g. snow (:mod:`~.snow_cover`).
    """
    ground: Surface
    stand: Stand
    representation: str = "explicit"
    leaf: Optics | None = None
    bark: Optics = OPTICS["bark"]
    floor: Optics = OPTICS["litter"]
    classes: int = 8
    sunlit_albedo: float | None = None
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

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
        a = self.sunlit_albedo
        check("sunlit_albedo", a, a is None or (isinstance(a, (int, float))
                                                  and math.isfinite(a) and 0 <= a <= 1),
              "must be in [0, 1] or None")
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

    # ------------------------------------------------------------ over a DEM
    @property
    def dem(self):
        """The ground's DEM (a forest over a :class:`~lidar_mitsuba.ground.dem.DEMSurface`:
        what a granule asks for its CRS)."""
        return self.ground.dem

    @property
    def roughness(self):
        """The ground's roughness heightfield, or None."""
        return getattr(self.ground, "roughness", None)

    @property
    def origin_m(self) -> tuple[float, float]:
        """The ground's frame origin in its CRS [m] ((0, 0) for a plane or a heightfield)."""
        return tuple(getattr(self.ground, "origin_m", (0.0, 0.0)))

    def with_origin(self, origin_m: tuple[float, float]) -> "ForestSurface":
        """The same forest in the frame whose origin is ``origin_m`` (the ground's CRS [m]):
        the ground's :meth:`~lidar_mitsuba.ground.dem.DEMSurface.with_origin` and the stand
        moved with it (the same trees on the same ground). A granule puts its frame near
        the track's start."""
        dx, dy = (float(n) - float(o) for n, o in zip(origin_m, self.origin_m))
        if dx == 0.0 and dy == 0.0:
            return self
        s = self.stand
        (x0, y0), (x1, y1) = s.bounds_m
        stand = replace(s, x_m=s.x_m - dx, y_m=s.y_m - dy,
                        bounds_m=((x0 - dx, y0 - dy), (x1 - dx, y1 - dy)))
        moved = replace(self, ground=self.ground.with_origin(origin_m), stand=stand)
        object.__setattr__(moved, "_cache", self._cache)    # prototypes, turns, cover: the
        return moved                                        # same wherever the frame is

    # ------------------------------------------------------------ the vegetation
    def prototypes(self) -> list[dict]:
        """The explicit representation's prototype trees (built once)."""
        if "prototypes" not in self._cache:
            self._cache["prototypes"] = explicit.prototypes(self.stand, classes=self.classes)
        return self._cache["prototypes"]

    def canopy_cover(self) -> float:
        """The stand's canopy cover (:meth:`~.stand.Stand.canopy_cover`, computed once: ~1 s
        for a 2 km stand, and every plan of a granule's sections says it)."""
        if "cover" not in self._cache:
            self._cache["cover"] = self.stand.canopy_cover()
        return self._cache["cover"]

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
        """Explicit leaves: a corridor tile per chunk of at most :data:`TILE_SHOTS` shots
        (``_ForestTiles``): the ground's mesh and the trees within ``reach_m`` of the chunk's
        shots (a DEM's own corridor tiles with the trees over them); ``crop`` False
        (``--full-tile``) is refused: a forest's tile is too many leaves to trace whole. A
        representation that adds no shapes to the scene: the ground's own tiling (one scene
        for a plane or a tile, folded positions, the whole stand's canopy table); over a
        DEM the DEM's corridor tiles, the ``canopy`` integrator holding the stand's crowns
        and each tile handing it the ground under them (:func:`.turbid.tile_crowns`)."""
        kw = dict(x_local_m=x_local_m, y_local_m=y_local_m, dz_m=dz_m, reach_m=reach_m,
                  bsdf=bsdf, crop=crop, chunk_shots=chunk_shots)
        tiled = hasattr(self.ground, "corridor_tile")
        if self.representation != "explicit" and tiled:
            # a DEM's corridor tiles, each with its own canopy table (the trees over it)
            kw["chunk_shots"] = min(int(chunk_shots), self.ground.tile_shots)
            return _ForestTiles(self, x_m, y_m, **{k: v for k, v in kw.items() if k != "crop"})
        if self.representation != "explicit":
            if type(self.ground).tiles is Surface.tiles:
                return Surface.tiles(self, x_m, y_m, **kw)
            return self.ground.tiles(x_m, y_m, **kw)
        if hasattr(bsdf, "shapes"):
            raise ParameterError("snow", "a snow volume under a forest is not supported: "
                                 "give the floor snow's albedo (floor=vegetation.optics."
                                 "snow_optics(...))")
        if not crop:
            raise ParameterError("crop_to_track", "a forest is traced in corridor tiles "
                                 "along the track (its whole tile is too many leaves)")
        kw["chunk_shots"] = min(int(chunk_shots), TILE_SHOTS,
                                getattr(self.ground, "tile_shots", TILE_SHOTS))
        return _ForestTiles(self, x_m, y_m, **{k: v for k, v in kw.items() if k != "crop"})

    # ------------------------------------------------------------ words
    def config(self) -> dict:
        return {"kind": "forest", "representation": self.representation,
                "ground": self.ground.config(), "stand": self.stand.config(),
                "canopy_cover": self.canopy_cover(),
                "optics_532nm": {name: {"R": o.reflectance, "T": o.transmittance,
                                        "source": o.source}
                                 for name, o in (("leaf", self.leaf), ("bark", self.bark),
                                                 ("floor", self.floor))},
                **({} if self.sunlit_albedo is None
                   else {"sunlit_albedo": self.sunlit_albedo})}

    def notes(self, *, instrument, max_depth, crop, triangles) -> list[str]:
        s = self.stand
        out = [f"forest ({self.representation}): {s.n_trees} {s.species} trees over "
               f"{s.area_m2 / 1e4:.3g} ha, mean height {float(s.height_m.mean()):.3g} m, "
               f"{s.crown_shape} crowns, LAI {s.lai():.3g}, leaf angles {s.leaf_angle}; "
               f"{triangles} triangles in the first corridor tile (copies of "
               f"{len(self.prototypes())} prototype trees)"]
        if self.representation == "explicit" and s.clumping < 1:
            from .explicit import CLUSTER_LEAVES, cluster_radius
            out.append(f"clumping index {s.clumping:g} inside the crowns: leaves in clusters "
                       f"of {CLUSTER_LEAVES}, {100 * cluster_radius(s):.3g} cm in radius "
                       f"(solved for it at nadir)")
        out.append(f"optics at 532 nm: {self.leaf.name} R {self.leaf.reflectance:g} "
                   f"T {self.leaf.transmittance:g}, bark {self.bark.reflectance:g}, floor "
                   f"{self.floor.reflectance:g}")
        if self.sunlit_albedo is not None:
            out.append(f"the sun sees the forest with albedo {self.sunlit_albedo:g} (given: "
                       f"the crowns shade the floor; its own albedo is "
                       f"{self.floor.albedo:.3g})")
        return out + self.ground.notes(instrument=instrument, max_depth=max_depth, crop=crop,
                                       triangles=triangles)

    def warnings(self, *, instrument) -> list[str]:
        out = self.ground.warnings(instrument=instrument)
        top = float(self.stand.height_m.max()) if self.stand.n_trees else 0.0
        half = instrument.range_gate_m / 2.0
        if top > half:
            out.append(f"the range gate (+-{half:g} m about the ground) cuts the canopy "
                       f"(trees up to {top:.3g} m): photons from above are not recorded; "
                       f"set range_gate_m (--range-gate-m) to at least "
                       f"{2 * math.ceil(top + 2):g}")
        return out


class _ForestTiles(ChunkTiles):
    """A forest's tiling: every chunk of shots traces its own corridor tile, built when the
    chunk is launched (:class:`~lidar_mitsuba.ground.tiling.ChunkTiles`): the ground's mesh
    over the chunk's shots ``reach_m`` about them (a plane's or a heightfield's in the frame
    of the chunk's first shot, unwrapped; a DEM's own corridor tile) and the stand's trees
    there (:meth:`ForestSurface.with_vegetation`); turbid and gap crowns over a DEM: the
    stand's crowns handed to the ``canopy`` integrator once (:meth:`attach`), and each
    tile's ground under them as the tile is (:func:`.turbid.tile_crowns`)."""

    def __init__(self, forest: ForestSurface, x_m, y_m, *, x_local_m, y_local_m, dz_m,
                 reach_m: float, bsdf, chunk_shots: int):
        self.forest = forest
        x, y = np.asarray(x_m, np.float64), np.asarray(y_m, np.float64)
        self.offsets_m = (x - np.asarray(x_local_m, np.float64),
                          y - np.asarray(y_local_m, np.float64),
                          np.broadcast_to(np.asarray(dz_m, np.float64), x.shape))
        self.integrator = None
        super().__init__(x, y, reach_m=reach_m, bsdf=bsdf, chunk_shots=chunk_shots)

    def attach(self, integrator) -> None:
        """The ``canopy`` integrator of a turbid or gap forest over a DEM: handed the stand's
        crowns (:func:`.turbid.stand_crowns`, padded by the field of view's diameter: a leg
        after the first ends where it leaves the field of view's cylinder, so none reaches
        farther from where it starts) and the first tile's ground (the scout traces it);
        each later tile's ground as the tile is."""
        self.integrator = integrator
        if self._first is not None and self._first[5] is not None:
            pad = 2.0 * float(integrator.fov_radius_m) + 1.0
            integrator.set_stand(turbid.stand_crowns(self.forest, pad_m=pad))
            integrator.set_tile(self._first[5])

    def _use(self, built: tuple) -> None:
        if built[5] is not None and self.integrator is not None:
            self.integrator.set_tile(built[5])

    def _build(self, a: int, b: int, prepared=None):
        """``(scene, x_local, y_local, offsets, triangles, tile)`` of shots ``a`` .. ``b - 1``
        (``tile``: turbid and gap over a DEM, :func:`.turbid.tile_crowns`; else None;
        ``prepared`` is always None: a forest's tiles have no ``prepare``)."""
        forest, x, y, n = self.forest, self.x_m[a:b], self.y_m[a:b], b - a
        if hasattr(forest.ground, "corridor_tile"):            # a DEM: its own tiles
            ground, (ox, oy), tri = forest.ground.corridor_tile(x, y, reach_m=self.reach_m,
                                                                bsdf=self.bsdf)
            shift = (float(ox), float(oy), 0.0)           # the tile's origin in the frame
            offsets = (np.full(n, float(ox)), np.full(n, float(oy)), np.zeros(n))
        else:       # the ground's tile frame (the stand's), folded at the chunk's first shot
            d = tuple(float(o[a]) for o in self.offsets_m)
            xl, yl, r = x - d[0], y - d[1], self.reach_m
            ground, tri = forest.ground.mitsuba_scene(
                bsdf=self.bsdf, margin_m=r,
                bounds_m=(float(xl.min()) - r, float(xl.max()) + r,
                          float(yl.min()) - r, float(yl.max()) + r))
            shift, offsets = (0.0, 0.0, 0.0), tuple(np.full(n, v) for v in d)
        if forest.representation != "explicit":       # the ground under the crowns there
            tile = turbid.tile_crowns(forest, x_m=x, y_m=y, reach_m=self.reach_m,
                                      origin_m=shift[:2])
            return ground, x - offsets[0], y - offsets[1], offsets, int(tri), tile
        scene, veg = forest.with_vegetation(ground, shift_m=shift)
        return scene, x - offsets[0], y - offsets[1], offsets, int(tri) + veg, None


def forest(*, species: str = "conifer", ground: Surface | None = None,
           representation: str = "explicit", leaf: Optics | None = None,
           floor: Optics | None = None, classes: int = 8, sunlit_albedo: float | None = None,
           **stand_kwargs) -> ForestSurface:
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
                         classes=classes, sunlit_albedo=sunlit_albedo, **kw)


def default_sunlit_albedo(species: str) -> float:
    """The albedo the sun sees of a forest over snow when none is given: Moody et al. 2007's
    snow-covered evergreen needleleaf forest (0.36) for ``conifer``, its mixed forest (0.39)
    for other species (:mod:`~.snow_cover`)."""
    from .snow_cover import SNOW_COVERED_ALBEDO
    return SNOW_COVERED_ALBEDO["evergreen needleleaf forest" if species == "conifer"
                               else "mixed forest"]


def forest_from_spec(spec: str, *, ground: Surface | None = None) -> ForestSurface:
    """The CLI's ``--forest SPECIES[:key=value,...]``, e.g. ``conifer:height=18,cover=0.6,
    lai=4``: keys ``height`` (m), ``cover``, ``stems`` (per ha), ``lai``, ``leaf_angle``,
    ``clumping``, ``crown_ratio``, ``crown_radius`` (m), ``crown_shape``, ``leaf_width`` (m),
    ``size`` (the side of the flat ground when ``ground`` is None, m, default 1024; over a
    DEM the side of the periodic stand, a square at the DEM's centre, default
    :data:`~.stand.DEM_STAND_M`), ``seed``, ``representation``, ``floor`` (the floor's
    optics: ``litter``, ``soil`` or ``snow``, :func:`~.optics.optics`) and ``sunlit_albedo``
    (the albedo the sun sees of the forest: :attr:`ForestSurface.sunlit_albedo`; with a snow
    floor and none given, the published albedo of a snow-covered evergreen needleleaf forest
    for conifers and of a mixed forest otherwise, :func:`default_sunlit_albedo`). Errors are
    ``ParameterError("forest", ...)``."""
    species, _, rest = spec.partition(":")
    names = {"height": "height_m", "cover": "cover", "stems": "stems_per_ha", "lai": "lai",
             "leaf_angle": "leaf_angle", "clumping": "clumping", "crown_ratio": "crown_ratio",
             "crown_radius": "crown_radius_m", "crown_shape": "crown_shape",
             "leaf_width": "leaf_width_m", "seed": "seed", "size": "size",
             "representation": "representation", "floor": "floor",
             "sunlit_albedo": "sunlit_albedo"}
    text = {"leaf_angle", "crown_shape", "representation", "floor"}
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
    size = kw.pop("size", None)
    if "floor" in kw:
        from .optics import optics
        try:
            kw["floor"] = optics(kw["floor"])
        except ParameterError as e:
            raise ParameterError("forest", f"floor: {e.message}") from None
        if kw["floor"].name.startswith("snow") and "sunlit_albedo" not in kw:
            kw["sunlit_albedo"] = default_sunlit_albedo(species.strip())
    over_dem = ground is not None and hasattr(ground, "dem")
    if size is not None and ground is not None and not over_dem:
        raise ParameterError("forest", "size only applies without --surface (the ground's "
                             "tile is the stand's)")
    size = (DEM_STAND_M if over_dem else 1024.0) if size is None else size
    check("forest", size, math.isfinite(size) and 1 <= size <= 1e5,
          "size must be in [1, 1e5] m")
    if over_dem:                       # a periodic square of that side at the DEM's centre
        (cx, cy) = ground.centre_xy_m()
        kw["bounds_m"] = ((cx - size / 2, cy - size / 2), (cx + size / 2, cy + size / 2))
    try:
        return forest(species=species.strip(),
                      ground=Plane(size_m=size) if ground is None else ground, **kw)
    except ParameterError as e:
        raise ParameterError("forest", f"{e.name}: {e.message}") from None
