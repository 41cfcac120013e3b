"""Surface properties that vary in space: GeoTIFF rasters (snow grain size, density,
roughness relief) read window by window at points given by latitude and longitude, their
binning to the levels a campaign simulates, and a demo raster with a gradient.

A raster is any north-up GeoTIFF in a projected CRS (:class:`~lidar_mitsuba.ground.dem.DEM`
reads it: the same windowed reads as a DEM's heights, one window per block of points, so a
task reads only the window under its own track). Values are bilinear between pixel centres;
nodata and points off the raster are NaN.

**Binning** (:func:`snap`, :func:`section_levels`): each beam's granule section is simulated
with one value of each property, the median of the raster over the section's footprints of
that beam (every :data:`SAMPLE_M` along track) snapped to the nearest of the spec's levels; the
granule's value is the median over every beam's footprints. The snow's subsurface kernel is
tabulated once per (grain, density) pair of levels (:mod:`lidar_mitsuba.ground.snow.kernel`),
not once per granule.
"""
from __future__ import annotations

import math
import os
import pathlib

import numpy as np

from ..constants import ParameterError

#: along-track spacing [m] of the points a granule's property median is taken over
SAMPLE_M = 20.0


class PropertyRaster:
    """A property GeoTIFF sampled at latitudes and longitudes (:meth:`at`).

    Attributes:
        path: the file; dem: its :class:`~lidar_mitsuba.ground.dem.DEM` reader.
    """

    def __init__(self, path: str | os.PathLike):
        from ..ground.dem import DEM
        self.path = pathlib.Path(path)
        self.dem = DEM.open(self.path)          # ParameterError "dem" names what is wrong
        self._to_crs = None

    def at(self, lat_deg, lon_deg, *, block: int = 4096) -> np.ndarray:
        """Bilinear values at ``(lat_deg, lon_deg)`` (any one shape), NaN off the raster or
        over nodata; one window read per ``block`` points (points in a block should be near
        each other, as along a track)."""
        from pyproj import Transformer

        from ..ground.dem.heights import heights_at
        if self._to_crs is None:
            self._to_crs = Transformer.from_crs("EPSG:4326", self.dem.crs, always_xy=True)
        lat = np.asarray(lat_deg, np.float64)
        x, y = self._to_crs.transform(np.asarray(lon_deg, np.float64), lat)
        return heights_at(self.dem, np.asarray(x, np.float64).reshape(lat.shape),
                          np.asarray(y, np.float64).reshape(lat.shape), [(0.0, 0.0)],
                          block)[0]


def snap(value: float, levels) -> float:
    """The level nearest ``value`` (NaN stays NaN)."""
    if not math.isfinite(value):
        return math.nan
    lv = np.asarray(levels, np.float64)
    return float(lv[int(np.argmin(np.abs(lv - value)))])


def track_points(track, beams, *, n_shots: int, spacing_m: float):
    """``(lat, lon, shot)``: latitude and longitude [deg] ((n_beams, n_points)) of every
    beam's footprints of a granule's ``n_shots`` shots, every :data:`SAMPLE_M` along the
    track, and the shot index nearest each point ((n_points,))."""
    from ..geotrack import beam_shots
    n = max(2, int(math.ceil((n_shots - 1) * spacing_m / SAMPLE_M)) + 1)
    step = (n_shots - 1) * spacing_m / (n - 1) if n_shots > 1 else SAMPLE_M
    lat0, lon0, az, _ = track.shots(n, spacing_m=step)
    pts = [beam_shots(lat0, lon0, az, b) for b in beams]
    shot = np.minimum(np.round(np.arange(n) * step / spacing_m).astype(np.int64), n_shots - 1)
    return np.array([p[0] for p in pts]), np.array([p[1] for p in pts]), shot


def section_levels(values: np.ndarray, shot, *, beams, levels, bounds,
                   fallback: float) -> dict[str, list[float]]:
    """Each beam's level of the property per granule section, from the raster's ``values``
    at :func:`track_points` ((n_beams, n_points)) and their ``shot``s (``bounds``: the
    sections' ``(first, stop)`` shots, :func:`lidar_mitsuba.granule.section_bounds`): the
    median over the beam's points in the section, snapped to ``levels``; ``fallback`` (the
    granule's level) where a section has no finite value."""
    sec = np.searchsorted([a for a, _ in bounds], shot, side="right") - 1
    out = {}
    for j, b in enumerate(beams):
        medians = [finite_median(values[j, sec == k]) for k in range(len(bounds))]
        out[b.name] = [snap(m, levels) if math.isfinite(m) else fallback for m in medians]
    return out


def finite_median(values) -> float:
    """The median of the finite ``values`` (NaN when there is none)."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else math.nan


def median_along(raster: PropertyRaster, lat, lon) -> float:
    """The median of the raster's finite values at the points (NaN when there is none)."""
    return finite_median(raster.at(lat, lon))


def gradient_raster(path: str | os.PathLike, *, like: str | os.PathLike, start: float,
                    stop: float, direction_deg: float = 90.0, posting_m: float | None = None,
                    log: bool = False) -> pathlib.Path:
    """Write a GeoTIFF over the DEM ``like`` (its CRS and extent; pixels of ``posting_m``
    [m], default the DEM's) whose value rises linearly (geometrically with ``log``) from
    ``start`` on one edge to ``stop`` on the opposite one, along ``direction_deg`` [deg
    clockwise from the CRS's +y axis: 90 is +x, east in polar stereographic at its central
    meridian]. E.g. snow grain size from 100 um in the west to 1000 um in the east."""
    from ..ground.dem import DEM, write_geotiff
    dem = DEM.open(like)
    g = float(posting_m or dem.posting_m)
    if not (math.isfinite(g) and g > 0):
        raise ParameterError("posting_m", f"must be > 0 (got {posting_m!r})")
    if log and not (start > 0 and stop > 0):
        raise ParameterError("start", "a geometric gradient needs start and stop > 0")
    tr = dem.transform
    x0, y1 = tr.c, tr.f
    w, h = dem.width * tr.a, dem.height * -tr.e
    nx, ny = max(2, int(round(w / g))), max(2, int(round(h / g)))
    x = x0 + (np.arange(nx) + 0.5) * g
    y = y1 - (np.arange(ny) + 0.5) * g
    X, Y = np.meshgrid(x, y)
    d = math.radians(direction_deg)
    s = (X - X.mean()) * math.sin(d) + (Y - Y.mean()) * math.cos(d)
    t = (s - s.min()) / max(s.max() - s.min(), 1e-12)
    z = np.exp(np.log(start) + t * (np.log(stop) - np.log(start))) if log else \
        start + t * (stop - start)
    return write_geotiff(path, z, x0_m=x0, y1_m=y1, posting_m=g, crs=dem.crs.to_string())
