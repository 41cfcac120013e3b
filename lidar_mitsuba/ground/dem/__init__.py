"""Real terrain: a GeoTIFF DEM (any projected CRS, metres), optionally with fractal roughness
below its posting, traced in corridor tiles that stream along the track.

A :class:`DEMSurface` never meshes the whole DEM. For every chunk of shots it reads the
DEM window under that chunk's corridor (rasterio windowed reads), meshes a grid aligned with
the chunk's chord (so a diagonal or curved track costs no more than a straight one), in a
local frame whose origin is the chunk's first shot (float32 holds millimetres there; the
origin is added back in float64 on the device), traces it, and drops it. Memory is that of
one tile whatever the track's length.

Heights are the DEM's bilinear interpolation (plus the roughness tile's, when given), in
the DEM's vertical datum (ellipsoid heights for ArcticDEM / REMA). Nodata cells are NaN:
a track whose footprints or corridor touch one is refused (``ParameterError`` naming
``track``), never traced over a hole.

Roughness (:func:`roughness`): the paper's fractal (1/f^p, eqs. 2-4) synthesised on a
periodic tile, with every wavelength longer than the DEM's posting removed (the DEM already
holds those), scaled to ``relief_m`` (max - min of what is left).

Where the code is: :class:`DEM` reads the file window by window (:meth:`DEM.windows`: one
window per block of points); :mod:`lidar_mitsuba.ground.dem.heights` turns windows into heights at
points (bilinear look-ups, the closed-form footprint mean of the reference elevation);
:mod:`lidar_mitsuba.ground.dem.tiles` meshes a chunk's corridor (the DEM's own pixels, or a grid
along the chord); :class:`DEMSurface` puts them behind the :class:`~lidar_mitsuba.ground.surface.
Surface` interface.
"""
from __future__ import annotations

import math
import os
import pathlib
import threading
import dataclasses
from dataclasses import dataclass

import numpy as np

from . import tiles
from .. import terrain
from .heights import finite_at, footprint_mean, heights_at
from ...constants import ParameterError, check
from ...machine import check_memory
from ..surface import ChunkTiles, Surface
from ..terrain import Heightfield

#: most shots per corridor tile (about 2.9 km at 0.7 m): bounds a tile's mesh
TILE_SHOTS = 4096
MESH_TOLERANCE_M = 1e-3
"""Largest height error [m] of the pixel mesh (:meth:`DEMSurface.pixel_tile`) against the
DEM's bilinear surface."""


def _rasterio():
    import rasterio          # imported when a DEM is used: the rest of the package needs no GDAL
    return rasterio


_OPEN = threading.local()
_OPEN_MAX = 8


def _open_for_reading(path):
    """A rasterio dataset of ``path`` kept open for window reads (opening a GeoTIFF costs ~2 ms,
    and a track reads a window per tile and per block of points). Per thread (datasets are
    not shared between threads) and process, one per file version (path, modification time,
    size); at most :data:`_OPEN_MAX` per thread."""
    st = os.stat(path)
    key = (str(path), st.st_mtime_ns, st.st_size, os.getpid())
    cache = getattr(_OPEN, "datasets", None)
    if cache is None:
        cache = _OPEN.datasets = {}
    ds = cache.get(key)
    if ds is None or ds.closed:
        if len(cache) >= _OPEN_MAX:
            for old in cache.values():
                old.close()
            cache.clear()
        ds = cache[key] = _rasterio().open(path)
    return ds


#: a DEM of at most this many bytes (as float64) is read whole, once per process, and its
#: windows are sliced from memory (a 100 km x 10 km DEM at 100 m is 0.8 MB; a granule reads
#: ~860 windows, each ~0.1-0.4 ms of rasterio and masked-array work)
WHOLE_DEM_MAX_BYTES = 64 * 2 ** 20
_WHOLE: dict = {}
_WHOLE_MAX = 2                  # DEMs held (a campaign's worker moves from DEM to DEM)
_WHOLE_LOCK = threading.Lock()


