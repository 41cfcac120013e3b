"""Repeat-orbit ground tracks, the granules' ICESat-2 names, and the tracks that cross a DEM.

**The orbit** (:class:`RepeatOrbit`): a circular orbit of inclination ``i`` (ICESat-2: 92 deg)
that repeats its ground track after ``rgts`` revolutions in ``days`` nodal days (1387 in 91:
the reference ground tracks, RGTs). On a sphere, with ``u`` the argument of latitude (the
angle from the ascending node along the orbit),

    sin(lat) = sin(i) sin(u),    lon = lon_node + atan2(cos(i) sin(u), cos(u)) - q u,

where ``q = days / rgts`` is the Earth's turn (relative to the orbit's node) during one
revolution as a fraction of a revolution: the ground track drifts west by ``q u``. In units of
the orbital angular speed times the Earth's radius the footprint's velocity is

    v_north = sin(i) cos(u) / cos(lat),    v_east = cos(i) / cos(lat) - q cos(lat),

(the inertial part from the conservation of angular momentum, ``cos^2(lat) dlon/du = cos i``,
and the Earth's rotation ``q cos(lat)``), so the heading (clockwise from north) at latitude
``lat`` is, with ``cos(u) = +-sqrt(cos^2(lat) - cos^2(i)) / sin(i)`` (+ ascending, - descending),

    tan(heading) = (cos(i) - q cos^2(lat)) / (+-sqrt(cos^2(lat) - cos^2(i)))

(:meth:`RepeatOrbit.heading_deg`). Without the Earth's rotation (``q = 0``) this is
Clairaut's relation for the great circle, ``sin(heading) = cos(i) / cos(lat)``. ICESat-2 at
70 N heads 352.9 deg ascending and 187.1 deg descending. Consecutive revolutions cross the
equator ``360 q`` deg = 23.6 deg apart, and the 1387 RGTs' ascending nodes fill a grid of
``360 / 1387`` deg (0.26 deg, 28.9 km at the equator, 9.9 km at 70 N): RGT ``k`` has its node at
``node_lon_deg - (k - 1) 360 q`` and passes it ``(k - 1) * period`` after its cycle began; cycle
``c`` begins ``(c - 1) * days`` nodal days after ``cycle1_utc``. A nodal day is the Earth's turn
relative to the orbit's node, which precesses (J2; +0.27 deg/day at 92 deg): 86 228.46 s, so a
cycle is 90.819 days and a revolution (the period) 5 657.38 s.

The sphere's latitudes are used as geodetic ones and the orbit's nodal precession is folded
into ``q``: the geometry (headings, spacing, which tracks cross an area) is right to about a
tenth of a degree of heading, and a track's longitude at a latitude to 0.02 deg at 35 deg (the
sphere's latitude is off the ellipsoid's by up to 0.19 deg; ``tests/test_campaign.py``).

**The phase** is ICESat-2's by default, from what NASA publishes:

- ``node_lon_deg`` = -0.129 deg, RGT 1's ascending node: NASA's reference ground track KML of
  cycle 14 (ICESat-2 technical specifications, https://icesat-2.gsfc.nasa.gov/science/specs;
  tabulated as the ``RGT_cycle_14`` data of the IceSat2R R package, whose "ICESat-2 Mission
  Orbits" vignette prints RGT 1's first points) puts RGT 1 at 0.02796 N, 0.13185 W on
  2021-12-22 07:57:49 UTC, going north; back along the track to the equator, 0.129 W, 0.44 s
  earlier.
- ``nodal_day_s`` = 86 228.46 s and ``cycle1_utc`` = 2018-09-28T16:20:02Z: the time between
  that node passage (RGT 1, cycle 14) and RGT 225's of cycle 1, 2018-10-13T08:20:56Z (the start
  of its granule region 1, the ascending node: ``ANC41_20181013082056_02250101`` in the
  lineage of the real ATL03 granule this package ships, ``lidar_mitsuba/data``), is 13 cycles
  less 224 revolutions: a cycle of 91 nodal days of 86 228.46 s; cycle 1 began with RGT 1's
  node passage 224 revolutions before RGT 225's. The model runs through the KML's points of
  RGT 1 to 0.018 deg of longitude (up to 35 N) and one minute apart to 2.4 s; the granule's
  own name (``ATL03_20181014002445_02350104``: RGT 235, region 4 from 00:24:44.6) and its ATL02
  inputs' (regions 3 and 5) begin within 6 s of when the model enters those regions
  (``tests/test_campaign.py``, with the tolerances the model's simplifications allow).

**Names** (:func:`product_name`): ``ATL03_[yyyymmdd][hhmmss]_[tttt][cc][ss]_[vvv]_[rr].h5`` as
ICESat-2 names its granules: the first shot's UTC time, the RGT (4 digits), the cycle (2), the
granule region (2: :func:`granule_region`, the 14 latitude bands of an orbit), the product
version (3) and revision (2).

**Crossings** (:func:`crossings`): the RGTs (ascending, descending or both) along which every
beam of a granule stays over valid DEM pixels, each as its longest such stretch.
"""
from __future__ import annotations

