"""A real granule's twin: the shots of a real ICESat-2 file of any product (ATL03, ATL06,
ATL07 or ATL08: its beams, strong or weak, spacecraft orientation, ground tracks, times, sun,
spacecraft altitude and transmitted energy, :mod:`lidar_mitsuba.products.real`), to simulate
them again over a DEM or a built-in surface, open water included (``lidar-mitsuba simulate
--like REAL.h5``) and set real and simulated photons side by side along the same track.

Shots come from the file's segments (ATL03's 20 m geolocation segments, ATL06's land-ice,
ATL07's sea-ice or ATL08's land segments): per beam, runs of segments with no gap
in time longer than ``GAP_S`` are *pieces* (a subset may hold several, e.g. two passes over the
same latitude); in a piece the pulses fire at the PRF from half a segment before the first
segment's reference time to half a segment after the last, and each pulse's footprint centre,
spacecraft altitude and sun (geometric, from the segments' time and place: :func:`model_sun`;
the file's own ``solar_elevation`` is the refracted one) are interpolated in time between the
segments' reference photons (positions through an azimuthal equidistant projection centred on the piece, so the
poles and the antimeridian are no trouble). The along-track distance runs on across pieces
(each piece starts ``PIECE_GAP_M`` after the last), so a track folds into a tile as any other.
"""
from __future__ import annotations

import os
import pathlib
from dataclasses import dataclass

import numpy as np

from .constants import ParameterError
from .geotrack import Beam, Geolocation, _geod, beam_layout

REAL_SUBSET = pathlib.Path(__file__).parent / "data" / "ATL03_gt1l_20181014.h5"
"""A real ATL03 subset shipped with the package: weak beam gt1l over snow-covered Arctic sea
ice at night, 14 Oct 2018 (NASA, doi:10.5067/ATLAS/ATL03.006; ``data/README.md``)."""

GAP_S = 0.1
"""A time step between two geolocation segments longer than this starts a new piece [s]."""
PIECE_GAP_M = 100.0
"""Along-track distance put between two pieces [m] (their shots never share a footprint)."""


def model_sun(lat_deg, lon_deg, delta_time_s) -> tuple[np.ndarray, np.ndarray]:
    """The sun [deg] the model lights a real file's shots with: ``(elevation, azimuth)``,
    **geometric** (no refraction), from the file's own time and place by the NREL SPA
    (:func:`~lidar_mitsuba.radiometry.solar_angles`, every point), as for any other run; the
    sky model adds the refraction itself (:mod:`lidar_mitsuba.sky`).

    Not the file's ``solar_elevation``: its attribute says "the effect of atmospheric
    refraction is not included", but in the real files it is the **apparent** elevation. Above
    the horizon it exceeds SPA's geometric one by Saemundsson's refraction to within 0.003
    deg (Baffin Bay ATL07 at +4.0 deg: +0.187-0.191 deg, refraction 0.187-0.191; Jakobshavn
    ATL06 at +12.1 deg: +0.076, refraction 0.075; the forest ATL03 at +33.5 deg: +0.023,
    0.025; ``tests/test_twin.py``), and below it by 0.21 deg at -1.6 deg (Pine Island), 0.05
    at -7.3, 0.01 at -26 to -41 (another rule there). Taking it as geometric refracted the sun
    twice (+0.19 deg at +4 deg)."""
    from .radiometry import solar_angles
    return solar_angles(lat_deg, lon_deg, delta_time_s, every=1)


def beam_energy_uj(own_strength: str, file_energy_uj: float | None, delta_time_s: float,
                   strength: str | None = None) -> tuple[float, str]:
    """The pulse energy [uJ] of a real beam (``own_strength``) fired as a ``strength`` beam
    (its own by default), and where it comes from: the file's ``tx_pulse_energy`` (scaled by
    ATLAS's strong:weak design ratio for the other strength), else ATLAS's history at
    ``delta_time_s`` (:func:`~lidar_mitsuba.instrument.atlas_pulse_energy_uj`, ESTIMATE)."""
    from .instrument import ATLAS_PULSE_ENERGY_UJ, atlas_pulse_energy_uj
    kind = strength or own_strength
    if file_energy_uj is not None and np.isfinite(file_energy_uj):
        scale = ATLAS_PULSE_ENERGY_UJ[kind] / ATLAS_PULSE_ENERGY_UJ[own_strength]
        return float(file_energy_uj) * scale, "tx_pulse_energy"
    return atlas_pulse_energy_uj(kind, delta_time_s)


