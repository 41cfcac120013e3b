"""Ground tracks on the Earth and ICESat-2's six beams.

A :class:`GeoTrack` is the reference ground track: a start latitude/longitude and azimuth
(a geodesic on the WGS84 ellipsoid), or a polyline of (lat, lon) vertices (e.g. a reference
ground track read from a file, :meth:`GeoTrack.from_file`), with shots every
``shot_spacing_m`` along it and shot times at the instrument's PRF from ``epoch_utc``.

The six beams (:func:`beam_layout`) fly in three pairs about it: pair centres 3.3 km apart
across track (gt1 left of the reference track, gt2 on it, gt3 right, looking along the
direction of travel), the two beams of a pair 90 m apart (``l`` left, ``r`` right). Which
beam of a pair is strong follows the spacecraft orientation, as in ATL03's
``orbit_info/sc_orient``: backward (0): the left beams are strong and gt1l..gt3r are ATLAS
spots 1..6; forward (1): the right beams are strong and gt1l..gt3r are spots 6..1. Spots
1, 3, 5 are strong (four times the energy of spots 2, 4, 6). The beams' along-track stagger
(~2.5 km between the beams of a pair in orbit) is left out: all six fire at each shot time
over the same along-track position.

Times: ``delta_time`` [s] since the ATLAS Standard Data Product epoch, 2018-01-01T00:00:00Z
(GPS seconds 1198800018; no leap second has occurred since, so UTC differences count it).
"""
from __future__ import annotations

import csv
import datetime as _dt
import math
import os
import pathlib
from dataclasses import dataclass

import numpy as np

from .constants import ParameterError, check

#: GPS seconds of the ATLAS SDP epoch 2018-01-01T00:00:00Z (ATL03 ancillary_data)
ATLAS_SDP_GPS_EPOCH = 1198800018.0
SDP_EPOCH_UTC = _dt.datetime(2018, 1, 1, tzinfo=_dt.timezone.utc)
PAIR_SEPARATION_M = 3300.0
BEAM_SEPARATION_M = 90.0


@dataclass(frozen=True)
class Beam:
    """One ATLAS beam.

    Attributes:
        name: ground-track group name (``gt1l`` .. ``gt3r``).
        spot: ATLAS spot number (1-6).
        strength: ``"strong"`` or ``"weak"``.
        across_m: offset from the reference ground track [m], positive to the left.
    """
    name: str
    spot: int
    strength: str
    across_m: float

    @property
    def pce(self) -> int:
        """The photon-counting electronics card of the spot (1: spots 1-2, 2: 3-4, 3: 5-6)."""
        return (self.spot + 1) // 2


def beam_layout(sc_orient: int = 0) -> list[Beam]:
    """The six beams for spacecraft orientation ``sc_orient`` (0 backward, 1 forward)."""
    check("sc_orient", sc_orient, sc_orient in (0, 1), "must be 0 (backward) or 1 (forward)")
    out = []
    for i, pair in enumerate((1, 2, 3)):
        centre = (1 - i) * PAIR_SEPARATION_M
        for j, side in enumerate("lr"):
            k = 2 * i + j                                   # 0..5 left to right
            spot = k + 1 if sc_orient == 0 else 6 - k
            out.append(Beam(name=f"gt{pair}{side}", spot=spot,
                            strength="strong" if spot % 2 else "weak",
                            across_m=centre + (BEAM_SEPARATION_M / 2 if side == "l"
                                               else -BEAM_SEPARATION_M / 2)))
    return out


def select_beams(spec: str, sc_orient: int = 0) -> list[Beam]:
    """Beams by a CLI spec: ``all``, ``strong``, ``weak`` or names (``gt1l,gt2r``)."""
    beams = beam_layout(sc_orient)
    spec = spec.strip().lower()
    if spec == "all":
        return beams
    if spec in ("strong", "weak"):
        return [b for b in beams if b.strength == spec]
    names = [s.strip() for s in spec.split(",") if s.strip()]
    known = {b.name: b for b in beams}
    bad = [n for n in names if n not in known]
    if bad or not names:
        raise ParameterError("beams", f"unknown beam {', '.join(bad) or repr(spec)}: use all, "
                             f"strong, weak or names from {', '.join(known)}")
    return [known[n] for n in dict.fromkeys(names)]