def _whole_band(path, width: int, height: int):
    """The whole first band of ``path`` as float64 [m], nodata and non-finite values NaN
    (what :meth:`DEM.read_window` makes of a window), read once per file version and
    process; ``None`` when it is larger than :data:`WHOLE_DEM_MAX_BYTES`."""
    if 8.0 * width * height > WHOLE_DEM_MAX_BYTES:
        return None
    st = os.stat(path)
    key = (str(path), st.st_mtime_ns, st.st_size, os.getpid())
    with _WHOLE_LOCK:
        z = _WHOLE.get(key)
        if z is None:
            ds = _open_for_reading(path)
            z = np.ma.filled(ds.read(1, masked=True).astype(np.float64), np.nan)
            z[~np.isfinite(z)] = np.nan
            z.setflags(write=False)
            while len(_WHOLE) >= _WHOLE_MAX:
                _WHOLE.pop(next(iter(_WHOLE)))
            _WHOLE[key] = z
    return z


def _slice_padded_south_up(z: np.ndarray, row0: int, row1: int, col0: int, col1: int
                           ) -> np.ndarray:
    """Rows ``row0 .. row1`` and columns ``col0 .. col1`` (inclusive) of ``z`` turned over
    (row ``k`` is row ``row1 - k`` of ``z``), contiguous, NaN where they fall off it (as a
    boundless read fills them)."""
    out = np.full((row1 - row0 + 1, col1 - col0 + 1), np.nan)
    r0, r1 = max(row0, 0), min(row1, z.shape[0] - 1)
    c0, c1 = max(col0, 0), min(col1, z.shape[1] - 1)
    if r0 <= r1 and c0 <= c1:
        out[row1 - r1:row1 - r0 + 1, c0 - col0:c1 - col0 + 1] = z[r0:r1 + 1, c0:c1 + 1][::-1]
    return out