@dataclass
class TwinBeam:
    """The shots of one beam of a real granule. Arrays have shape (n_shots,).

    Attributes:
        beam: the beam (name, spot, strength, across-track offset).
        geolocation: each pulse's footprint centre, direction, time and sun.
        along_m: along-track distance from the first pulse [m] (pieces ``PIECE_GAP_M`` apart).
        altitude_m: the spacecraft's height above the ellipsoid [m].
        surface_h_m: the surface height under the pulse [m above the ellipsoid]: the median
            height of the segment's high-confidence photons (NaN where a segment has none).
        pieces: ``[(first, stop), ...]`` pulse ranges with no gap in time.
        pulse_energy_uj: the beam's transmitted energy per pulse [uJ] as the file records it
            (ATL03 ``tx_pulse_energy``, median), or None (ATLAS's history applies).
        surface: what the product says the surface is (``sea ice``, ``land ice``, ...).
    """
    beam: Beam
    geolocation: Geolocation
    along_m: np.ndarray
    altitude_m: np.ndarray
    surface_h_m: np.ndarray
    pieces: list[tuple[int, int]]
    pulse_energy_uj: float | None = None
    surface: str = "unknown"

    def energy_uj(self, strength: str | None = None) -> tuple[float, str]:
        """The pulse energy [uJ] to fire this beam's shots with as a ``strength`` beam (its
        own by default) and where it comes from (:func:`beam_energy_uj`)."""
        return beam_energy_uj(self.beam.strength, self.pulse_energy_uj,
                              float(np.median(self.geolocation.delta_time_s)), strength)

    @property
    def n_shots(self) -> int:
        return int(self.along_m.size)


@dataclass
class TwinGranule:
    """The beams of a real ICESat-2 file, ready to simulate again (:func:`read`)."""
    path: pathlib.Path
    sc_orient: int
    beams: list[TwinBeam]
    prf_hz: float
    product: str = "ATL03"
    missing: list[str] | None = None

    def missing_line(self) -> str:
        """What the file lacks that the twin would use, in one line."""
        if not self.missing:
            return f"{self.path.name} ({self.product}): nothing missing"
        return f"{self.path.name} ({self.product}) lacks: " + "; ".join(self.missing)

    # the reference-track interface of lidar_mitsuba.granule (as GeoTrack's)
    def beam_geolocation(self, beam: Beam, first: int, n_shots: int, *, spacing_m: float = 0.7,
                         prf_hz: float = 10e3) -> tuple[Geolocation, np.ndarray]:
        """Shots ``first`` .. ``first + n_shots - 1`` of ``beam`` as the real file has them
        (``spacing_m`` and ``prf_hz`` are the file's own)."""
        b = self.beam(beam.name)
        sl = slice(int(first), int(first) + int(n_shots))
        return b.geolocation.select(sl), b.along_m[sl]

    def beam_shot_count(self, beam: Beam, shots: int | None = None) -> int:
        """The beam's pulses in the file (``shots``, if given, caps them)."""
        n = self.beam(beam.name).n_shots
        return n if shots is None else min(n, int(shots))

    def start_lat_lon(self, *, spacing_m: float = 0.7) -> tuple[float, float]:
        g = self.beams[0].geolocation
        return float(g.lat_deg[0]), float(g.lon_deg[0])

    def time_span_s(self, shots: int | None = None, *, prf_hz: float = 10e3
                    ) -> tuple[float, float]:
        t = np.concatenate([b.geolocation.delta_time_s for b in self.beams])
        return float(t.min()), float(t.max())

    def select_beams(self, spec: str) -> list[Beam]:
        """The file's beams by a CLI spec (``all``, ``strong``, ``weak`` or names)."""
        from .geotrack import select_beams
        wanted = {b.name for b in select_beams(spec, self.sc_orient)}
        out = [b.beam for b in self.beams if b.beam.name in wanted]
        if not out:
            raise ParameterError("beams", f"{spec!r}: {self.path.name} has "
                                 f"{', '.join(b.beam.name for b in self.beams)}")
        return out

    @property
    def epoch_utc(self) -> str:
        from .products.atl03.file import utc
        return utc(self.time_span_s()[0]).decode()

    def median_range_m(self) -> float:
        """The spacecraft's median height above the surface under it [m] (above the
        ellipsoid where no surface was found)."""
        r = np.concatenate([b.altitude_m - np.nan_to_num(b.surface_h_m) for b in self.beams])
        return float(np.nanmedian(r))

    def median_surface_height_m(self) -> float:
        """The median height of the surface under the shots [m above the ellipsoid] (0 when
        the file has no confident photon)."""
        h = np.concatenate([b.surface_h_m for b in self.beams])
        return float(np.nanmedian(h)) if np.isfinite(h).any() else 0.0

    def median_altitude_m(self) -> float:
        """The spacecraft's median height above the ellipsoid [m]."""
        return float(np.nanmedian(np.concatenate([b.altitude_m for b in self.beams])))

    def to_dict(self) -> dict:
        return {"like": str(self.path), "product": self.product, "sc_orient": self.sc_orient,
                "beams": {b.beam.name: b.n_shots for b in self.beams},
                "missing": list(self.missing or [])}

    def beam(self, name: str) -> TwinBeam:
        for b in self.beams:
            if b.beam.name == name:
                return b
        raise ParameterError("beams", f"{self.path.name} has no beam {name} (it has "
                             f"{', '.join(b.beam.name for b in self.beams)})")