import datetime as _dt
import math
import re
from dataclasses import dataclass

import numpy as np

from ..constants import check
from ..geotrack import SDP_EPOCH_UTC, Beam, beam_shots, parse_utc

#: ICESat-2's orbit: inclination [deg], reference ground tracks per repeat, repeat [nodal days]
ICESAT2_INCLINATION_DEG = 92.0
ICESAT2_RGTS = 1387
ICESAT2_REPEAT_DAYS = 91
#: ICESat-2's phase and nodal day, from NASA's RGT KML and granule names (module docstring):
#: RGT 1's ascending node [deg], the start of cycle 1 (RGT 1's node passage), a nodal day [s]
ICESAT2_NODE_LON_DEG = -0.129
CYCLE1_UTC = "2018-09-28T16:20:02Z"
ICESAT2_NODAL_DAY_S = 86228.458
EARTH_RADIUS_M = 6371008.8
#: north latitude bounds of the 7 northern granule regions (ATL03's: 0-27, 27-59.5, 59.5-80)
_REGION_LATS = (27.0, 59.5, 80.0)
_SOUTH_LATS = (27.0, 50.0, 79.0)
NAME_PATTERN = re.compile(r"^(ATL\d\d)_(\d{8})(\d{6})_(\d{4})(\d{2})(\d{2})_(\d{3})_(\d{2})\.h5$")