@dataclass(frozen=True, eq=False)
class DEM:
    """A north-up GeoTIFF DEM, read window by window.

    Attributes:
        path: the file.
        crs: its coordinate reference system (a projected CRS in metres).
        transform: affine pixel -> CRS transform (north-up: no rotation).
        width, height: size in pixels.
        nodata: the nodata value (or None).
    """
    path: pathlib.Path
    crs: object
    transform: object
    width: int
    height: int
    nodata: float | None

    @classmethod
    def open(cls, path: str | os.PathLike) -> "DEM":
        """Open a GeoTIFF. ``ParameterError`` (named ``dem``) for a missing or unreadable file,
        a geographic or rotated grid, or no CRS."""
        rio = _rasterio()
        path = pathlib.Path(path)
        if not path.is_file():
            raise ParameterError("dem", f"{path}: no such file")
        try:
            with rio.open(path) as ds:
                crs, tr, w, h, nodata, count = (ds.crs, ds.transform, ds.width, ds.height,
                                                ds.nodata, ds.count)
        except rio.errors.RasterioError as e:
            raise ParameterError("dem", f"{path}: not a raster GDAL can read ({e})") from None
        if crs is None:
            raise ParameterError("dem", f"{path}: has no CRS (write one, e.g. EPSG:3413)")
        if not crs.is_projected:
            raise ParameterError("dem", f"{path}: CRS {crs.to_string()} is not projected; "
                                 "reproject the DEM to a metric CRS (e.g. polar stereographic)")
        if tr.b != 0 or tr.d != 0 or tr.a <= 0 or tr.e >= 0:
            raise ParameterError("dem", f"{path}: the grid is rotated or not north-up; "
                                 "warp it north-up first (gdalwarp)")
        if abs(abs(tr.a) - abs(tr.e)) > 1e-6 * abs(tr.a):
            raise ParameterError("dem", f"{path}: pixels are not square ({tr.a:g} x {-tr.e:g} m)")
        if count < 1 or w < 2 or h < 2:
            raise ParameterError("dem", f"{path}: needs one band of at least 2 x 2 pixels")
        return cls(path=path, crs=crs, transform=tr, width=int(w), height=int(h),
                   nodata=None if nodata is None else float(nodata))

    @property
    def posting_m(self) -> float:
        """Pixel size [m]."""
        return float(self.transform.a)

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        """``(x0, x1, y0, y1)`` [m] of the pixel centres (where bilinear look-ups are defined)."""
        tr = self.transform
        x0 = tr.c + 0.5 * tr.a
        y1 = tr.f + 0.5 * tr.e
        return x0, x0 + (self.width - 1) * tr.a, y1 + (self.height - 1) * tr.e, y1

    def read_window(self, x0: float, x1: float, y0: float, y1: float
                    ) -> tuple[np.ndarray, tuple[float, float]]:
        """The pixels covering ``[x0, x1] x [y0, y1]`` [m] (plus one on every side):
        ``(z, (ox, oy))``, ``z`` (ny, nx) float64 [m] with rows running south to north and
        ``z[0, 0]`` the pixel centred at (ox, oy); nodata and pixels off the DEM are NaN."""
        return self._window(_whole_band(self.path, self.width, self.height), x0, x1, y0, y1)

    def _window(self, whole, x0: float, x1: float, y0: float, y1: float):
        """:meth:`read_window` from ``whole`` (:func:`_whole_band`: the DEM in memory, or
        ``None``: read from the file)."""
        tr, g = self.transform, self.posting_m
        col0 = math.floor((x0 - tr.c) / g - 0.5) - 1
        col1 = math.ceil((x1 - tr.c) / g - 0.5) + 1
        row0 = math.floor((tr.f - y1) / g - 0.5) - 1
        row1 = math.ceil((tr.f - y0) / g - 0.5) + 1
        check_memory("dem", 8.0 * (col1 - col0 + 1) * (row1 - row0 + 1),
                     f"a DEM window of {col1 - col0 + 1} x {row1 - row0 + 1} pixels",
                     "use a shorter track chunk")
        origin = (tr.c + (col0 + 0.5) * g, tr.f - (row1 + 0.5) * g)
        if whole is not None:          # (the file's rows run north to south: turned over)
            return _slice_padded_south_up(whole, row0, row1, col0, col1), origin
        rio = _rasterio()
        win = rio.windows.Window(col0, row0, col1 - col0 + 1, row1 - row0 + 1)
        inside = col0 >= 0 and row0 >= 0 and col1 < self.width and row1 < self.height
        ds = _open_for_reading(self.path)       # (boundless reads go through a slow VRT)
        z = ds.read(1, window=win, boundless=not inside, masked=True,
                    fill_value=self.nodata if self.nodata is not None else np.nan)
        z = np.ma.filled(z.astype(np.float64), np.nan)
        z[~np.isfinite(z)] = np.nan
        return np.ascontiguousarray(z[::-1]), origin

    def windows(self, x: np.ndarray, y: np.ndarray, *, pad_m: float, block: int):
        """Yield ``(slice, z, origin)`` over consecutive blocks of ``block`` points (``x``,
        ``y``: (n,) CRS [m]), each block's window (:meth:`read_window`, ``pad_m`` [m] beyond
        its finite points) read once (points along a track are local in blocks); ``z`` is
        None for a block without a finite point. The blocks' extents come from one compiled
        pass (:func:`~lidar_mitsuba.ground.dem.heights.block_extents`: numpy's minima and
        maxima of each block's finite points, the same numbers)."""
        from .heights import block_extents
        x = np.ascontiguousarray(x, np.float64)
        y = np.ascontiguousarray(y, np.float64)
        found, x_lo, x_hi, y_lo, y_hi = block_extents(x, y, int(block))
        whole = _whole_band(self.path, self.width, self.height)
        for k, a in enumerate(range(0, x.size, block)):
            s = slice(a, min(x.size, a + block))
            if not found[k]:
                yield s, None, None
                continue
            z, origin = self._window(whole, x_lo[k] - pad_m, x_hi[k] + pad_m,
                                     y_lo[k] - pad_m, y_hi[k] + pad_m)
            yield s, z, origin