def sea_ice_surface(*, lat_deg: float, size_m: float | None = None):
    """``(surface, reason)``: the surface a twin of sea ice at ``lat_deg`` [deg] is simulated
    over, the one place ``validate``'s sea-ice twin and the realism matrix's sea-ice rows take
    it from: rough sea ice of the published preset the site's ice gets
    (:func:`~lidar_mitsuba.ground.sea_ice_surface.site_preset`: the central Arctic pack's
    Fram Strait roughness with ridge sails; ``SurfaceSpec(kind="sea_ice")`` on a ``size_m``
    tile, the default 1024 m without), or ``None`` (flat snow) for other sea ice, with the
    reason either way. Chosen by the ice's age and region, nothing from the file's photons."""
    from .ground.sea_ice_surface import site_preset
    from .ground.surface import sea_ice_spec
    preset, why = site_preset(lat_deg=float(lat_deg))
    if preset is None:
        return None, why
    return sea_ice_spec(preset, **({} if size_m is None else {"size_m": float(size_m)})), why


def read(path: str | os.PathLike, *, beams: str = "all", prf_hz: float = 10e3) -> TwinGranule:
    """The shots of the beams of a real ICESat-2 file (ATL03, ATL06, ATL07 or ATL08, any
    release; ``beams``: ``all``, ``strong``, ``weak`` or names) from its segments
    (:func:`lidar_mitsuba.products.real.read_product`): strong or weak from each beam
    group's ``atlas_beam_type``, the pulse energy from ATL03's ``tx_pulse_energy`` (else
    ATLAS's energy history), the surface from the product's heights. What the file lacks is
    in ``missing`` (one line: :meth:`TwinGranule.missing_line`). Raises ``ParameterError``
    (``like``) for a file it cannot read."""
    from .products.real import read_product
    real = read_product(path, beams=beams)
    out = [b for b in (_beam(rb, prf_hz) for rb in real.beams) if b is not None]
    if not out:
        raise ParameterError("like", f"{real.path}: no beam with two segments in a row"
                             + ("" if beams == "all" else f" among {beams!r}"))
    orient = real.sc_orient if real.sc_orient in (0, 1) else 0
    return TwinGranule(path=real.path, sc_orient=orient, beams=out, prf_hz=float(prf_hz),
                       product=real.product, missing=list(real.missing))


