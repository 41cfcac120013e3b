"""Surfaces: what a run traces, and the truth it is measured against.

Every surface answers the same questions (:class:`Surface`): where the middle of the track
goes, how shot positions fold into the mesh that is traced, the height and the
footprint-weighted reference elevation under each shot, the Mitsuba scene to trace, and how
to describe itself. Three kinds:

* :class:`Plane`: a flat or sloped plane, two triangles. Single bounce is exact on it, and a
  track of any length folds into one tile exactly (the height offset is added back).
* :class:`HeightfieldSurface`: a :class:`~lidar_mitsuba.ground.terrain.Heightfield` (the fractal, or
  your own grid), meshed with trimesh over the track's corridor. A periodic heightfield folds
  a long track into its tile; a non-periodic one must hold the whole track.
* :class:`SceneSurface`: any Mitsuba scene (XML, dict or a loaded ``mi.Scene``), with its
  own BSDFs; heights come from vertical ray casts.

:class:`SurfaceSpec` describes a built-in surface by parameters (the CLI's ``--surface``);
:func:`resolve` turns whatever the user gave into a :class:`Surface`.
The scenes a track is traced in, chunk by chunk (:meth:`Surface.tiles`), are a
:class:`~lidar_mitsuba.ground.tiling.Tiling` (:mod:`lidar_mitsuba.ground.tiling`).
"""
from __future__ import annotations

import dataclasses
import math
import pathlib
from dataclasses import dataclass

from typing import TYPE_CHECKING

import numpy as np

from . import sea_ice_ridges, sea_ice_surface, terrain
from .brdf import ward_bsdf_dict
from ..constants import ParameterError, check
from ..machine import check_memory
from .terrain import Heightfield
# the tilings live in their own room; imported here for Surface.tiles and so that
# ``from lidar_mitsuba.ground.surface import ChunkTiles`` (the DEM's, the forest's) still works
from .tiling import ChunkTiles, OneTile, Tiling  # noqa: F401

if TYPE_CHECKING:                 # annotations only: the renderer is set up on first use,
    import mitsuba as mi          # trimesh where a heightfield or plane is meshed (a DEM's
    import trimesh                # tiles are meshed without it)

SURFACES = ("flat", "slope", "fractal", "sea_ice")
#: peak memory of meshing a heightfield per vertex [bytes]: grid temporaries, the trimesh
#: (float64 vertices, int64 faces) and Mitsuba's float32 / uint32 copies
MESH_BYTES_PER_VERTEX = 200