def _geod():
    from pyproj import Geod
    return Geod(ellps="WGS84")


def parse_utc(text: str) -> _dt.datetime:
    """An ISO 8601 UTC time (``2019-06-01T12:00:00Z``); ``ParameterError`` (``epoch``)."""
    try:
        t = _dt.datetime.fromisoformat(str(text).replace("Z", "+00:00"))
    except ValueError:
        raise ParameterError("epoch", f"must be an ISO 8601 UTC time like "
                             f"2019-06-01T12:00:00Z (got {text!r})") from None
    if t.tzinfo is None:
        t = t.replace(tzinfo=_dt.timezone.utc)
    t = t.astimezone(_dt.timezone.utc)
    if t < SDP_EPOCH_UTC:
        raise ParameterError("epoch", f"must be after the ATLAS SDP epoch 2018-01-01 (got {text})")
    return t


@dataclass(frozen=True)
class GeoTrack:
    """A reference ground track on the WGS84 ellipsoid.

    Attributes:
        start_lat_deg, start_lon_deg: the first shot [deg] (with ``azimuth_deg``).
        azimuth_deg: direction of travel at the start [deg], clockwise from north; the track
            follows the geodesic.
        polyline: ``((lat, lon), ...)`` vertices [deg] instead of a start and azimuth; shots
            follow the geodesic segments between them from the first vertex.
        epoch_utc: time of the first shot (ISO 8601 UTC).
    """
    start_lat_deg: float | None = None
    start_lon_deg: float | None = None
    azimuth_deg: float = 0.0
    polyline: tuple[tuple[float, float], ...] | None = None
    epoch_utc: str = "2019-06-01T00:00:00Z"

    def __post_init__(self):
        parse_utc(self.epoch_utc)
        if self.polyline is not None:
            pts = np.asarray(self.polyline, np.float64)
            check("track", "polyline", pts.ndim == 2 and pts.shape[1] == 2 and len(pts) >= 2
                  and np.isfinite(pts).all(), "a polyline needs >= 2 finite (lat, lon) vertices")
            check("track", "polyline", (np.abs(pts[:, 0]) <= 90).all(),
                  "latitudes must be in [-90, 90]")
            object.__setattr__(self, "polyline", tuple(map(tuple, pts.tolist())))
            return
        lat, lon = self.start_lat_deg, self.start_lon_deg
        ok = all(isinstance(v, (int, float)) and math.isfinite(v) for v in (lat, lon))
        check("track", (lat, lon), ok and abs(lat) < 90, "needs a start latitude in (-90, 90) "
              "and a longitude, or a polyline")
        check("azimuth_deg", self.azimuth_deg, math.isfinite(self.azimuth_deg),
              "must be a finite number")

    @classmethod
    def from_file(cls, path: str | os.PathLike, *, epoch_utc: str = "2019-06-01T00:00:00Z"
                  ) -> "GeoTrack":
        """A polyline from a text/CSV file of ``lat, lon`` rows [deg] (comma or whitespace
        separated; a header row and ``#`` comments are skipped)."""
        path = pathlib.Path(path)
        if not path.is_file():
            raise ParameterError("track", f"{path}: no such file")
        rows = []
        for line in path.read_text().splitlines():
            line = line.split("#", 1)[0].strip()
            if not line:
                continue
            fields = next(csv.reader([line])) if "," in line else line.split()
            try:
                lat, lon = (float(v) for v in fields[:2])
            except ValueError:
                if rows:
                    raise ParameterError("track", f"{path}: bad row {line!r} (want lat, lon)") \
                        from None
                continue                                    # a header
            rows.append((lat, lon))
        if len(rows) < 2:
            raise ParameterError("track", f"{path}: needs at least two (lat, lon) rows")
        return cls(polyline=tuple(rows), epoch_utc=epoch_utc)

    @classmethod
    def parse(cls, text: str, *, epoch_utc: str = "2019-06-01T00:00:00Z") -> "GeoTrack":
        """``LAT,LON,AZIMUTH`` [deg] or the path of a polyline file."""
        parts = text.split(",")
        if len(parts) == 3:
            try:
                lat, lon, az = (float(p) for p in parts)
            except ValueError:
                pass
            else:
                return cls(start_lat_deg=lat, start_lon_deg=lon, azimuth_deg=az,
                           epoch_utc=epoch_utc)
        if not pathlib.Path(text).is_file():
            raise ParameterError("track", f"must be LAT,LON,AZIMUTH (degrees) or a file of "
                                 f"lat, lon rows (got {text!r})")
        return cls.from_file(text, epoch_utc=epoch_utc)

    def shots(self, n_shots: int, *, spacing_m: float, first: int = 0
              ) -> tuple[np.ndarray, ...]:
        """``(lat_deg, lon_deg, azimuth_deg, along_m)`` of the reference track's shots
        ``first`` .. ``first + n_shots - 1``, each (n_shots,) float64: positions every
        ``spacing_m`` along the track, the local direction of travel [deg clockwise from
        north] and the distance from the track's first shot [m]."""
        along = (int(first) + np.arange(int(n_shots), dtype=np.float64)) * float(spacing_m)
        if self.polyline is None:
            lat0 = np.full(along.shape, self.start_lat_deg, np.float64)
            lon0 = np.full(along.shape, self.start_lon_deg, np.float64)
            az0 = np.full(along.shape, self.azimuth_deg, np.float64)
            d = along
        else:
            pts = np.asarray(self.polyline, np.float64)
            az_seg, _, seg_len = _geod().inv(pts[:-1, 1], pts[:-1, 0], pts[1:, 1], pts[1:, 0])
            ends = np.concatenate([[0.0], np.cumsum(seg_len)])
            if along.size and along[-1] > ends[-1] + 1e-6:
                raise ParameterError("shots", f"{first + n_shots} shots ({along[-1] / 1e3:.2f} km) run "
                                     f"past the end of the track's polyline "
                                     f"({ends[-1] / 1e3:.2f} km); use fewer shots")
            k = np.clip(np.searchsorted(ends, along, side="right") - 1, 0, len(seg_len) - 1)
            lat0, lon0 = pts[k, 0], pts[k, 1]
            az0, d = np.asarray(az_seg)[k], along - ends[k]
        from .geodesic import direct      # Geod.fwd's bits, one line for a run of shots
        lat, lon, fwd = direct(lat0, lon0, az0, d)
        back = np.where(fwd > 0, fwd - 180.0, fwd + 180.0)  # Geod.fwd's back azimuth, and
        az = np.mod(back + 180.0, 360.0)                    # the forward azimuth at each shot
        return lat, lon, az, along

    def beam_geolocation(self, beam: "Beam", first: int, n_shots: int, *, spacing_m: float,
                         prf_hz: float) -> tuple["Geolocation", np.ndarray]:
        """Shots ``first`` .. ``first + n_shots - 1`` of ``beam``: their
        :class:`Geolocation` (the reference track's shots moved across track to the beam,
        fired at ``prf_hz`` from ``epoch_utc``) and their along-track distance [m]."""
        return self.beams_geolocation([beam], first, n_shots, spacing_m=spacing_m,
                                      prf_hz=prf_hz)[0]

    def beams_geolocation(self, beams: list["Beam"], first: int, n_shots: int, *,
                          spacing_m: float, prf_hz: float
                          ) -> list[tuple["Geolocation", np.ndarray]]:
        """:meth:`beam_geolocation` of each of ``beams`` (the same bits), their positions
        from one geodesic a shot on each side of the track (:func:`beams_shots`)."""
        key = (self, int(n_shots), float(spacing_m), int(first))
        last = _LAST_SHOTS[0]
        if last is not None and last[0][0] is self and last[0][1:] == key[1:]:
            lat0, lon0, az0, along = last[1]       # the beams of one section share them
        else:
            lat0, lon0, az0, along = shots = self.shots(n_shots, spacing_m=spacing_m,
                                                        first=first)
            for a in shots:
                a.setflags(write=False)
            _LAST_SHOTS[0] = (key, shots)
        out = []
        for lat, lon in beams_shots(lat0, lon0, az0, beams):
            times = delta_time_s(self.epoch_utc, n_shots, prf_hz=prf_hz, first=first)
            out.append((Geolocation(lat_deg=np.asarray(lat), lon_deg=np.asarray(lon),
                                    azimuth_deg=np.asarray(az0), delta_time_s=times), along))
        return out

    def beam_shot_count(self, beam: "Beam", shots: int) -> int:
        """Shots of ``beam`` in a granule of ``shots`` shots per beam: ``shots``."""
        return int(shots)

    def start_lat_lon(self, *, spacing_m: float) -> tuple[float, float]:
        """The first shot of the reference track [deg]."""
        lat0, lon0, _, _ = self.shots(1, spacing_m=spacing_m)
        return float(lat0[0]), float(lon0[0])

    def time_span_s(self, shots: int, *, prf_hz: float) -> tuple[float, float]:
        """First and last shot times [s since the SDP epoch] of ``shots`` shots."""
        t0 = float(delta_time_s(self.epoch_utc, 1, prf_hz=prf_hz)[0])
        return t0, t0 + (shots - 1) / prf_hz

    def to_dict(self) -> dict:
        return {"start_lat_deg": self.start_lat_deg, "start_lon_deg": self.start_lon_deg,
                "azimuth_deg": self.azimuth_deg,
                "polyline": None if self.polyline is None else [list(p) for p in self.polyline],
                "epoch_utc": self.epoch_utc}