def roughness(*, p: float, relief_m: float, posting_m: float, grid_m: float = 1.0,
              size_m: float = 1024.0, seed: int = 0) -> Heightfield:
    """Fractal roughness for a DEM of ``posting_m``: the paper's 1/f^p surface on a periodic
    ``size_m`` tile at ``grid_m`` [m], with every spatial frequency below ``1 / posting_m``
    removed (the DEM holds those scales), scaled to ``relief_m`` (max - min) [m]."""
    check("roughness_relief_m", relief_m, math.isfinite(relief_m) and 0 < relief_m <= 100,
          "must be in (0, 100]")
    check("mesh_grid_m", grid_m, math.isfinite(grid_m) and 0 < grid_m < posting_m,
          f"must be finer than the DEM posting ({posting_m:g} m) for roughness below it")
    hf = terrain.fractal(p=p, size_m=size_m, grid_m=grid_m, relief_m=1.0, seed=seed)
    spec = np.fft.fft2(hf.z_m)
    fy = np.fft.fftfreq(hf.ny, d=grid_m)[:, None]
    fx = np.fft.fftfreq(hf.nx, d=grid_m)[None, :]
    spec[np.hypot(fx, fy) < 1.0 / posting_m] = 0.0
    z = np.fft.ifft2(spec).real
    z *= relief_m / (z.max() - z.min())
    return Heightfield(z_m=z, grid_m=float(grid_m), periodic=True)