def _beam(rb, prf_hz: float) -> TwinBeam | None:
    """One beam's pulses from its segments (a :class:`~lidar_mitsuba.products.real.RealBeam`;
    None when no two segments are in a row). Segments without a place are dropped; a
    product without the spacecraft's altitude puts it at ATLAS's nominal range above the
    surface."""
    from .constants import ALTITUDE_M
    ok = np.isfinite(rb.delta_time_s) & np.isfinite(rb.lat_deg) & np.isfinite(rb.lon_deg)
    order = np.flatnonzero(ok)[np.argsort(rb.delta_time_s[ok], kind="stable")]
    order = order[np.r_[True, np.diff(rb.delta_time_s[order]) > 0]]   # one segment a time
    t_seg = rb.delta_time_s[order]
    if t_seg.size < 2:
        return None
    lat_seg, lon_seg = rb.lat_deg[order], rb.lon_deg[order]
    h_seg = rb.surface_h_m[order]
    alt_seg = (rb.altitude_m[order] if rb.altitude_m is not None
               else ALTITUDE_M + np.nan_to_num(h_seg, nan=float(np.nanmedian(h_seg))
                                               if np.isfinite(h_seg).any() else 0.0))
    sun = list(model_sun(lat_seg, lon_seg, t_seg))
    cuts = np.flatnonzero(np.diff(t_seg) > GAP_S) + 1
    bounds = list(zip(np.r_[0, cuts], np.r_[cuts, t_seg.size]))
    parts, pieces, along0 = [], [], 0.0
    n = 0
    for a, b in bounds:
        if b - a < 2:                         # a lone segment: no direction to interpolate
            continue
        part = _piece(t_seg[a:b], lat_seg[a:b], lon_seg[a:b], alt_seg[a:b], h_seg[a:b],
                      [None if s is None else s[a:b] for s in sun], prf_hz)
        part["along_m"] = part["along_m"] + along0
        along0 = float(part["along_m"][-1]) + PIECE_GAP_M
        pieces.append((n, n + part["t"].size))
        n += part["t"].size
        parts.append(part)
    if not parts:
        return None
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0] if parts[0][k] is not None}
    geoloc = Geolocation(lat_deg=cat["lat"], lon_deg=cat["lon"], azimuth_deg=cat["az"],
                         delta_time_s=cat["t"], solar_elevation_deg=cat.get("sun_el"),
                         solar_azimuth_deg=cat.get("sun_az"))
    across = {b.name: b.across_m for b in beam_layout(0)}[rb.name]
    energy = (float(np.nanmedian(rb.pulse_energy_uj)) if rb.pulse_energy_uj is not None
              else None)
    return TwinBeam(beam=Beam(name=rb.name, spot=rb.spot, strength=rb.strength,
                              across_m=across),
                    geolocation=geoloc, along_m=cat["along_m"], altitude_m=cat["alt"],
                    surface_h_m=cat["h"], pieces=pieces, pulse_energy_uj=energy,
                    surface=rb.surface)


def _piece(t, lat, lon, alt, h, sun, prf_hz: float) -> dict:
    """The pulses of one gap-free run of segments, interpolated in time between the
    segments' reference points (extrapolated half a segment beyond the ends)."""
    from pyproj import Transformer
    half = 0.5 * float(np.median(np.diff(t)))
    times = np.arange(t[0] - half, t[-1] + half, 1.0 / prf_hz)
    aeqd = (f"+proj=aeqd +lat_0={float(lat[0])!r} +lon_0={float(lon[0])!r} +ellps=WGS84 "
            "+units=m")
    fwd = Transformer.from_crs("EPSG:4326", aeqd, always_xy=True)
    x_seg, y_seg = fwd.transform(lon, lat)

    def interp(v):                    # linear in time, extrapolated along the end slopes
        v = np.asarray(v, np.float64)
        out = np.interp(times, t, v)
        lo, hi = times < t[0], times > t[-1]
        out[lo] = v[0] + (times[lo] - t[0]) * (v[1] - v[0]) / (t[1] - t[0])
        out[hi] = v[-1] + (times[hi] - t[-1]) * (v[-1] - v[-2]) / (t[-1] - t[-2])
        return out

    x, y = interp(x_seg), interp(y_seg)
    lon_p, lat_p = Transformer.from_crs(aeqd, "EPSG:4326", always_xy=True).transform(x, y)
    lon_p, lat_p = np.asarray(lon_p), np.asarray(lat_p)
    az, _, step = _geod().inv(lon_p[:-1], lat_p[:-1], lon_p[1:], lat_p[1:])
    az = np.mod(np.append(az, az[-1]), 360.0)
    along = np.concatenate([[0.0], np.cumsum(step)])
    h_p = np.interp(times, t[np.isfinite(h)], h[np.isfinite(h)]) if np.isfinite(h).any() \
        else np.full(times.size, np.nan)
    out = {"t": times, "lat": lat_p, "lon": np.mod(lon_p + 180.0, 360.0) - 180.0, "az": az,
           "along_m": along, "alt": interp(alt), "h": h_p,
           "sun_el": None if sun[0] is None else interp(sun[0]), "sun_az": None}
    if sun[1] is not None:
        rad = np.deg2rad(sun[1])
        out["sun_az"] = np.mod(np.rad2deg(np.arctan2(interp(np.sin(rad)),
                                                     interp(np.cos(rad)))), 360.0)
    return out