class SectionPlaces:
    """Where a granule's beams' shots are, a section at a time: ``places(beam, first, n)``
    gives shots ``first`` .. ``first + n - 1`` of ``beam`` as ``(geolocation, along_m, x_m,
    y_m)`` (:meth:`GeoTrack.beam_geolocation`, and ``x_m``, ``y_m`` (n,) in the CRS of the
    pyproj ``to_crs`` transformer from EPSG:4326, longitude first: its bits, compiled for
    the ice sheets' polar stereographic CRSs, :class:`~lidar_mitsuba.polar_stereo.Projector`). On a :class:`GeoTrack`
    the first call of a section places every one of ``beams`` (:meth:`GeoTrack.beams_geolocation`:
    one geodesic a shot each side of the track) and projects them in one call, and the
    section's other beams are kept for their calls (the same bits as one beam at a time:
    every point is its own); other tracks (a real granule's twin) place one beam a call.
    Each shot's place is its own, so a beam asked for out of turn is placed again."""

    def __init__(self, track, to_crs, *, beams: list[Beam] = (), spacing_m: float,
                 prf_hz: float):
        from .polar_stereo import Projector
        self.track, self.to_crs, self.beams = track, to_crs, list(beams)
        self.project = Projector(to_crs)       # (to_crs.transform's bits, compiled)
        self.spacing_m, self.prf_hz = float(spacing_m), float(prf_hz)
        self._last = None

    def __call__(self, beam: Beam, first: int, n: int) -> tuple:
        together = isinstance(self.track, GeoTrack) and beam in self.beams
        beams = self.beams if together else [beam]
        key = (int(first), int(n), tuple(b.name for b in beams))
        if self._last is None or self._last[0] != key:
            self._last = None                          # (the last section's, let go first)
            kw = dict(spacing_m=self.spacing_m, prf_hz=self.prf_hz)
            located = (self.track.beams_geolocation(beams, first, n, **kw) if together
                       else [self.track.beam_geolocation(beam, first, n, **kw)])
            x, y = self.project(np.concatenate([g.lon_deg for g, _ in located]),
                                np.concatenate([g.lat_deg for g, _ in located]))
            x, y = (np.asarray(v, np.float64).reshape(len(beams), -1) for v in (x, y))
            self._last = (key, {b.name: (*located[j], x[j], y[j])
                                for j, b in enumerate(beams)})
        return self._last[1][beam.name]