@dataclass(frozen=True, eq=False)
class DEMSurface(Surface):
    """A DEM (plus optional periodic ``roughness``) traced in corridor tiles.

    Attributes:
        dem: the :class:`DEM`.
        roughness: a periodic heightfield added to the DEM (:func:`roughness`), or None.
        mesh_grid_m: spacing of the corridor mesh [m], a grid along the track; ``None`` (the
            default): the roughness grid when there is roughness, else the DEM's own pixels
            (:meth:`pixel_tile`: exact at every pixel centre, each pixel split until its
            triangles are within :data:`MESH_TOLERANCE_M` of the bilinear surface).
        tile_shots: most shots per corridor tile.
        origin_m: the DEM CRS coordinates (x, y) [m] of the simulation frame's origin: every
            position this surface takes or gives is ``CRS - origin_m``, so float32 scattering
            points keep millimetres near a track whose CRS coordinates are ~1e6 m.
    """
    dem: DEM
    roughness: Heightfield | None = None
    mesh_grid_m: float | None = None
    tile_shots: int = TILE_SHOTS
    origin_m: tuple[float, float] = (0.0, 0.0)


    def __post_init__(self):
        if self.mesh_grid_m is not None:
            check("mesh_grid_m", self.mesh_grid_m,
                  math.isfinite(self.mesh_grid_m) and 0.05 <= self.mesh_grid_m <= 1e3,
                  "must be in [0.05, 1000] m")
        if self.roughness is not None and (
                self.mesh_grid_m is None
                or not math.isclose(self.roughness.grid_m, self.mesh_grid_m)):
            object.__setattr__(self, "mesh_grid_m", float(self.roughness.grid_m))

    def with_origin(self, origin_m: tuple[float, float]) -> "DEMSurface":
        """This surface in the frame whose origin is ``origin_m`` (CRS [m])."""
        return dataclasses.replace(self, origin_m=(float(origin_m[0]), float(origin_m[1])))

    # ---------------------------------------------------------------- heights
    def _crs(self, x_m, y_m) -> tuple[np.ndarray, np.ndarray]:
        """The DEM CRS coordinates [m] of frame positions, broadcast to one shape (float64)."""
        return np.broadcast_arrays(np.asarray(x_m, np.float64) + self.origin_m[0],
                                   np.asarray(y_m, np.float64) + self.origin_m[1])

    def _dem_at(self, x_m, y_m, offsets_m, block: int | None = None) -> np.ndarray:
        """DEM heights [m] at every point shifted by each ``(dx, dy)`` of ``offsets_m``
        (:func:`lidar_mitsuba.ground.dem.heights.heights_at`): shape ``(len(offsets_m),) +
        broadcast shape``; NaN over nodata or off the DEM."""
        return heights_at(self.dem, *self._crs(x_m, y_m), offsets_m, block or self.tile_shots)

    def height_m(self, x_m, y_m, *, block: int | None = None) -> np.ndarray:
        """DEM (+ roughness) height at each point [m]; NaN over nodata or off the DEM.
        ``block``: points per DEM window read (default ``tile_shots``; points in a block
        should be near each other)."""
        z = self._dem_at(x_m, y_m, [(0.0, 0.0)], block=block)[0]
        if self.roughness is not None:
            z = z + self.roughness.height_m(x_m, y_m)
        return z

    def reference_elevation_m(self, x_m, y_m, *, sigma_m: float) -> np.ndarray:
        """Gaussian-footprint-weighted mean height [m], exactly: the DEM part in closed form
        (:func:`lidar_mitsuba.ground.dem.heights.footprint_mean`), the roughness part by its exact
        Gaussian filter (:meth:`Heightfield.reference_elevation_m`)."""
        z = footprint_mean(self.dem, *self._crs(x_m, y_m), sigma_m=float(sigma_m),
                           block=self.tile_shots)
        if self.roughness is not None:
            z = z + self.roughness.reference_elevation_m(x_m, y_m, sigma_m=sigma_m)
        return z

    # ---------------------------------------------------------------- the Surface API
    def centre_xy_m(self):
        x0, x1, y0, y1 = self.dem.bounds_m
        return 0.5 * (x0 + x1) - self.origin_m[0], 0.5 * (y0 + y1) - self.origin_m[1]

    def fold(self, x_m, y_m, *, margin_m: float):
        """No folding: every shot sees its own terrain. Refuses (``track``) shots whose
        footprint (``margin_m`` about the centre, probed at the centre and four points on
        that circle) is off the DEM or over nodata."""
        x = np.asarray(x_m, np.float64)
        y = np.asarray(y_m, np.float64)
        probes = [(0, 0), (margin_m, 0), (-margin_m, 0), (0, margin_m), (0, -margin_m)]
        bad = ~finite_at(self.dem, *self._crs(x, y), probes, self.tile_shots)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ParameterError(
                "track", f"{int(bad.sum())} of the {x.size} shots have their footprint "
                f"({margin_m:g} m about the centre) off the DEM or over nodata, the first at "
                f"x {x.flat[i] + self.origin_m[0]:.1f} m, y {y.flat[i] + self.origin_m[1]:.1f} m "
                f"({self.dem.crs.to_string()}); "
                f"move or shorten the track, or fill the DEM")
        zero = np.zeros(x.shape)
        return x, y, zero

    def tiles(self, x_m, y_m, *, x_local_m, y_local_m, dz_m, reach_m: float, bsdf,
              crop: bool, chunk_shots: int) -> "CorridorTiles":
        """A corridor tile per chunk of at most :attr:`tile_shots` shots
        (:class:`CorridorTiles`): the DEM is never one scene."""
        return CorridorTiles(self, x_m, y_m, reach_m=reach_m, bsdf=bsdf,
                             chunk_shots=min(int(chunk_shots), self.tile_shots))

    def corridor_tile(self, x_m: np.ndarray, y_m: np.ndarray, *, reach_m: float,
                      bsdf, mesh: tuple | None = None):
        """Mesh the corridor of one chunk's shots and load it (``bsdf``: the ground's BSDF,
        loaded or its dict, or a snow volume: :func:`~lidar_mitsuba.trace.scene.scene_from_mesh`;
        ``mesh``: :meth:`corridor_mesh` of the same shots, made already).
        Returns ``(scene, origin_xy_m, triangles)``; the shots trace at ``(x - ox, y - oy)``.
        """
        vertices, faces, origin = (self.corridor_mesh(x_m, y_m, reach_m=reach_m)
                                   if mesh is None else mesh)
        from ...trace import scene as scn
        return scn.scene_from_mesh(vertices, faces, bsdf=bsdf), origin, int(len(faces))

    def corridor_mesh(self, x_m: np.ndarray, y_m: np.ndarray, *, reach_m: float) -> tuple:
        """The corridor mesh of one chunk's shots, numpy alone (any thread): ``(vertices,
        faces, (ox, oy))``, relative to the first shot (ox, oy).

        With ``mesh_grid_m`` the grid is aligned with the chord from the first to the last
        shot and covers every shot ``reach_m`` [m] about it
        (:func:`lidar_mitsuba.ground.dem.tiles.grid_tile`); without it the mesh is the DEM's own
        pixels (:meth:`pixel_tile`)."""
        if self.mesh_grid_m is None:
            return self.pixel_tile(x_m, y_m, reach_m=reach_m)
        return tiles.grid_tile(
            np.asarray(x_m, np.float64), np.asarray(y_m, np.float64), reach_m=reach_m,
            grid_m=self.mesh_grid_m, height_m=self.height_m, dem=self.dem,
            origin_m=self.origin_m)

    def pixel_tile(self, x_m: np.ndarray, y_m: np.ndarray, *, reach_m: float
                   ) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
        """The corridor mesh on the DEM's own pixels (no roughness), each cell split until
        within :data:`MESH_TOLERANCE_M` of the bilinear surface
        (:func:`lidar_mitsuba.ground.dem.tiles.pixel_tile`): ``(vertices, faces, (ox, oy))``,
        (n, 3) [m] relative to the first shot ``(ox, oy)`` (heights absolute), (m, 3)
        triangles with normals up."""
        return tiles.pixel_tile(self.dem, np.asarray(x_m, np.float64),
                                np.asarray(y_m, np.float64), reach_m=reach_m,
                                origin_m=self.origin_m, tolerance_m=MESH_TOLERANCE_M)

    def mitsuba_scene(self, *, bsdf, margin_m, bounds_m):
        raise ParameterError("surface", "a DEM is traced in corridor tiles along a track "
                             "(simulate() does this); it has no single scene")

    def config(self) -> dict:
        out = {"kind": "dem", "dem_file": str(self.dem.path), "crs": self.dem.crs.to_string(),
               "posting_m": self.dem.posting_m, "mesh_grid_m": self.mesh_grid_m,
               "tile_shots": int(self.tile_shots), "frame_origin_m": list(self.origin_m)}
        if self.roughness is not None:
            out["roughness"] = {"relief_m": self.roughness.relief_m,
                                "grid_m": self.roughness.grid_m,
                                "size_m": self.roughness.size_x_m}
        return out

    def notes(self, *, instrument, max_depth, crop, triangles) -> list[str]:
        mesh = (f"at {self.mesh_grid_m:g} m" if self.mesh_grid_m is not None else
                f"on its own pixels (split to {1e3 * MESH_TOLERANCE_M:g} mm of its bilinear "
                f"surface)")
        out = [f"DEM {self.dem.path.name} ({self.dem.crs.to_string()}, {self.dem.posting_m:g} m "
               f"posting) meshed in corridor tiles of <= {self.tile_shots} shots {mesh}, "
               f"streamed along the track (first tile: {triangles} triangles); every shot sees "
               f"its own terrain"]
        if self.roughness is not None:
            out.append(f"fractal roughness below the {self.dem.posting_m:g} m posting added "
                       f"({self.roughness.relief_m:g} m relief)")
        return out

    def warnings(self, *, instrument) -> list[str]:
        if self.mesh_grid_m is None or self.mesh_grid_m <= instrument.footprint_sigma_m / 2:
            return []
        return [f"the corridor mesh spacing ({self.mesh_grid_m:g} m) is coarser than half the "
                f"footprint sigma ({instrument.footprint_sigma_m:g} m)"]