def simulate_over_surface(twin: TwinGranule, *, surface=None, beams: str = "all",
                          shots: int | None = None, instrument: str = "atlas",
                          instrument_options: dict | None = None, seed: int = 0,
                          progress: bool = True, strength: str | None = None,
                          water_wind_mps: float | None = None, **simulate_options):
    """The twin of ``twin`` over a built-in surface (a
    :class:`~lidar_mitsuba.ground.surface.SurfaceSpec`; default: the flat Ward snow), in memory: each
    beam's pulses are placed in a frame centred on the granule's first pulse (an azimuthal
    equidistant projection, x east, y north) at the real latitudes, longitudes, times and sun,
    the surface's z = 0 under them and the spacecraft at the real range to the surface (the
    granule's median ``altitude_sc - surface height``). Returns a
    :class:`~lidar_mitsuba.products.record.Granule` (``granule.write_atl03`` writes it).

    Args:
        beams: ``all``, ``strong``, ``weak`` or names among the file's beams.
        shots: at most this many pulses of each beam (``None``: all).
        instrument: ``atlas`` (default) or ``paper``; ``instrument_options``: fields.
        strength: fire every beam's shots as a ``"strong"`` or ``"weak"`` beam instead of its
            own (``None``): e.g. the strong:weak ratio on the same shots.
        water_wind_mps: open water (ocean, leads) instead of the surface's Ward snow: the
            ``water`` BSDF (:func:`~lidar_mitsuba.ground.water.water_bsdf`) roughened by
            this wind speed [m/s] (Cox & Munk), on the (flat by default) surface.
        seed, progress, simulate_options: as :func:`~lidar_mitsuba.run.simulate`.

    With ATLAS (``instrument="atlas"``) each beam fires the energy its file recorded
    (:meth:`TwinBeam.energy_uj`) unless ``instrument_options`` sets ``pulse_energy_uj``.
    """
    from pyproj import Transformer
    from .geotrack import GeoTrack, ProjectedTrack, Site
    from .granule import _beam_seed
    from .products.record import BeamRun, Granule
    from .instrument import Instrument
    from .run import simulate
    from .ground.surface import SurfaceSpec
    lat0, lon0 = twin.start_lat_lon()
    aeqd = (f"+proj=aeqd +lat_0={lat0!r} +lon_0={lon0!r} +x_0=0 +y_0=0 +ellps=WGS84 "
            "+units=m")
    to_xy = Transformer.from_crs("EPSG:4326", aeqd, always_xy=True)
    opts = {"altitude_m": twin.median_range_m(), **(instrument_options or {})}
    site = Site(height_m=float(np.clip(twin.median_surface_height_m(), -500, 9000)))
    if water_wind_mps is not None:
        from .ground.water import water_bsdf
        if "bsdf" in simulate_options:
            raise ParameterError("water_wind_mps", "give a bsdf or open water, not both")
        try:
            simulate_options["bsdf"] = water_bsdf(wind_speed_mps=water_wind_mps)
        except ValueError as e:
            raise ParameterError("water_wind_mps", str(e)) from None
    runs = []
    for beam in twin.select_beams(beams):
        n = twin.beam_shot_count(beam, shots)
        geo, along = twin.beam_geolocation(beam, 0, n)
        x, y = (np.asarray(a) for a in to_xy.transform(geo.lon_deg, geo.lat_deg))
        track = ProjectedTrack(x_m=x, y_m=y, along_m=along, geolocation=geo,
                               info={"like": str(twin.path), "beam": beam.name})
        kind = strength or beam.strength
        beam_opts = dict(opts)
        if instrument == "atlas" and "pulse_energy_uj" not in beam_opts:
            beam_opts["pulse_energy_uj"] = twin.beam(beam.name).energy_uj(kind)[0]
        inst = (Instrument.atlas(kind, **beam_opts) if instrument == "atlas"
                else Instrument(beam=kind, **beam_opts))
        try:
            res = simulate(instrument=inst, surface=surface or SurfaceSpec(kind="flat"),
                           track=track, shots=n, seed=_beam_seed(seed, beam), site=site,
                           progress=progress, **simulate_options)
        except ParameterError as e:
            raise ParameterError(e.name, f"{beam.name}: {e.message}") from None
        runs.append(BeamRun(beam=beam, result=res))
    first = runs[0]
    ref = GeoTrack(start_lat_deg=float(first.lat_deg[0]), start_lon_deg=float(first.lon_deg[0]),
                   azimuth_deg=float(first.azimuth_deg[0]), epoch_utc=twin.epoch_utc)
    return Granule(beams=runs, sc_orient=twin.sc_orient, crs=aeqd, frame_origin_m=(0.0, 0.0),
                   track=ref, config={"like": twin.to_dict(), "instrument": instrument,
                                      "instrument_options": opts, "seed": int(seed),
                                      "water_wind_mps": water_wind_mps,
                                      "sc_orient": twin.sc_orient,
                                      "beams": [r.beam.name for r in runs]})