class Surface:
    """What :func:`~lidar_mitsuba.run.simulate` needs of a surface (see the module)."""
    #: single bounce is exact (nothing can scatter twice), so ``max_depth="auto"`` needs no pilot
    exact_single_bounce: bool = False
    #: built-in surfaces take a BSDF; a scene has its own
    takes_bsdf: bool = True

    def tiles(self, x_m: np.ndarray, y_m: np.ndarray, *, x_local_m: np.ndarray,
              y_local_m: np.ndarray, dz_m: np.ndarray, reach_m: float, bsdf,
              crop: bool, chunk_shots: int) -> "Tiling":
        """The scenes the shots at (``x_m``, ``y_m``) [m] are traced in, chunk by chunk
        (:class:`~lidar_mitsuba.ground.tiling.Tiling`). Here one scene for every chunk
        (:class:`~lidar_mitsuba.ground.tiling.OneTile`): the surface's mesh, cropped to
        ``reach_m`` around the folded positions (``x_local_m``, ``y_local_m``) when ``crop``,
        the offsets ``(x - x_local, y - y_local, dz)`` putting the returns back on the track.
        A DEM yields a corridor tile per chunk instead."""
        bounds = None
        if crop:
            bounds = (float(x_local_m.min()) - reach_m, float(x_local_m.max()) + reach_m,
                      float(y_local_m.min()) - reach_m, float(y_local_m.max()) + reach_m)
        scene, triangles = self.mitsuba_scene(bsdf=bsdf, margin_m=reach_m, bounds_m=bounds)
        return OneTile(scene, triangles, x_local_m=x_local_m, y_local_m=y_local_m,
                       offsets_m=(x_m - x_local_m, y_m - y_local_m, dz_m),
                       chunk_shots=chunk_shots)

    def centre_xy_m(self) -> tuple[float, float]:
        """Where the middle of a default track goes [m]."""
        raise NotImplementedError

    def default_bsdf(self) -> dict:
        """The BSDF on the surface's mesh when the run gives none (a ready surface: the
        paper's Ward snow; a forest: its floor's)."""
        return ward_bsdf_dict()

    def fold(self, x_m: np.ndarray, y_m: np.ndarray, *, margin_m: float):
        """Shot positions in the traced mesh, and the height offset to add back.

        Returns ``(x_loc, y_loc, dz)``, each like ``x_m`` [m]: a periodic surface folds the
        positions into its tile (``dz`` 0), a plane too (``dz`` its exact height change);
        other surfaces return the positions unchanged after checking that every footprint,
        ``margin_m`` around its centre, lies on the surface (``ParameterError`` otherwise).
        """
        raise NotImplementedError

    def height_m(self, x_m, y_m) -> np.ndarray:
        """Surface height under each point [m] (NaN where there is none)."""
        raise NotImplementedError

    def reference_elevation_m(self, x_m, y_m, *, sigma_m: float) -> np.ndarray:
        """Gaussian-footprint-weighted mean height around each point [m]."""
        raise NotImplementedError

    def mitsuba_scene(self, *, bsdf: dict | None, margin_m: float,
                      bounds_m: tuple[float, float, float, float] | None) -> tuple[mi.Scene, int]:
        """The Mitsuba scene to trace and its triangle count. ``bounds_m`` (x0, x1, y0, y1):
        mesh only that corridor (in folded coordinates); ``None``: the whole surface plus
        ``margin_m``."""
        raise NotImplementedError

    def config(self) -> dict:
        """A JSON-serialisable description (recorded in every output file)."""
        raise NotImplementedError

    def notes(self, *, instrument, max_depth: int, crop: bool, triangles: int) -> list[str]:
        """What ``--explain`` says about the surface's modelling choices."""
        return []

    def warnings(self, *, instrument) -> list[str]:
        """Modelling choices that may cost accuracy (shown without ``--explain`` too)."""
        return []


# --------------------------------------------------------------------------- meshes
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
    check_memory("grid_m", MESH_BYTES_PER_VERTEX * ix.size * iy.size,
                 f"a mesh of {ix.size} x {iy.size} nodes ({x1 - x0:g} x {y1 - y0:g} m at "
                 f"{g:g} m)", "use a coarser grid_m or a shorter track")
    if hf.periodic:
        z = hf.z_m[np.ix_(iy % hf.ny, ix % hf.nx)]
    else:
        z = hf.z_m[np.ix_(np.clip(iy, 0, hf.ny - 1), np.clip(ix, 0, hf.nx - 1))]
    X, Y = np.meshgrid(ix * g, iy * g)
    vertices = np.column_stack([X.ravel(), Y.ravel(), z.ravel()])
    import trimesh
    return trimesh.Trimesh(vertices, grid_faces(*z.shape), process=False)


def grid_faces(ny: int, nx: int) -> np.ndarray:
    """(2 (ny - 1) (nx - 1), 3) triangles of a row-major grid of ny x nx vertices whose rows
    step along the second axis of a right-handed frame (y for x, y): two per cell, normals
    up."""
    i = (np.arange(ny - 1)[:, None] * nx + np.arange(nx - 1)[None, :]).ravel()
    a, b, c, d = i, i + 1, i + nx, i + nx + 1        # (x,y), (x+1,y), (x,y+1), (x+1,y+1)
    return np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])


def export_ply(tm: trimesh.Trimesh, path: str | pathlib.Path) -> None:
    """Write a binary PLY that ``<shape type="ply">`` loads."""
    tm.export(str(path), file_type="ply", encoding="binary")


def _scene(tm: trimesh.Trimesh, bsdf: dict | None) -> tuple[mi.Scene, int]:
    from ..trace import scene as scn
    return scn.scene_from_mesh(tm.vertices, tm.faces, bsdf=bsdf), int(len(tm.faces))