@dataclass(frozen=True)
class RepeatOrbit:
    """A circular repeat orbit (see the module docstring).

    Attributes:
        inclination_deg: orbital inclination [deg] (ICESat-2: 92).
        rgts: revolutions (reference ground tracks) per repeat cycle (1387).
        days: nodal days per repeat cycle (91); 0: a non-rotating Earth (great circles).
        node_lon_deg: longitude of RGT 1's ascending node [deg] (ICESat-2's: -0.129).
        cycle1_utc: start of cycle 1 (ISO 8601 UTC): RGT 1's ascending node passage
            (ICESat-2's: 2018-09-28T16:20:02Z).
        nodal_day_s: a nodal day [s]: the Earth's turn relative to the orbit's precessing
            node (ICESat-2's: 86 228.46 s).
    """
    inclination_deg: float = ICESAT2_INCLINATION_DEG
    rgts: int = ICESAT2_RGTS
    days: float = ICESAT2_REPEAT_DAYS
    node_lon_deg: float = ICESAT2_NODE_LON_DEG
    cycle1_utc: str = CYCLE1_UTC
    nodal_day_s: float = ICESAT2_NODAL_DAY_S

    def __post_init__(self):
        check("inclination_deg", self.inclination_deg, 0 < self.inclination_deg < 180
              and self.inclination_deg != 90, "must be in (0, 180) and not 90 deg")
        check("rgts", self.rgts, isinstance(self.rgts, int) and self.rgts >= 1,
              "must be an integer >= 1")
        check("days", self.days, 0 <= self.days < self.rgts, "must be in [0, rgts)")
        check("nodal_day_s", self.nodal_day_s, math.isfinite(self.nodal_day_s)
              and 8e4 <= self.nodal_day_s <= 9e4, "must be in [80000, 90000] s")
        parse_utc(self.cycle1_utc)

    @property
    def q(self) -> float:
        """The Earth's turn relative to the node per revolution [revolutions]: days / rgts."""
        return float(self.days) / self.rgts

    @property
    def cycle_s(self) -> float:
        """Time of one repeat cycle [s]: ``days`` nodal days."""
        return float(self.days or 1.0) * float(self.nodal_day_s)

    @property
    def period_s(self) -> float:
        """Time of one revolution [s]: a cycle over ``rgts``."""
        return self.cycle_s / self.rgts

    def rgt_node_lon_deg(self, rgt) -> np.ndarray:
        """Longitude [deg] in [-180, 180) of RGT ``rgt``'s ascending node (1-based)."""
        lon = self.node_lon_deg - (np.asarray(rgt, np.float64) - 1) * 360.0 * self.q
        return np.mod(lon + 180.0, 360.0) - 180.0

    def ground_track(self, u_rad, rgt) -> tuple[np.ndarray, np.ndarray]:
        """``(lat_deg, lon_deg)`` of RGT ``rgt`` at arguments of latitude ``u_rad`` [rad]
        (any shape; lon in [-180, 180))."""
        u = np.asarray(u_rad, np.float64)
        i = math.radians(self.inclination_deg)
        lat = np.degrees(np.arcsin(np.clip(math.sin(i) * np.sin(u), -1.0, 1.0)))
        alpha = np.degrees(np.arctan2(math.cos(i) * np.sin(u), np.cos(u)))
        lon = self.rgt_node_lon_deg(rgt) + alpha - self.q * np.degrees(u)
        return lat, np.mod(lon + 180.0, 360.0) - 180.0

    def heading_at_u_deg(self, u_rad) -> np.ndarray:
        """Heading [deg clockwise from north, in [0, 360)] of the footprint at ``u_rad``,
        from its velocity (north and east components, module docstring)."""
        u = np.asarray(u_rad, np.float64)
        i = math.radians(self.inclination_deg)
        cos_lat = np.sqrt(1.0 - (math.sin(i) * np.sin(u)) ** 2)
        v_n = math.sin(i) * np.cos(u) / cos_lat
        v_e = math.cos(i) / cos_lat - self.q * cos_lat
        return np.mod(np.degrees(np.arctan2(v_e, v_n)), 360.0)

    def heading_deg(self, lat_deg, *, ascending: bool) -> np.ndarray:
        """The closed form: heading [deg clockwise from north, in [0, 360)] of the ascending
        (or descending) track at latitude ``lat_deg`` (``|lat|`` below the orbit's highest)."""
        c = np.cos(np.radians(np.asarray(lat_deg, np.float64)))
        ci = math.cos(math.radians(self.inclination_deg))
        north = np.sqrt(np.maximum(c * c - ci * ci, 0.0)) * (1.0 if ascending else -1.0)
        return np.mod(np.degrees(np.arctan2(ci - self.q * c * c, north)), 360.0)

    def cycle_start_s(self, cycle: int) -> float:
        """Start of ``cycle`` [s since the ATLAS SDP epoch 2018-01-01]."""
        t1 = (parse_utc(self.cycle1_utc) - SDP_EPOCH_UTC).total_seconds()
        return t1 + (int(cycle) - 1) * self.cycle_s

    def cycle_of(self, t_s: float) -> int:
        """The cycle (>= 0; 0 before cycle 1) a time [s since the SDP epoch] falls in."""
        t1 = self.cycle_start_s(1)
        return max(0, int(math.floor((t_s - t1) / self.cycle_s)) + 1)

    def time_s(self, rgt: int, cycle: int, u_rad: float) -> float:
        """Time [s since the SDP epoch] RGT ``rgt`` of ``cycle`` is at ``u_rad`` (in [0, 2 pi))."""
        return (self.cycle_start_s(cycle) + (int(rgt) - 1) * self.period_s
                + float(u_rad) / (2.0 * math.pi) * self.period_s)


def utc_text(t_s: float) -> str:
    """ISO 8601 UTC (microseconds) of ``t_s`` [s since the SDP epoch]."""
    t = SDP_EPOCH_UTC + _dt.timedelta(seconds=float(t_s))
    return t.strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def granule_region(lat_deg: float, *, ascending: bool) -> int:
    """ICESat-2's ATL03 granule region (1-14) at ``lat_deg`` going north (``ascending``) or
    south: 1-3 ascending in the north (0-27, 27-59.5, 59.5-80 N), 4 over the north pole
    (above 80 N), 5-7 descending in the north, 8-10 descending in the south (0-27, 27-50,
    50-79 S), 11 over the south pole (beyond 79 S), 12-14 ascending in the south."""
    lat = float(lat_deg)
    if lat >= 0:
        band = int(np.searchsorted(_REGION_LATS, lat, side="right"))     # 0..3
        return 4 if band == 3 else (1 + band if ascending else 7 - band)
    band = int(np.searchsorted(_SOUTH_LATS, -lat, side="right"))
    return 11 if band == 3 else (8 + band if not ascending else 14 - band)