#: the reference track's shots of the last :meth:`GeoTrack.beam_geolocation` call (read-only):
#: a granule asks for the same shots of each of its six beams in turn
_LAST_SHOTS: list = [None]


def beam_shots(lat_deg, lon_deg, azimuth_deg, beam: Beam) -> tuple[np.ndarray, np.ndarray]:
    """The beam's footprint centres ``(lat, lon)`` [deg]: the reference track's shots moved
    ``beam.across_m`` across track along the geodesic perpendicular to the direction of
    travel (left for positive offsets)."""
    return beams_shots(lat_deg, lon_deg, azimuth_deg, [beam])[0]


def beams_shots(lat_deg, lon_deg, azimuth_deg, beams: list[Beam]
                ) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`beam_shots` of each of ``beams`` (the same bits), the beams left of the track
    on one geodesic a shot and those right of it on another
    (:func:`lidar_mitsuba.geodesic.fan`)."""
    from .geodesic import fan
    out: list = [None] * len(beams)
    for side in (1.0, -1.0):                     # left (positive offsets), then right
        js = [j for j, b in enumerate(beams) if b.across_m * side > 0]
        if js:
            az = np.asarray(azimuth_deg, np.float64) + (-90.0 if side > 0 else 90.0)
            lat, lon = fan(lat_deg, lon_deg, az, [abs(beams[j].across_m) for j in js])
            for r, j in enumerate(js):
                out[j] = (lat[r].reshape(np.shape(az)), lon[r].reshape(np.shape(az)))
    for j, b in enumerate(beams):
        if b.across_m == 0:
            out[j] = (np.asarray(lat_deg, np.float64), np.asarray(lon_deg, np.float64))
    return out


@dataclass(frozen=True)
class Geolocation:
    """Where and when each shot was: its footprint centre on the WGS84 ellipsoid and its
    transmit time. Every array has shape (n_shots,), float64.

    Attributes:
        lat_deg, lon_deg: footprint centre [deg].
        azimuth_deg: direction of travel [deg clockwise from north].
        delta_time_s: transmit time [s since 2018-01-01T00:00:00Z, the ATLAS SDP epoch].
        solar_elevation_deg, solar_azimuth_deg: the sun at the footprint [deg] where known
            (a real granule's, :mod:`lidar_mitsuba.twin`), else ``None`` (computed when needed:
            :func:`lidar_mitsuba.radiometry.solar_angles`).
    """
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    azimuth_deg: np.ndarray
    delta_time_s: np.ndarray
    solar_elevation_deg: np.ndarray | None = None
    solar_azimuth_deg: np.ndarray | None = None

    def select(self, index) -> "Geolocation":
        """The shots at ``index`` (a slice, mask or indices)."""
        return Geolocation(*(None if a is None else np.asarray(a)[index] for a in (
            self.lat_deg, self.lon_deg, self.azimuth_deg, self.delta_time_s,
            self.solar_elevation_deg, self.solar_azimuth_deg)))


#: where and when a built-in surface or XML scene lies by default: the paper's ATM profile in
#: northern Greenland (76 deg 46' 48" N, 66 deg 12' W; Zhang & Kerekes, Fig. 2) at 16:00 UTC on
#: the June solstice, local noon there (the sun 37 deg high)
DEFAULT_SITE = {"lat_deg": 76.78, "lon_deg": -66.2, "epoch_utc": "2019-06-21T16:00:00Z"}


@dataclass(frozen=True)
class Site:
    """Where and when a scene lies on the Earth, for runs on built-in surfaces and Mitsuba
    scenes: its origin (x = y = 0) is at ``lat_deg``, ``lon_deg``, x points east, y north and
    z up from the ellipsoid, and the first shot fires at ``epoch_utc``. Photons then get
    latitudes, longitudes and times, and the sun a position (``--instrument atlas``'s solar
    background).

    Attributes:
        lat_deg, lon_deg: the scene origin [deg] (by default the paper's site in northern
            Greenland).
        epoch_utc: time of the first shot, ISO 8601 UTC (default 2019-06-21T16:00:00Z: local
            noon there, the sun 37 deg high).
        height_m: height of the scene's z = 0 above sea level [m], for the air above the
            surface that attenuates and scatters (``--instrument atlas``); heights in the
            output stay the scene's.
    """
    lat_deg: float = DEFAULT_SITE["lat_deg"]
    lon_deg: float = DEFAULT_SITE["lon_deg"]
    epoch_utc: str = DEFAULT_SITE["epoch_utc"]
    height_m: float = 0.0

    def __post_init__(self):
        check("lat", self.lat_deg, isinstance(self.lat_deg, (int, float))
              and math.isfinite(self.lat_deg) and abs(self.lat_deg) < 90,
              "must be a latitude in (-90, 90) degrees")
        check("lon", self.lon_deg, isinstance(self.lon_deg, (int, float))
              and math.isfinite(self.lon_deg), "must be a finite longitude in degrees")
        parse_utc(self.epoch_utc)
        check("height_m", self.height_m, isinstance(self.height_m, (int, float))
              and -500 <= self.height_m <= 9000, "must be a height in [-500, 9000] m")

    def geolocation(self, x_m: np.ndarray, y_m: np.ndarray, *, prf_hz: float,
                    first: int = 0) -> Geolocation:
        """Shots at scene positions ``x_m``, ``y_m`` [m] ((n_shots,) each), fired at the PRF
        from ``epoch_utc``: latitudes and longitudes through the azimuthal equidistant
        projection centred on the origin (exact distances and bearings from it: a track
        kilometres long keeps its shape to millimetres), and the direction of travel from
        shot to shot (the projection's north at a single shot)."""
        from pyproj import Transformer
        aeqd = (f"+proj=aeqd +lat_0={float(self.lat_deg)!r} +lon_0={float(self.lon_deg)!r} "
                "+x_0=0 +y_0=0 +ellps=WGS84 +units=m")
        to_lonlat = Transformer.from_crs(aeqd, "EPSG:4326", always_xy=True)
        x = np.asarray(x_m, np.float64)
        y = np.asarray(y_m, np.float64)
        lon, lat = (np.asarray(a) for a in to_lonlat.transform(x, y))
        if x.size > 1:
            az, _, _ = _geod().inv(lon[:-1], lat[:-1], lon[1:], lat[1:])
            az = np.mod(np.append(az, az[-1]), 360.0)
        else:
            az = np.zeros(x.size)
        return Geolocation(lat_deg=lat, lon_deg=np.mod(lon + 180.0, 360.0) - 180.0,
                           azimuth_deg=np.asarray(az, np.float64),
                           delta_time_s=delta_time_s(self.epoch_utc, x.size, prf_hz=prf_hz,
                                                     first=first))

    def to_dict(self) -> dict:
        return {"lat_deg": self.lat_deg, "lon_deg": self.lon_deg, "epoch_utc": self.epoch_utc,
                "height_m": self.height_m}


@dataclass(frozen=True)
class ProjectedTrack:
    """Precomputed shot positions in a surface's frame, in the shape
    :func:`~lidar_mitsuba.run.simulate` takes as ``track``.

    Attributes:
        x_m, y_m: (n_shots,) footprint centres in the simulation frame [m].
        along_m: (n_shots,) distance along the track from the first shot [m].
        info: a JSON-serialisable description (recorded in the output).
        geolocation: the shots on the Earth (latitude, longitude, direction, time), or
            ``None`` (then ``simulate`` places them with its ``site``).
    """
    x_m: np.ndarray
    y_m: np.ndarray
    along_m: np.ndarray
    info: dict
    geolocation: Geolocation | None = None

    def positions(self, n_shots: int, *, spacing_m: float, centre_xy_m=None):
        if n_shots != self.x_m.size:
            raise ParameterError("shots", f"the track has {self.x_m.size} shots, not {n_shots}")
        return self.along_m, self.x_m, self.y_m

    def to_dict(self) -> dict:
        return dict(self.info)


def delta_time_s(epoch_utc: str, n_shots: int, *, prf_hz: float, first: int = 0) -> np.ndarray:
    """(n_shots,) transmit time [s] since the ATLAS SDP epoch of shots ``first`` ..
    ``first + n_shots - 1``."""
    t0 = (parse_utc(epoch_utc) - SDP_EPOCH_UTC).total_seconds()
    return t0 + (int(first) + np.arange(int(n_shots), dtype=np.float64)) / float(prf_hz)