class CorridorTiles(ChunkTiles):
    """A DEM's tiling: every chunk of shots traces its own corridor tile
    (:meth:`DEMSurface.corridor_tile`), meshed when the chunk is launched and dropped with
    its trace, so memory is one or two tiles for any track
    (:class:`~lidar_mitsuba.ground.tiling.ChunkTiles`)."""

    def __init__(self, surface: DEMSurface, x_m, y_m, *, reach_m: float, bsdf,
                 chunk_shots: int):
        self.surface, self._loaded_bsdf = surface, None
        super().__init__(x_m, y_m, reach_m=reach_m, bsdf=bsdf, chunk_shots=chunk_shots)

    def _tile_bsdf(self):
        """The ground's BSDF for a tile's mesh: a BSDF dict loaded once for every tile of the
        tiling (loading it per tile made a plugin per tile, ~0.2 ms: the same parameters, so
        the same photons); anything else (a snow volume, a loaded BSDF) as given."""
        if not isinstance(self.bsdf, dict):
            return self.bsdf
        if self._loaded_bsdf is None:
            from ...trace.variant import ensure_renderer
            self._loaded_bsdf = ensure_renderer().load_dict(self.bsdf)
        return self._loaded_bsdf

    def prepare(self, a: int, b: int) -> tuple:
        """The corridor mesh of shots ``a`` .. ``b - 1`` (:meth:`DEMSurface.corridor_mesh`:
        numpy alone, so a granule's stream makes the next one on its own thread while the
        trace launcher traces, and the launcher only loads it), for :meth:`tile`."""
        return self.surface.corridor_mesh(self.x_m[a:b], self.y_m[a:b], reach_m=self.reach_m)

    def _build(self, a: int, b: int, prepared: tuple | None = None):
        x, y = self.x_m[a:b], self.y_m[a:b]
        scene, (ox, oy), triangles = self.surface.corridor_tile(x, y, reach_m=self.reach_m,
                                                                bsdf=self._tile_bsdf(),
                                                                mesh=prepared)
        n = b - a
        return (scene, x - ox, y - oy, (np.full(n, ox), np.full(n, oy), np.zeros(n)),
                triangles)