def _check_inside(x_m, y_m, *, lo, hi, margin_m: float, what: str) -> None:
    """ParameterError (named ``shots``) unless every footprint lies ``margin_m`` inside the
    rectangle ``lo``-``hi`` (x, y) [m]."""
    x, y = np.asarray(x_m, float), np.asarray(y_m, float)
    inside = ((x - margin_m >= lo[0]) & (x + margin_m <= hi[0])
              & (y - margin_m >= lo[1]) & (y + margin_m <= hi[1]))
    if not inside.all():
        raise ParameterError(
            "shots", f"the track leaves {what} (x {lo[0]:g} .. {hi[0]:g} m, y {lo[1]:g} .. "
            f"{hi[1]:g} m): {int(inside.sum())} of its {x.size} shots have their footprint "
            f"({margin_m:g} m around the centre) on it; use fewer shots, or move or turn "
            f"the track")


# --------------------------------------------------------------------------- planes
@dataclass(frozen=True)
class Plane(Surface):
    """Plane through ``(size_m/2, size_m/2, 0)`` rising at ``slope_deg`` toward ``azimuth_deg``
    (0 = +x, the along-track direction; 90 = +y). ``size_m`` is the tile a track folds into.

    >>> import lidar_mitsuba as lm
    >>> res = lm.simulate(surface=lm.Plane(slope_deg=5), bsdf={"type": "diffuse"},
    ...                   shots=500)                                    # doctest: +SKIP"""
    slope_deg: float = 0.0
    azimuth_deg: float = 0.0
    size_m: float = 1024.0

    exact_single_bounce = True

    def __post_init__(self):
        check("slope_deg", self.slope_deg,
              math.isfinite(self.slope_deg) and 0 <= self.slope_deg < 90, "must be in [0, 90)")
        check("azimuth_deg", self.azimuth_deg, math.isfinite(self.azimuth_deg), "must be finite")
        check("size_m", self.size_m, math.isfinite(self.size_m) and self.size_m > 0, "must be > 0")

    @property
    def gradient(self) -> tuple[float, float]:
        """(dz/dx, dz/dy)."""
        t = math.tan(math.radians(self.slope_deg))
        a = math.radians(self.azimuth_deg)
        return t * math.cos(a), t * math.sin(a)

    def centre_xy_m(self):
        return self.size_m / 2.0, self.size_m / 2.0

    def height_m(self, x_m, y_m) -> np.ndarray:
        gx, gy = self.gradient
        c = self.size_m / 2.0
        return gx * (np.asarray(x_m, float) - c) + gy * (np.asarray(y_m, float) - c)

    def reference_elevation_m(self, x_m, y_m, *, sigma_m: float) -> np.ndarray:
        """Gaussian-weighted mean height: for a plane, the height at the centre (exact)."""
        return self.height_m(x_m, y_m)

    def fold(self, x_m, y_m, *, margin_m: float = 0.0):
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
        import trimesh
        return trimesh.Trimesh(v, np.array([[0, 1, 3], [0, 3, 2]]), process=False)

    def mitsuba_scene(self, *, bsdf, margin_m, bounds_m):
        return _scene(self.to_trimesh(margin_m=margin_m, bounds_m=bounds_m), bsdf)

    def config(self) -> dict:
        return {"kind": "slope" if self.slope_deg else "flat", "slope_deg": self.slope_deg,
                "slope_azimuth_deg": self.azimuth_deg, "size_m": self.size_m}

    def notes(self, **_) -> list[str]:
        return ["plane: two triangles; a track of any length folds into the tile exactly"]