def product_name(product: str, *, t_s: float, rgt: int, cycle: int, region: int,
                 version: int, revision: int) -> str:
    """``ATL03_20190601123456_01230302_006_01.h5``-style file name (module docstring) of a
    granule whose first shot is at ``t_s`` [s since the SDP epoch]."""
    t = SDP_EPOCH_UTC + _dt.timedelta(seconds=float(t_s))
    return (f"{product}_{t:%Y%m%d%H%M%S}_{int(rgt):04d}{int(cycle):02d}{int(region):02d}_"
            f"{int(version):03d}_{int(revision):02d}.h5")


def parse_product_name(name: str) -> dict | None:
    """The fields of an ICESat-2 granule file name (``None`` if it is not one): product,
    date, time, rgt, cycle, region, version, revision."""
    m = NAME_PATTERN.match(name)
    if m is None:
        return None
    keys = ("product", "date", "time", "rgt", "cycle", "region", "version", "revision")
    vals = m.groups()
    return {k: (v if k in ("product", "date", "time") else int(v)) for k, v in zip(keys, vals)}


# --------------------------------------------------------------------------- crossings
@dataclass(frozen=True)
class Crossing:
    """A stretch of an RGT over a DEM along which every beam has valid DEM under it.

    Attributes:
        rgt: the reference ground track (1-based); ascending: its pass.
        u_rad: (n,) arguments of latitude [rad, in [0, 2 pi)] of samples along the stretch.
        lat_deg, lon_deg: (n,) the samples [deg]; along_m: (n,) WGS84 distance [m] from the first.
    """
    rgt: int
    ascending: bool
    u_rad: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    along_m: np.ndarray

    @property
    def length_m(self) -> float:
        return float(self.along_m[-1])


def _u_ranges(orbit: RepeatOrbit, lat_lo: float, lat_hi: float, passes: str):
    """``[(ascending, u0, u1)]`` [rad] of the passes through the latitude band."""
    s = math.sin(math.radians(orbit.inclination_deg))
    lo = math.asin(np.clip(math.sin(math.radians(lat_lo)) / s, -1.0, 1.0))
    hi = math.asin(np.clip(math.sin(math.radians(lat_hi)) / s, -1.0, 1.0))
    if lo >= hi:
        return []
    out = []
    if passes in ("ascending", "both"):
        out.append((True, lo, hi))
    if passes in ("descending", "both"):
        out.append((False, math.pi - hi, math.pi - lo))
    return out


def _dem_latlon_band(dem) -> tuple[float, float]:
    """The latitude range [deg] of the DEM's area (its boundary, densified)."""
    from pyproj import Transformer
    x0, x1, y0, y1 = dem.bounds_m
    t = np.linspace(0.0, 1.0, 101)
    xs = np.concatenate([x0 + (x1 - x0) * t, np.full_like(t, x1), x1 - (x1 - x0) * t,
                         np.full_like(t, x0)])
    ys = np.concatenate([np.full_like(t, y0), y0 + (y1 - y0) * t, np.full_like(t, y1),
                         y1 - (y1 - y0) * t])
    lon, lat = Transformer.from_crs(dem.crs, "EPSG:4326", always_xy=True).transform(xs, ys)
    return float(np.min(lat)), float(np.max(lat))