def write_geotiff(path: str | os.PathLike, z_m: np.ndarray, *, x0_m: float, y1_m: float,
                  posting_m: float, crs: str, nodata: float = -9999.0) -> pathlib.Path:
    """Write a north-up float32 GeoTIFF: ``z_m`` (rows north to south) [m], the upper-left
    pixel corner at (``x0_m``, ``y1_m``), square pixels of ``posting_m``; NaN -> ``nodata``."""
    rio = _rasterio()
    from rasterio.transform import from_origin
    z = np.where(np.isfinite(z_m), z_m, nodata).astype(np.float32)
    with rio.open(path, "w", driver="GTiff", height=z.shape[0], width=z.shape[1], count=1,
                  dtype="float32", crs=crs, transform=from_origin(x0_m, y1_m, posting_m,
                                                                  posting_m),
                  nodata=nodata, compress="deflate", tiled=True) as ds:
        ds.write(z, 1)
    return pathlib.Path(path)


def synthetic_ice_sheet(path: str | os.PathLike, *, lat_deg: float = 70.0,
                        lon_deg: float = -45.0, width_m: float = 12000.0,
                        length_m: float = 12000.0, posting_m: float = 20.0, seed: int = 0,
                        hole: bool = True) -> pathlib.Path:
    """A test DEM like a slice of the Greenland ice sheet, in NSIDC polar stereographic north
    (EPSG:3413), centred on (``lat_deg``, ``lon_deg``): a surface at ~2000 m sloping 0.5 %
    toward the coast, with 1/f^2 undulations of 40 m relief at kilometre scales, and (``hole``)
    a 1 x 1 km nodata square in its south-west corner. The track along the meridian
    ``lon_deg`` = -45 is a straight line (x = const) in this projection."""
    from pyproj import Transformer
    cx, cy = Transformer.from_crs("EPSG:4326", "EPSG:3413", always_xy=True).transform(
        lon_deg, lat_deg)
    nx = int(round(width_m / posting_m)) + 1
    ny = int(round(length_m / posting_m)) + 1
    n = min(1 << max(nx, ny).bit_length(), 2048)     # a longer DEM repeats the undulations
    und = terrain.fractal(p=2.0, size_m=n * posting_m, grid_m=posting_m, relief_m=40.0,
                          seed=seed).z_m[np.ix_(np.arange(ny) % n, np.arange(nx) % n)]
    x = cx - width_m / 2 + np.arange(nx) * posting_m
    y = cy + length_m / 2 - np.arange(ny) * posting_m          # rows north to south
    X, Y = np.meshgrid(x, y)
    r = np.hypot(X, Y)                                          # distance from the pole
    z = 2000.0 - 0.005 * (r - np.hypot(cx, cy)) + und
    if hole:
        z[-int(1000 / posting_m):, :int(1000 / posting_m)] = np.nan
    return write_geotiff(path, z, x0_m=x[0] - posting_m / 2, y1_m=y[0] + posting_m / 2,
                         posting_m=posting_m, crs="EPSG:3413")