# --------------------------------------------------------------------------- heightfields
@dataclass(frozen=True, eq=False)
class HeightfieldSurface(Surface):
    """A :class:`~lidar_mitsuba.ground.terrain.Heightfield` as a surface (nodes at ``ix * grid_m``,
    ``iy * grid_m``). Periodic: tracks fold into the tile. Not periodic: the grid covers
    ``[0, (nx - 1) grid_m] x [0, (ny - 1) grid_m]`` and must hold every footprint."""
    hf: Heightfield

    def centre_xy_m(self):
        if self.hf.periodic:
            return self.hf.size_x_m / 2.0, self.hf.size_y_m / 2.0
        return (self.hf.nx - 1) * self.hf.grid_m / 2.0, (self.hf.ny - 1) * self.hf.grid_m / 2.0

    def fold(self, x_m, y_m, *, margin_m: float):
        x_m, y_m = np.asarray(x_m, float), np.asarray(y_m, float)
        if self.hf.periodic:
            return (np.mod(x_m, self.hf.size_x_m), np.mod(y_m, self.hf.size_y_m),
                    np.zeros(np.broadcast(x_m, y_m).shape))
        g = self.hf.grid_m
        _check_inside(x_m, y_m, lo=(0.0, 0.0), hi=((self.hf.nx - 1) * g, (self.hf.ny - 1) * g),
                      margin_m=margin_m, what="the non-periodic heightfield")
        return x_m, y_m, np.zeros(np.broadcast(x_m, y_m).shape)

    def height_m(self, x_m, y_m):
        return self.hf.height_m(x_m, y_m)

    def reference_elevation_m(self, x_m, y_m, *, sigma_m):
        return self.hf.reference_elevation_m(x_m, y_m, sigma_m=sigma_m)

    def mitsuba_scene(self, *, bsdf, margin_m, bounds_m):
        return _scene(heightfield_to_trimesh(self.hf, margin_m=margin_m, bounds_m=bounds_m), bsdf)

    def config(self) -> dict:
        return {"kind": "heightfield", "nx": self.hf.nx, "ny": self.hf.ny,
                "grid_m": self.hf.grid_m, "periodic": self.hf.periodic,
                "relief_m": self.hf.relief_m}

    def notes(self, *, instrument, max_depth, crop, triangles) -> list[str]:
        size = max(self.hf.size_x_m, self.hf.size_y_m)
        if crop:
            out = [f"mesh cropped to the track corridor: {triangles} triangles (the "
                   f"footprints' 5 sigma{'' if max_depth == 1 else ' / the field of view'}); "
                   f"--full-tile meshes the whole {size:g} m tile"]
        else:
            out = [f"whole {size:g} m tile meshed: {triangles} triangles"]
        ratio = instrument.footprint_sigma_m / self.hf.grid_m
        out.append(f"mesh spacing {self.hf.grid_m:g} m = footprint sigma / {ratio:.1f}"
                   + ("" if ratio >= 2 else ": coarser than the footprint resolves"))
        return out

    def warnings(self, *, instrument) -> list[str]:
        ratio = instrument.footprint_sigma_m / self.hf.grid_m
        if ratio >= 2:
            return []
        return [f"the mesh spacing ({self.hf.grid_m:g} m) is coarser than half the footprint "
                f"sigma ({instrument.footprint_sigma_m:g} m): the terrain inside each footprint "
                f"is not resolved; use a finer --grid-m (<= {instrument.footprint_sigma_m / 2:g} m)"]


# --------------------------------------------------------------------------- Mitsuba scenes
@dataclass(frozen=True, eq=False)
class SceneSurface(Surface):
    """Any Mitsuba scene (z up, metres), traced as it is, with its own BSDFs.

    >>> import lidar_mitsuba as lm
    >>> res = lm.simulate(scene="scenes/melt_pond.xml", params={"depth_m": "2"},
    ...                   shots=500)       # a SceneSurface; doctest: +SKIP

    ``source`` says where it came from (a file name, ``"dict"`` or ``"mi.Scene"``).
    """
    scene: mi.Scene
    source: str = "mi.Scene"
    #: heights through ``null`` surfaces (a scene with layers in the air: the ground's)
    through_null: bool = False

    takes_bsdf = False

    @property
    def bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        from ..trace import scene as scn
        return scn.scene_bounds(self.scene)

    def centre_xy_m(self):
        lo, hi = self.bounds_m
        return 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])

    def fold(self, x_m, y_m, *, margin_m: float):
        lo, hi = self.bounds_m
        _check_inside(x_m, y_m, lo=lo[:2], hi=hi[:2], margin_m=margin_m,
                      what="the scene's bounding box")
        x_m, y_m = np.asarray(x_m, float), np.asarray(y_m, float)
        return x_m, y_m, np.zeros(np.broadcast(x_m, y_m).shape)

    def height_m(self, x_m, y_m):
        from ..trace import scene as scn
        return scn.cast_heights_m(self.scene, x_m, y_m, through_null=self.through_null)

    def reference_elevation_m(self, x_m, y_m, *, sigma_m):
        from ..trace import scene as scn
        return scn.raycast_reference_elevation_m(self.scene, x_m, y_m, sigma_m=sigma_m,
                                                 through_null=self.through_null)

    def mitsuba_scene(self, *, bsdf, margin_m, bounds_m):
        return self.scene, -1

    def config(self) -> dict:
        lo, hi = self.bounds_m
        return {"kind": "scene", "scene_file": self.source,
                "bounds_m": [lo.tolist(), hi.tolist()]}