def _valid_runs(ok: np.ndarray) -> list[tuple[int, int]]:
    """``[(a, b)]`` of the runs of True in ``ok`` (b exclusive)."""
    d = np.diff(np.concatenate([[0], ok.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def crossings(dem, orbit: RepeatOrbit, *, beams: list[Beam], margin_m: float,
              passes: str = "both", min_length_m: float = 1000.0,
              step_m: float = 50.0) -> list[Crossing]:
    """The RGTs crossing ``dem`` (a :class:`~lidar_mitsuba.ground.dem.DEM`), in order of pass
    (ascending first) and RGT: for each, the longest stretch (at least ``min_length_m`` [m])
    along which every one of ``beams`` has valid DEM pixels within ``margin_m`` [m] of its
    footprints (probed every ``step_m`` [m] along the track, at the centre and four points
    ``margin_m`` away)."""
    lat_lo, lat_hi = _dem_latlon_band(dem)
    pad = math.degrees((margin_m + 4000.0) / EARTH_RADIUS_M)
    out = []
    for ascending, u0, u1 in _u_ranges(orbit, lat_lo - pad, lat_hi + pad, passes):
        for rgt in _candidates(dem, orbit, u0, u1):
            c = _crossing(dem, orbit, rgt, ascending, u0, u1, beams=beams, margin_m=margin_m,
                          step_m=step_m)
            if c is not None and c.length_m >= min_length_m:
                out.append(c)
    return out


def _candidates(dem, orbit: RepeatOrbit, u0: float, u1: float) -> list[int]:
    """RGTs whose track over ``[u0, u1]`` (sampled coarsely) comes within ~5 km of the DEM."""
    from pyproj import Transformer
    u = np.linspace(u0, u1, max(8, int((u1 - u0) * EARTH_RADIUS_M / 2000.0) + 2))
    rgts = np.arange(1, orbit.rgts + 1)
    lat, lon = np.broadcast_arrays(*orbit.ground_track(u[None, :], rgts[:, None]))
    x, y = Transformer.from_crs("EPSG:4326", dem.crs, always_xy=True).transform(lon, lat)
    x0, x1, y0, y1 = dem.bounds_m
    reach = 5000.0 + (u[1] - u[0]) * EARTH_RADIUS_M
    near = ((x > x0 - reach) & (x < x1 + reach) & (y > y0 - reach) & (y < y1 + reach))
    return [int(k) for k in rgts[near.any(axis=1)]]


def _crossing(dem, orbit, rgt, ascending, u0, u1, *, beams, margin_m, step_m):
    """The longest valid stretch of one RGT's pass (:func:`crossings`), or ``None``."""
    from pyproj import Geod, Transformer
    from ..ground.dem.heights import heights_at
    u = np.arange(u0, u1, step_m / EARTH_RADIUS_M)
    lat, lon = orbit.ground_track(u, rgt)
    az = orbit.heading_at_u_deg(u)
    to_crs = Transformer.from_crs("EPSG:4326", dem.crs, always_xy=True)
    probes = [(0, 0), (margin_m, 0), (-margin_m, 0), (0, margin_m), (0, -margin_m)]
    ok = np.ones(u.size, bool)
    for beam in beams:
        blat, blon = beam_shots(lat, lon, az, beam)
        x, y = to_crs.transform(blon, blat)
        z = heights_at(dem, np.asarray(x), np.asarray(y), probes, block=256)
        ok &= np.isfinite(z).all(axis=0)
    runs = _valid_runs(ok)
    if not runs:
        return None
    a, b = max(runs, key=lambda r: r[1] - r[0])
    if b - a < 2:
        return None
    lat, lon, u = lat[a:b], lon[a:b], u[a:b]
    _, _, d = Geod(ellps="WGS84").inv(lon[:-1], lat[:-1], lon[1:], lat[1:])
    along = np.concatenate([[0.0], np.cumsum(d)])
    return Crossing(rgt=int(rgt), ascending=bool(ascending), u_rad=np.mod(u, 2.0 * math.pi),
                    lat_deg=lat, lon_deg=lon, along_m=along)


def crossing_polyline(c: Crossing, *, start_m: float, length_m: float,
                      vertex_m: float = 1000.0) -> tuple[tuple[tuple[float, float], ...], float]:
    """A polyline (``((lat, lon), ...)`` [deg]) along ``c`` from its sample at or before
    ``start_m`` [m] covering ``length_m`` [m], with vertices about every ``vertex_m`` [m];
    and the argument of latitude [rad] of its first vertex."""
    i0 = int(np.clip(np.searchsorted(c.along_m, start_m, side="right") - 1, 0, c.along_m.size - 2))
    i1 = int(min(c.along_m.size - 1, np.searchsorted(c.along_m, c.along_m[i0] + length_m) + 1))
    step = max(1, int(round(vertex_m / max(c.along_m[1] - c.along_m[0], 1e-9))))
    idx = list(range(i0, i1, step))
    if idx[-1] != i1:
        idx.append(i1)
    pts = tuple((float(c.lat_deg[k]), float(c.lon_deg[k])) for k in idx)
    return pts, float(c.u_rad[i0])