# --------------------------------------------------------------------------- built-in surfaces
@dataclass(frozen=True)
class SurfaceSpec:
    """A built-in surface and its Ward reflectance (the paper's snow by default).

    >>> import lidar_mitsuba as lm
    >>> lm.SurfaceSpec(kind="fractal", p=1.8, relief_m=10.0).kind
    'fractal'

    Attributes:
        kind: ``flat``, ``slope``, ``fractal`` or ``sea_ice`` (rough sea ice of published
            rms height and correlation length, :mod:`~lidar_mitsuba.ground.sea_ice_surface`).
        slope_deg: slope of the ``slope`` plane [deg], in [0, 90).
        slope_azimuth_deg: direction of steepest ascent [deg] (0 = along track).
        p: spectral exponent of the fractal (1/f^p filter).
        relief_m: max - min height of the fractal tile [m].
        size_m: side of the square tile [m].
        grid_m: fractal grid spacing [m].
        terrain_seed: seed of the fractal's (or the sea ice's) white noise (>= 0).
        surface_rms_m: rms height of the ``sea_ice`` surface over its tile [m] (default:
            Beckers et al. 2015's Fram Strait mean, 0.16 m; 0.09 m north of Svalbard).
        surface_corr_m: correlation length (e-folding) of the ``sea_ice`` surface [m]
            (default 25: IceBridge ATM's 20-30 m, Remote Sens. 2022, 14, 3011).
        surface_ridges: the ``sea_ice`` surface's ridge sails (``arctic_obstacles``:
            Castellani et al. 2014's, 0.45 m high every ~20 m; ``none``: Gaussian relief;
            :mod:`~lidar_mitsuba.ground.sea_ice_ridges`); the rms is still the whole's.
        rho_d: Ward diffuse albedo.
        rho_s: Ward specular reflectance.
        alpha: Ward roughness (RMS slope of the specular lobe).
    """
    kind: str = "fractal"
    slope_deg: float = 0.0
    slope_azimuth_deg: float = 0.0
    p: float = 1.8
    relief_m: float = 10.0
    size_m: float = 1024.0
    grid_m: float = 1.0
    terrain_seed: int = 0
    rho_d: float = 0.9
    rho_s: float = 0.05
    alpha: float = 0.3
    surface_rms_m: float = sea_ice_surface.PRESETS[sea_ice_surface.DEFAULT_PRESET]["rms_m"]
    surface_corr_m: float = sea_ice_surface.PRESETS[
        sea_ice_surface.DEFAULT_PRESET]["corr_length_m"]
    surface_ridges: str = dataclasses.field(
        default=sea_ice_surface.PRESETS[sea_ice_surface.DEFAULT_PRESET]["ridges"],
        metadata={"choices": (*sea_ice_ridges.RIDGES, sea_ice_ridges.NONE)})

    def __post_init__(self):
        check("surface", self.kind, self.kind in SURFACES, f"must be one of {', '.join(SURFACES)}")
        check("slope_azimuth_deg", self.slope_azimuth_deg,
              math.isfinite(self.slope_azimuth_deg), "must be finite")
        check("slope_deg", self.slope_deg,
              math.isfinite(self.slope_deg) and 0 <= self.slope_deg < 90, "must be in [0, 90)")
        if self.kind != "slope" and self.slope_deg != 0:
            raise ParameterError("slope_deg", "only applies to --surface slope")
        for name in ("rho_d", "rho_s"):
            v = getattr(self, name)
            check(name, v, math.isfinite(v) and 0 <= v <= 1, "must be in [0, 1]")
        if self.rho_d + self.rho_s > 1:
            raise ParameterError("rho_d", f"rho_d + rho_s must be <= 1 "
                                 f"(got {self.rho_d} + {self.rho_s})")
        check("alpha", self.alpha, math.isfinite(self.alpha) and self.alpha > 0, "must be > 0")
        check("size_m", self.size_m, math.isfinite(self.size_m) and 1 <= self.size_m <= 1e5,
              "must be in [1, 1e5]")
        check("grid_m", self.grid_m, math.isfinite(self.grid_m) and self.grid_m > 0, "must be > 0")
        check("terrain_seed", self.terrain_seed,
              isinstance(self.terrain_seed, (int, np.integer)) and self.terrain_seed >= 0,
              "must be an integer >= 0")
        if self.kind == "fractal":   # the fractal's own checks, without building it
            terrain.check_fractal_parameters(p=self.p, size_m=self.size_m, grid_m=self.grid_m,
                                             relief_m=self.relief_m)
            check("relief_m", self.relief_m, self.relief_m <= 1e4, "must be in [0, 1e4]")
        preset = sea_ice_surface.PRESETS[sea_ice_surface.DEFAULT_PRESET]
        for name, key in (("surface_rms_m", "rms_m"), ("surface_corr_m", "corr_length_m"),
                          ("surface_ridges", "ridges")):
            if self.kind != "sea_ice" and getattr(self, name) != preset[key]:
                raise ParameterError(name, "only applies to --surface sea_ice")
        if self.kind == "sea_ice":
            sea_ice_surface.check_parameters(rms_m=self.surface_rms_m,
                                             corr_length_m=self.surface_corr_m,
                                             size_m=self.size_m, grid_m=self.grid_m,
                                             ridges=self.surface_ridges)

    def bsdf_dict(self) -> dict:
        return ward_bsdf_dict(rho_d=self.rho_d, rho_s=self.rho_s, alpha=self.alpha)

    def build(self) -> Surface:
        """The surface: a :class:`Plane` or a periodic fractal or sea-ice
        :class:`HeightfieldSurface`."""
        if self.kind == "sea_ice":
            return HeightfieldSurface(sea_ice_surface.rough_sea_ice(
                rms_m=self.surface_rms_m, corr_length_m=self.surface_corr_m,
                size_m=self.size_m, grid_m=self.grid_m, seed=self.terrain_seed,
                ridges=self.surface_ridges))
        if self.kind == "fractal":
            return HeightfieldSurface(terrain.fractal(
                p=self.p, size_m=self.size_m, grid_m=self.grid_m, relief_m=self.relief_m,
                seed=self.terrain_seed))
        return Plane(slope_deg=self.slope_deg if self.kind == "slope" else 0.0,
                     azimuth_deg=self.slope_azimuth_deg, size_m=self.size_m)

    def config(self) -> dict:
        """The fields (the ``sea_ice`` ones only for that kind: other runs' records as
        before)."""
        out = dataclasses.asdict(self)
        if self.kind != "sea_ice":
            del out["surface_rms_m"], out["surface_corr_m"], out["surface_ridges"]
        return out


def sea_ice_spec(preset: str, *, ridges: str | None = None, **fields) -> SurfaceSpec:
    """``SurfaceSpec(kind="sea_ice")`` of a published roughness preset
    (:data:`~lidar_mitsuba.ground.sea_ice_surface.PRESETS`: its rms height, correlation length
    and ridge sails; ``ridges`` overrides the preset's); ``fields``: the spec's others
    (``terrain_seed``, ``size_m``)."""
    p = sea_ice_surface.PRESETS[preset]
    return SurfaceSpec(kind="sea_ice", surface_rms_m=p["rms_m"],
                       surface_corr_m=p["corr_length_m"],
                       surface_ridges=p["ridges"] if ridges is None else ridges, **fields)


def resolve(surface) -> tuple[Surface, dict | None, dict]:
    """``(surface, default bsdf, config)`` for what a user passed as a surface: a
    :class:`SurfaceSpec`, a :class:`Surface`, a :class:`~lidar_mitsuba.ground.terrain.Heightfield`
    or ``None`` (the default fractal). The default BSDF is the spec's Ward snow, the paper's
    Ward snow for a ready surface, and ``None`` for a scene (its own BSDFs)."""
    if surface is None:
        surface = SurfaceSpec()
    if isinstance(surface, SurfaceSpec):
        return surface.build(), surface.bsdf_dict(), surface.config()
    if isinstance(surface, Heightfield):
        surface = HeightfieldSurface(surface)
    if not isinstance(surface, Surface):
        raise ParameterError("surface", f"must be a SurfaceSpec, Plane, Heightfield or "
                             f"SceneSurface (got {type(surface).__name__})")
    return surface, (surface.default_bsdf() if surface.takes_bsdf else None), surface.config()
