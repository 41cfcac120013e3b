"""A granule: up to six ICESat-2 beams along a real ground track over a GeoTIFF DEM, written
as ATL03 and ATL06 files with the field names, dtypes, units and attributes that ICESat-2
readers use.

>>> from lidar_mitsuba import dem, geotrack, granule
>>> g = granule.simulate_granule(surface=dem.DEMSurface(dem.DEM.open("dem.tif")),
...                              track=geotrack.GeoTrack(start_lat_deg=69.95, start_lon_deg=-45,
...                                                      azimuth_deg=0), shots=2000)  # doctest: +SKIP
>>> granule.write_atl03(g, "ATL03_sim.h5"); granule.write_atl06(g, "ATL06_sim.h5")  # doctest: +SKIP

**ATL03** (``write_atl03``), per beam group ``gtXx``:

* ``heights/``: one row per detected photon, in shot order: ``lat_ph``, ``lon_ph`` [deg]
  (the footprint centre of the photon's shot: the beam points at nadir), ``h_ph`` [m, float32]
  above the DEM's vertical datum, ``delta_time`` [s since 2018-01-01], ``dist_ph_along``
  [m from the start of its 20 m geolocation segment], ``dist_ph_across`` [m, 0: the beam's own
  track], ``signal_conf_ph`` (n, 5) int8, ``quality_ph`` int8 (0 nominal), ``ph_id_count``
  (1-based index of the event in its channel and pulse), ``ph_id_channel`` (strong 1-16, weak
  17-20), ``ph_id_pulse`` (1-200 within the 50 Hz major frame), ``pce_mframe_cnt``;
* ``geolocation/``: one row per 20 m along-track segment from the track's start:
  ``segment_id`` (1, 2, ...), ``segment_ph_cnt``, ``ph_index_beg`` (1-based, 0 when empty),
  ``segment_dist_x`` [m from the first shot, not the equator], ``segment_length``,
  ``reference_photon_lat/lon`` [deg] and ``delta_time`` of the shot nearest the segment's
  centre, ``reference_photon_index``, ``ref_azimuth``, ``ref_elev`` [rad], ``sigma_h``,
  ``surf_type``;
* ``bckgrd_atlas/``: ``bckgrd_rate`` [Hz] (the modelled solar background reaching the
  detector, every 50 shots) and ``delta_time``; ``geophys_corr/``: zeros for tides and
  atmosphere (a simulation has none) and ``dem_h``, the DEM under each segment;
* ``ancillary_data/`` (``atlas_sdp_gps_epoch``, start/end times, ``calibrations/dead_time``
  per channel, ``tep``), ``atlas_impulse_response/`` (the modelled transmit pulse shape),
  ``orbit_info/sc_orient``; beam attributes ``atlas_beam_type``, ``atlas_spot_number``,
  ``atlas_pce``, ``groundtrack_id``, ``sc_orientation``.
* ``/truth/gtXx/{photons,shots}``: the simulation truth as :mod:`lidar_mitsuba.atl03` writes
  it for one beam, plus ``/truth`` attributes ``crs`` and ``frame_origin_m``: truth
  positions are in the DEM's CRS less that origin.

**ATL06** (``write_atl06``): ``gtXx/land_ice_segments/{h_li, h_li_sigma, latitude,
longitude, delta_time, segment_id, atl06_quality_summary, sigma_geo_h}`` and the subgroups
``fit_statistics``, ``bias_correction``, ``geophysical``, ``ground_track``, ``dem``, from
:func:`lidar_mitsuba.atl06.segments_from_result` (40 m segments every 20 m).
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import pathlib
from dataclasses import dataclass, field, replace

import numpy as np

from . import __version__, atl03, atl06, geotrack, h5chunks
from .atl03 import _ds, atomic_h5file
from .constants import FWHM_PER_SIGMA, ParameterError, check
from .dem import DEMSurface
from .geotrack import Beam, GeoTrack
from .instrument import INSTRUMENT_PRESETS, Instrument

SEGMENT_M = 20.0            #: ATL03 geolocation segment length [m]
PULSES_PER_MAJOR_FRAME = 200
BCKGRD_SHOTS = 50           #: shots per ATL03 bckgrd_atlas row (200 Hz at 10 kHz)


@dataclass
class BeamRun:
    """One beam of a granule.

    Attributes:
        beam: the :class:`~lidar_mitsuba.geotrack.Beam`.
        result: its :class:`~lidar_mitsuba.simulate.SimulationResult` (positions in the
            granule's frame).
        lat_deg, lon_deg: (n_shots,) footprint centres [deg].
        azimuth_deg: (n_shots,) direction of travel [deg clockwise from north].
        delta_time_s: (n_shots,) transmit times [s since 2018-01-01T00:00:00Z].
        first_shot: index of the result's first shot in the whole track (a streamed granule
            is simulated and written in sections; :func:`simulate_granule`: 0).
    """
    beam: Beam
    result: object
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    azimuth_deg: np.ndarray
    delta_time_s: np.ndarray
    first_shot: int = 0


@dataclass
class Granule:
    """Beams simulated along one reference ground track over one DEM.

    Attributes:
        beams: the :class:`BeamRun` of each beam simulated.
        sc_orient: spacecraft orientation (0 backward, 1 forward).
        crs: the DEM's CRS; frame_origin_m: its (x, y) [m] at the simulation frame's origin.
        track: the reference ground track.
        config: the run's settings.
    """
    beams: list[BeamRun]
    sc_orient: int
    crs: str
    frame_origin_m: tuple[float, float]
    track: GeoTrack
    config: dict = field(default_factory=dict)


def simulate_granule(*, surface: DEMSurface, track: GeoTrack, shots: int,
                     beams: str | list[Beam] = "all", sc_orient: int = 0,
                     instrument_options: dict | None = None, instrument: str = "paper",
                     seed: int = 0, paths_per_shot: int | str = "auto",
                     max_depth: int | str = "auto", progress: bool = True,
                     **simulate_options) -> Granule:
    """Simulate ``shots`` shots of each of ``beams`` along ``track`` over a DEM.

    Args:
        surface: the DEM surface (its ``origin_m`` is set here, near the track's start).
        track: the reference ground track (:class:`~lidar_mitsuba.geotrack.GeoTrack`), or a
            real granule's shots (:class:`~lidar_mitsuba.twin.TwinGranule`: its twin).
        shots: shots per beam (a twin: at most that many of each beam's, ``None``: all).
        beams: ``"all"``, ``"strong"``, ``"weak"``, names (``"gt1l,gt2l"``) or a list of beams.
        sc_orient: 0 backward (left beams strong), 1 forward.
        instrument_options: :class:`~lidar_mitsuba.instrument.Instrument` fields shared by the
            beams (``beam`` is set per beam: strong beams carry four times the weak ones' energy).
        instrument: ``"paper"`` (Zhang & Kerekes' instrument, ``Instrument(**options)``) or
            ``"atlas"`` (ATLAS as flown, ``Instrument.atlas(beam, **options)``: signal and
            background from its link budget).
        seed: the granule's seed; each beam runs with its own stream.
        paths_per_shot, max_depth, progress, simulate_options: as
            :func:`~lidar_mitsuba.simulate.simulate`.
    """
    if isinstance(beams, str):
        beams = geotrack.select_beams(beams, sc_orient)
    ctx = _Context(surface, track, instrument_options, instrument)
    runs = [ctx.beam_run(beam, 0, track.beam_shot_count(beam, shots),
                         seed=_beam_seed(seed, beam), progress=progress,
                         paths_per_shot=paths_per_shot, max_depth=max_depth, **simulate_options)
            for beam in _beam_bar(beams, progress)]
    return Granule(beams=runs, sc_orient=int(sc_orient), crs=ctx.surface.dem.crs.to_string(),
                   frame_origin_m=ctx.origin, track=track,
                   config=ctx.config(shots=shots, seed=seed, sc_orient=sc_orient, beams=beams))


def _beam_seed(seed: int, beam: Beam, section: int | None = None) -> int:
    key = [int(seed), beam.spot] + ([] if section is None else [int(section)])
    return int(np.random.SeedSequence(key).generate_state(1)[0])


class _Context:
    """What every beam and section of a granule shares: the surface in a frame near the
    track's start, the CRS transform, the instrument options."""

    def __init__(self, surface: DEMSurface, track: GeoTrack, instrument_options: dict | None,
                 preset: str = "paper"):
        from pyproj import Transformer
        self.opts = dict(instrument_options or {})
        if "beam" in self.opts:
            raise ParameterError("beam", "is set per beam in a granule (use beams=)")
        check("instrument", preset, preset in INSTRUMENT_PRESETS,
              f"must be one of {', '.join(INSTRUMENT_PRESETS)}")
        self.preset = preset
        self.base = self.instrument(None)
        self.track = track
        self.to_crs = Transformer.from_crs("EPSG:4326", surface.dem.crs, always_xy=True)
        lat0, lon0 = track.start_lat_lon(spacing_m=self.base.shot_spacing_m)
        x0, y0 = self.to_crs.transform(lon0, lat0)
        self.origin = (float(np.round(x0, -3)), float(np.round(y0, -3)))
        self.surface = replace(surface, origin_m=self.origin)

    def instrument(self, beam: Beam | None) -> Instrument:
        """The instrument of ``beam`` (``None``: a strong beam, for what all beams share)."""
        strength = "strong" if beam is None else beam.strength
        if self.preset == "atlas":
            return Instrument.atlas(strength, **self.opts)
        return Instrument(**self.opts, beam=strength)

    def beam_run(self, beam: Beam, first: int, n: int, *, seed: int, **simulate_kw) -> BeamRun:
        """Simulate shots ``first`` .. ``first + n - 1`` of ``beam``."""
        from .simulate import simulate
        geo, along = self.track.beam_geolocation(beam, first, n,
                                                 spacing_m=self.base.shot_spacing_m,
                                                 prf_hz=self.base.prf_hz)
        x, y = self.to_crs.transform(geo.lon_deg, geo.lat_deg)
        if not (np.isfinite(x).all() and np.isfinite(y).all()):
            raise ParameterError("track", f"{beam.name}: the track leaves the DEM's projection "
                                 f"({self.surface.dem.crs.to_string()})")
        ptrack = geotrack.ProjectedTrack(
            x_m=np.asarray(x) - self.origin[0], y_m=np.asarray(y) - self.origin[1],
            along_m=along, info={"reference_track": self.track.to_dict(), "beam": beam.name,
                                 "across_m": beam.across_m, "first_shot": int(first)},
            geolocation=geo)
        try:
            res = simulate(instrument=self.instrument(beam), surface=self.surface, track=ptrack,
                           shots=n, seed=seed, **{"keep_returns": False, **simulate_kw})
        except ParameterError as e:
            raise ParameterError(e.name, f"{beam.name}: {e.message}") from None
        return BeamRun(beam=beam, result=res, lat_deg=geo.lat_deg, lon_deg=geo.lon_deg,
                       azimuth_deg=geo.azimuth_deg, delta_time_s=geo.delta_time_s,
                       first_shot=int(first))

    def config(self, *, shots, seed, sc_orient, beams, **extra) -> dict:
        return {"shots": int(shots), "seed": int(seed), "sc_orient": int(sc_orient),
                "beams": [b.name for b in beams], "track": self.track.to_dict(),
                "surface": self.surface.config(), "instrument": self.preset,
                "instrument_options": self.opts, **extra}


def _beam_bar(beams, progress):
    if not progress or len(beams) < 2:
        return beams
    from tqdm.auto import tqdm
    return tqdm(beams, desc="beams", unit="beam", leave=False)


# --------------------------------------------------------------------------- ATL03
def _utc(delta_time_s: float) -> bytes:
    t = geotrack.SDP_EPOCH_UTC + _dt.timedelta(seconds=float(delta_time_s))
    return t.strftime("%Y-%m-%dT%H:%M:%S.%fZ").encode()


def _gps_week_sow(delta_time_s: float) -> tuple[int, float]:
    gps = geotrack.ATLAS_SDP_GPS_EPOCH + float(delta_time_s)
    return int(gps // 604800), gps % 604800


def _put(group, name, data, units, description):
    """Create a resizable, compressed dataset, or append ``data`` to it along axis 0 (a
    streamed granule writes each section's rows after the last); whole chunks are compressed
    on every core (:mod:`lidar_mitsuba.h5chunks`)."""
    return h5chunks.put(group, name, data, units, description, append=True)


def _photon_order(res) -> np.ndarray:
    """Photon order by shot (stable), so every segment's photons are contiguous."""
    return np.argsort(res.detections.shot, kind="stable")


def _ph_id_count(shot: np.ndarray, channel: np.ndarray) -> np.ndarray:
    """1-based index of each event among the events of its shot and channel, in order."""
    n = shot.size
    if n == 0:
        return np.zeros(0, np.int8)
    key = shot.astype(np.int64) * 64 + channel.astype(np.int64)
    order = np.argsort(key, kind="stable")
    k = key[order]
    start = np.r_[True, k[1:] != k[:-1]]
    run_start = np.maximum.accumulate(np.where(start, np.arange(n), 0))
    out = np.empty(n, np.int64)
    out[order] = np.arange(n) - run_start + 1
    return np.minimum(out, 127).astype(np.int8)


def _segments(along_m: np.ndarray, photon_shot: np.ndarray):
    """The 20 m segments ``k0 .. k0 + n - 1`` the shots fall in (``along_m`` (n_shots,) from
    the track's first shot): each shot's segment, the index of each segment's first photon
    and its photon count (photons sorted by shot, ``photon_shot`` local), the shot nearest
    each segment's centre, and ``k0``."""
    seg_of_shot = np.floor(along_m / SEGMENT_M).astype(np.int64)
    k0 = int(seg_of_shot[0]) if along_m.size else 0
    n_seg = int(seg_of_shot[-1]) - k0 + 1 if along_m.size else 0
    count = np.bincount(seg_of_shot[photon_shot] - k0, minlength=n_seg)
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    centre = (k0 + np.arange(n_seg) + 0.5) * SEGMENT_M
    ref_shot = np.clip(np.searchsorted(along_m, centre), 0, along_m.size - 1)
    prev = np.maximum(ref_shot - 1, 0)
    closer = np.abs(along_m[prev] - centre) < np.abs(along_m[ref_shot] - centre)
    ref_shot = np.where(closer, prev, ref_shot)
    return seg_of_shot, first, count, ref_shot, k0


def _span(granule: Granule):
    """``(instruments, t_first, t_last)`` of an in-memory granule, for the file headers."""
    runs = granule.beams
    return ([(r.beam, r.result.instrument) for r in runs],
            min(float(r.delta_time_s[0]) for r in runs),
            max(float(r.delta_time_s[-1]) for r in runs))


def write_atl03(granule: Granule, path: str | os.PathLike) -> pathlib.Path:
    """Write ``granule`` as an ATL03 file (see the module docstring), atomically."""
    path = pathlib.Path(path)
    with atomic_h5file(path) as f:
        _atl03_header(f, granule, *_span(granule))
        for r in granule.beams:
            _beam_atl03(f, r, granule.sc_orient)
    return path


def _atl03_header(f, granule, instruments, t_first, t_last):
    f.attrs["short_name"] = "ATL03"
    f.attrs["title"] = "simulated ATLAS/ICESat-2 L2A Global Geolocated Photon Data"
    f.attrs["description"] = ("Simulated by lidar_mitsuba (first-principles Monte Carlo): "
                              "photon heights over a DEM; /truth holds the simulation truth")
    f.attrs["lidar_mitsuba_version"] = __version__
    f.attrs["config"] = json.dumps(granule.config)
    f.attrs["time_coverage_start"] = _utc(t_first)
    f.attrs["time_coverage_end"] = _utc(t_last)
    _ancillary(f, instruments, t_first, t_last)
    _orbit_info(f, granule, t_first)
    t = f.create_group("truth")
    t.attrs["crs"] = granule.crs
    t.attrs["frame_origin_m"] = np.asarray(granule.frame_origin_m, np.float64)
    t.attrs["description"] = (
        "simulation truth per beam; positions x, y in the DEM CRS (attribute crs) less "
        "frame_origin_m [m], z and heights above the DEM's vertical datum [m]")


def _ancillary(f, instruments, t_first, t_last):
    a = f.create_group("ancillary_data")
    _ds(a, "atlas_sdp_gps_epoch", np.array([geotrack.ATLAS_SDP_GPS_EPOCH]), "seconds since "
        "1980-01-06T00:00:00.000000Z", "GPS seconds of the ATLAS SDP epoch 2018-01-01")
    for key, t in (("data_start_utc", t_first), ("granule_start_utc", t_first),
                   ("data_end_utc", t_last), ("granule_end_utc", t_last)):
        _ds(a, key, np.array([_utc(t)]), "1", f"{key[:-4].replace('_', ' ')} (UTC)")
    for when, t in (("start", t_first), ("end", t_last)):
        week, sow = _gps_week_sow(t)
        _ds(a, f"{when}_gpsweek", np.array([week], np.int32), "weeks", "GPS week")
        _ds(a, f"{when}_gpssow", np.array([sow]), "seconds", "GPS seconds of week")
        for key in ("cycle", "geoseg", "orbit", "region", "rgt"):
            _ds(a, f"{when}_{key}", np.array([0], np.int32), "1",
                f"{key}: not applicable to a simulated track (0)")
    _ds(a, "release", np.array([b"SIM"]), "1", "simulated: lidar_mitsuba")
    _ds(a, "version", np.array([__version__.encode()]), "1", "lidar_mitsuba version")
    tep = a.create_group("tep")
    _ds(tep, "tep_valid_spot", np.array([1, 1, 3, 3, 5, 5], np.int8), "1",
        "spot whose transmit pulse shape applies (every spot has the modelled shape)")
    cal = a.create_group("calibrations")
    dt = cal.create_group("dead_time")
    fpb = cal.create_group("first_photon_bias")
    fpb.attrs["description"] = ("no first-photon-bias tables: lidar_mitsuba's ATL06 corrects "
                                "event by event (lidar_mitsuba.fpb)")
    for beam, inst in instruments:
        g = dt.create_group(beam.name)
        _ds(g, "dead_time", np.full(inst.channels, inst.effective_dead_time_ns * 1e-9),
            "seconds", "modelled dead time of each channel")
        _ds(g, "sigma", np.zeros(inst.channels), "seconds", "dead time uncertainty (exact)")
        fpb.create_group(beam.name)
    imp = f.create_group("atlas_impulse_response")
    sigma_ns = instruments[0][1].pulse_sigma_ns
    t_ns = np.arange(-5 * sigma_ns, 5 * sigma_ns, 0.025)
    hist = np.exp(-0.5 * (t_ns / sigma_ns) ** 2)
    for pce in ("pce1_spot1", "pce2_spot3"):
        h = imp.create_group(f"{pce}/tep_histogram")
        _ds(h, "tep_hist", hist / hist.sum(), "1", "modelled transmit pulse shape "
            f"(Gaussian, FWHM {sigma_ns * FWHM_PER_SIGMA:g} ns), normalised")
        _ds(h, "tep_hist_time", t_ns * 1e-9, "seconds", "bin centre time from the pulse centre")
        _ds(h, "tep_tod", np.array([t_first]), "seconds since 2018-01-01", "histogram time")


def _orbit_info(f, granule, t_first):
    o = f.create_group("orbit_info")
    _ds(o, "sc_orient", np.array([granule.sc_orient], np.int8), "1",
        "spacecraft orientation: 0 backward (left beams strong), 1 forward, 2 transition")
    _ds(o, "sc_orient_time", np.array([t_first]), "seconds since 2018-01-01",
        "time of the orientation")
    for key, dtype in (("rgt", np.int16), ("cycle_number", np.int8), ("orbit_number", np.uint16)):
        _ds(o, key, np.array([0], dtype), "1", f"{key}: not applicable to a simulated track")


def _beam_atl03(f, run: BeamRun, sc_orient: int):
    res, beam = run.result, run.beam
    inst, det = res.instrument, res.detections
    order = _photon_order(res)
    shot = det.shot[order].astype(np.int64)              # local to this section
    gshot = shot + run.first_shot                        # in the whole track
    channel = det.channel[order]
    seg_of_shot, first, count, ref_shot, k0 = _segments(res.along_track_m, shot)
    gt = f.require_group(beam.name)
    done = gt["heights/h_ph"].shape[0] if "heights/h_ph" in gt else 0   # earlier sections
    gt.attrs.update({"atlas_beam_type": beam.strength, "atlas_spot_number": str(beam.spot),
                     "atlas_pce": f"pce{beam.pce}", "groundtrack_id": beam.name,
                     "sc_orientation": "Backward" if sc_orient == 0 else "Forward",
                     "description": "one ATLAS beam: photons, geolocation, background"})
    h = gt.require_group("heights")
    _put(h, "lat_ph", run.lat_deg[shot], "degrees_north",
        "latitude of the photon: its shot's footprint centre (nadir pointing)")
    _put(h, "lon_ph", run.lon_deg[shot], "degrees_east", "longitude of the photon")
    _put(h, "h_ph", res.h_m[order].astype(np.float32), "meters",
        "photon height above the DEM's vertical datum: altitude - c t / 2")
    _put(h, "delta_time", run.delta_time_s[shot], "seconds since 2018-01-01",
        "transmit time of the photon's shot")
    _put(h, "dist_ph_along", (res.along_track_m[shot] - SEGMENT_M * seg_of_shot[shot])
        .astype(np.float32), "meters", "along-track distance from the start of the segment")
    _put(h, "dist_ph_across", np.zeros(shot.size, np.float32), "meters",
        "across-track distance from the beam's ground track (0: nadir pointing)")
    conf = res.signal_conf[order].astype(np.int8)
    _put(h, "signal_conf_ph", np.repeat(conf[:, None], 5, axis=1), "counts",
        "confidence (land, ocean, sea ice, land ice, inland water; one histogram test for all): "
        "0 noise, 2 low, 3 medium, 4 high")
    _put(h, "quality_ph", np.zeros(shot.size, np.int8), "1", "0: nominal")
    _put(h, "ph_id_count", _ph_id_count(shot, channel), "counts",
        "1-based index of the event in its channel and pulse")
    base = 1 if beam.strength == "strong" else 17
    _put(h, "ph_id_channel", (channel.astype(np.int64) + base).astype(np.uint8), "1",
        "channel: strong beam 1-16, weak beam 17-20")
    _put(h, "ph_id_pulse", (gshot % PULSES_PER_MAJOR_FRAME + 1).astype(np.uint8), "counts",
        "pulse number within the major frame (1-200)")
    _put(h, "pce_mframe_cnt", (gshot // PULSES_PER_MAJOR_FRAME).astype(np.uint32), "counts",
        "major frame counter (from 0 at the first shot)")

    g = gt.require_group("geolocation")
    n_seg = count.size
    _put(g, "segment_id", k0 + np.arange(1, n_seg + 1, dtype=np.int32), "1",
        "20 m segment number, from 1 at the track's first shot")
    _put(g, "segment_ph_cnt", count.astype(np.int32), "counts", "photons in the segment")
    _put(g, "ph_index_beg", np.where(count > 0, done + first + 1, 0).astype(np.int64), "1",
        "1-based index in heights/ of the segment's first photon (0: none)")
    _put(g, "segment_dist_x", SEGMENT_M * (k0 + np.arange(n_seg, dtype=np.float64)), "meters",
        "along-track distance of the segment start from the track's first shot")
    _put(g, "segment_length", np.full(n_seg, SEGMENT_M), "meters", "segment length")
    _put(g, "reference_photon_lat", run.lat_deg[ref_shot], "degrees_north",
        "footprint centre of the shot nearest the segment centre")
    _put(g, "reference_photon_lon", run.lon_deg[ref_shot], "degrees_east",
        "footprint centre of the shot nearest the segment centre")
    ref_ph = np.searchsorted(shot, ref_shot)
    has = (ref_ph < shot.size) & (shot[np.minimum(ref_ph, max(shot.size - 1, 0))] == ref_shot) \
        if shot.size else np.zeros(n_seg, bool)
    _put(g, "reference_photon_index", np.where(has, ref_ph - first + 1, 0).astype(np.int32),
        "1", "1-based index in the segment of the reference shot's first photon (0: none)")
    _put(g, "delta_time", run.delta_time_s[ref_shot], "seconds since 2018-01-01",
        "transmit time of the reference shot")
    _put(g, "ref_azimuth", np.deg2rad(run.azimuth_deg[ref_shot]).astype(np.float32), "radians",
        "direction of travel, clockwise from north")
    _put(g, "ref_elev", np.full(n_seg, np.pi / 2, np.float32), "radians",
        "elevation of the unit pointing vector (nadir pointing)")
    _put(g, "sigma_h", np.zeros(n_seg, np.float32), "meters", "height uncertainty from "
        "geolocation (none in a simulation)")
    _put(g, "surf_type", np.tile(np.array([0, 0, 0, 1, 0], np.int8), (n_seg, 1)), "1",
        "surface types (land, ocean, sea ice, land ice, inland water): land ice")

    b = gt.require_group("bckgrd_atlas")
    rows = np.flatnonzero((run.first_shot + np.arange(res.n_shots)) % BCKGRD_SHOTS == 0)
    _put(b, "bckgrd_rate", np.full(rows.size, inst.background_mhz * 1e6, np.float32), "counts / "
        "second", "modelled solar background rate reaching the detector")
    _put(b, "delta_time", run.delta_time_s[rows], "seconds since 2018-01-01",
        "time of the 50-shot background period")

    c = gt.require_group("geophys_corr")
    _put(c, "delta_time", run.delta_time_s[ref_shot], "seconds since 2018-01-01",
        "segment time")
    for key in ("dac", "tide_earth", "tide_load", "tide_ocean", "tide_pole",
                "tide_equilibrium", "geoid", "dem_h"):
        v = res.surface_z_m[ref_shot] if key == "dem_h" else np.zeros(n_seg)
        _put(c, key, v.astype(np.float32), "meters",
            "DEM height at the reference shot" if key == "dem_h"
            else f"{key}: not modelled in a simulation (0)")

    _truth(f.require_group("truth").require_group(beam.name), res, order, run.first_shot)


def _truth(g, res, order, first_shot: int = 0):
    for group, name, data, units, desc in atl03.truth_fields(res, order=order,
                                                             first_shot=first_shot):
        _put(g.require_group(group), name, data, units, desc)
    if "config" not in g.attrs:                       # (the first section's)
        g.attrs["config"] = json.dumps(res.config)


# --------------------------------------------------------------------------- ATL06
#: ATL06 names of our segment fields: (subgroup or "" for land_ice_segments, name, dtype)
_ATL06_NAMES = {
    "h_li": ("", "h_li", np.float32), "h_li_sigma": ("", "h_li_sigma", np.float32),
    "atl06_quality_summary": ("", "atl06_quality_summary", np.int8),
    "dh_fit_dx": ("fit_statistics", "dh_fit_dx", np.float32),
    "h_mean": ("fit_statistics", "h_mean", np.float32),
    "sigma_h_mean": ("fit_statistics", "sigma_h_mean", np.float32),
    "h_robust_sprd": ("fit_statistics", "h_robust_sprd", np.float32),
    "h_rms_misfit": ("fit_statistics", "h_rms_misfit", np.float32),
    "n_fit_photons": ("fit_statistics", "n_fit_photons", np.int32),
    "n_seg_pulses": ("fit_statistics", "n_seg_pulses", np.float32),
    "w_surface_window_final": ("fit_statistics", "w_surface_window_final", np.float32),
    "snr": ("fit_statistics", "snr", np.float32),
    "fpb_corr_m": ("bias_correction", "fpb_mean_corr", np.float32),
    "fpb_corr_sigma_m": ("bias_correction", "fpb_mean_corr_sigma", np.float32),
    "fpb_med_corr_m": ("bias_correction", "fpb_med_corr", np.float32),
    "fpb_n_corr": ("bias_correction", "fpb_n_corr", np.float32),
    "bckgrd": ("geophysical", "bckgrd", np.float32),
    "x_atc": ("ground_track", "x_atc", np.float64),
    "h_ref_m": ("dem", "h_ref_m", np.float32),
}


def write_atl06(granule: Granule, path: str | os.PathLike, **options) -> pathlib.Path:
    """Fit ATL06 segments to every beam (:func:`lidar_mitsuba.atl06.segments_from_result`,
    ``options`` passed on) and write them with ATL06's names, atomically."""
    path = pathlib.Path(path)
    with atomic_h5file(path) as f:
        _atl06_header(f, granule, *_span(granule))
        for r in granule.beams:
            table = atl06.segments_from_result(r.result, **options)
            _beam_atl06(f, r.beam, granule.sc_orient, table, along_m=r.result.along_track_m,
                        lat_deg=r.lat_deg, lon_deg=r.lon_deg, delta_time_s=r.delta_time_s)
    return path


def _atl06_header(f, granule, instruments, t_first, t_last):
    f.attrs["short_name"] = "ATL06"
    f.attrs["description"] = ("Simulated land-ice heights (lidar_mitsuba.atl06: 40 m "
                              "segments every 20 m, first-photon-bias corrected)")
    f.attrs["lidar_mitsuba_version"] = __version__
    f.attrs["config"] = json.dumps(granule.config)
    _ancillary(f, instruments, t_first, t_last)
    li = f["ancillary_data"].create_group("land_ice")
    _ds(li, "t_dead", np.array([instruments[0][1].effective_dead_time_ns * 1e-9]),
        "seconds", "dead time used by the first-photon-bias correction")
    _orbit_info(f, granule, t_first)
    qa = f.create_group("quality_assessment")
    _ds(qa, "qa_granule_pass_fail", np.array([0], np.int8), "1", "0: pass")


def _beam_atl06(f, beam: Beam, sc_orient: int, table, *, along_m, lat_deg, lon_deg,
                delta_time_s):
    """Append ``table``'s segments to the beam's ``land_ice_segments``; positions and times
    are those of the shot nearest each segment centre among ``along_m`` [m] (with their
    ``lat_deg``, ``lon_deg``, ``delta_time_s``)."""
    gt = f.require_group(beam.name)
    gt.attrs.update({"atlas_beam_type": beam.strength, "atlas_spot_number": str(beam.spot),
                     "atlas_pce": f"pce{beam.pce}", "groundtrack_id": beam.name,
                     "sc_orientation": "Backward" if sc_orient == 0 else "Forward"})
    li = gt.require_group("land_ice_segments")
    for sub in ("fit_statistics", "bias_correction", "geophysical", "ground_track", "dem"):
        li.require_group(sub)
    i = np.clip(np.searchsorted(along_m, table.x_atc), 0, max(along_m.size - 1, 0))
    _put(li, "segment_id", np.asarray(table.segment_id, np.int32), "1",
         "segment number: the segment spans 20 m ATL03 segments segment_id and segment_id + 1")
    _put(li, "latitude", lat_deg[i], "degrees_north", "latitude of the segment centre")
    _put(li, "longitude", lon_deg[i], "degrees_east", "longitude of the segment centre")
    _put(li, "delta_time", delta_time_s[i], "seconds since 2018-01-01",
         "time of the segment centre")
    _put(li, "sigma_geo_h", np.zeros(len(table), np.float32), "meters",
         "height error from geolocation (none in a simulation)")
    for ours, (sub, name, dtype) in _ATL06_NAMES.items():
        units, desc = atl06.FIELDS[ours]
        v = np.asarray(getattr(table, ours))
        if np.issubdtype(dtype, np.floating):
            v = np.where(np.isfinite(v), v, np.finfo(dtype).max)   # ATL06's fill value
        ds = _put(li[sub] if sub else li, name, v.astype(dtype), units, desc)
        if np.issubdtype(dtype, np.floating):
            ds.attrs["_FillValue"] = np.finfo(dtype).max.astype(dtype)
    _put(li["ground_track"], "y_atc", np.full(len(table), beam.across_m, np.float32),
         "meters", "across-track offset of the beam from the reference ground track")


# --------------------------------------------------------------------------- streamed granules
SECTION_SHOTS = 1 << 16
"""Shots per section of a streamed granule (about 46 km): memory is bounded by a section."""


@dataclass
class BeamSummary:
    """Running statistics of one beam of a streamed granule (signal photons' h - z_ref).

    Attributes: beam; shots; photons (signal); bias_m, std_m [m]; bias_se_m [m];
    config: the first section's run config (its modelling choices).
    """
    beam: Beam
    shots: int = 0
    photons: int = 0
    sum_m: float = 0.0
    sum2_m2: float = 0.0
    config: dict | None = None

    def add(self, res) -> None:
        dh = res.dh_m[res.detections.is_signal]
        dh = dh[np.isfinite(dh)]
        self.shots += res.n_shots
        self.photons += int(dh.size)
        self.sum_m += float(dh.sum())          # (dh is centimetres to metres: sums of
        self.sum2_m2 += float(np.sum(dh * dh))  # squares lose nothing in float64)
        if self.config is None:
            self.config = res.config

    @property
    def bias_m(self) -> float:
        return self.sum_m / self.photons if self.photons else float("nan")

    @property
    def std_m(self) -> float:
        n = self.photons
        if n < 2:
            return float("nan")
        return float(np.sqrt(max(self.sum2_m2 - n * self.bias_m ** 2, 0.0) / (n - 1)))

    @property
    def bias_se_m(self) -> float:
        return self.std_m / np.sqrt(self.photons) if self.photons > 1 else float("nan")


def section_bounds(n_shots: int, *, spacing_m: float, section_shots: int,
                   along_m: np.ndarray | None = None) -> list[tuple[int, int]]:
    """``[(first, stop), ...]`` shot ranges of about ``section_shots`` shots, each starting
    on the first shot of a 20 m geolocation segment (so sections hold whole segments); shots
    are ``spacing_m`` apart along the track, or at ``along_m`` [m] ((n_shots,)) when given."""
    if along_m is None:
        seg = lambda i: int(np.floor(i * spacing_m / SEGMENT_M))    # noqa: E731 (as _segments)
    else:
        seg = lambda i: int(np.floor(along_m[i] / SEGMENT_M))      # noqa: E731
    cuts = [0]
    i = section_shots
    while i < n_shots:
        k = seg(i)
        j = i
        while j > cuts[-1] and seg(j - 1) == k:     # back to the segment's first shot
            j -= 1
        if j > cuts[-1]:
            cuts.append(j)
        i += section_shots
    cuts.append(n_shots)
    return list(zip(cuts[:-1], cuts[1:]))


def _along_of(track, beam: Beam, n_shots: int, spacing_m: float) -> np.ndarray | None:
    """A reference track's along-track distances of ``beam``'s shots when they are not
    ``spacing_m`` apart (a real granule's twin), else ``None``."""
    if isinstance(track, GeoTrack):
        return None
    return track.beam_geolocation(beam, 0, n_shots)[1]


class _SegmentStream:
    """ATL06 segments of one beam, fitted section by section. Each fit sees the previous
    section's last 20 m (the tail), so a 40 m segment across a section boundary holds all
    its photons; segments are on the whole track's grid (centres 20, 40, ... m from the
    first shot) and every one is fitted once, when its whole span has been simulated."""

    SHOT_KEYS = ("along", "zref", "lat", "lon", "time")
    PHOTON_KEYS = ("shot", "h", "channel")

    def __init__(self, options: dict):
        self.options = options
        self.next_centre = SEGMENT_M       # the first centre: 20 m from the first shot
        self.tail = None

    def fit(self, run: BeamRun, *, last: bool):
        """The segments completed by this section: ``(table, along, lat, lon, time)``."""
        res = run.result
        det = res.detections
        shots = {"along": res.along_track_m, "zref": res.z_ref_m, "lat": run.lat_deg,
                 "lon": run.lon_deg, "time": run.delta_time_s}
        ph = {"shot": det.shot.astype(np.int64), "h": res.h_m, "channel": det.channel}
        if self.tail is not None:
            n_tail = self.tail[0]["along"].size
            shots = {k: np.concatenate([self.tail[0][k], shots[k]]) for k in self.SHOT_KEYS}
            ph = {k: np.concatenate([self.tail[1][k], ph[k] + (n_tail if k == "shot" else 0)])
                  for k in self.PHOTON_KEYS}
        along = shots["along"]
        kw = dict(photon_along_m=along[ph["shot"]], h_m=ph["h"], shot=ph["shot"],
                  channel=ph["channel"], n_shots=along.size, shot_along_m=along,
                  z_ref_m=shots["zref"], gate_center_h_m=shots["zref"],
                  x0_m=self.next_centre - SEGMENT_M, **atl06.instrument_settings(res.instrument))
        kw.update(self.options)
        table = atl06.fit_segments(**kw)
        keep = table.x_atc >= self.next_centre - 1e-6
        if not last:      # a segment is done once the next section cannot add to it:
            # its span ends at or before the end of this section's last 20 m segment
            end = SEGMENT_M * (np.floor(along[-1] / SEGMENT_M) + 1)
            keep &= table.x_atc + SEGMENT_M <= end + 1e-6
        table = atl06.SegmentTable(**{f: np.asarray(getattr(table, f))[keep]
                                      for f in atl06.FIELDS})
        table.segment_id[:] = np.round(table.x_atc / SEGMENT_M).astype(table.segment_id.dtype)
        if table.x_atc.size:
            self.next_centre = float(table.x_atc[-1]) + SEGMENT_M
        start = self.next_centre - SEGMENT_M          # the next fit needs shots from here on
        s0 = int(np.searchsorted(along, start - 1e-9))
        p0 = int(np.searchsorted(ph["shot"], s0))
        self.tail = ({k: v[s0:].copy() for k, v in shots.items()},
                     {k: (v[p0:] - s0 if k == "shot" else v[p0:]).copy() for k, v in ph.items()})
        return table, along, shots["lat"], shots["lon"], shots["time"]


def stream_granule(*, surface: DEMSurface, track: GeoTrack, shots: int,
                   atl03_path: str | os.PathLike, atl06_path: str | os.PathLike | None = None,
                   beams: str | list[Beam] = "all", sc_orient: int = 0,
                   instrument_options: dict | None = None, instrument: str = "paper",
                   seed: int = 0, paths_per_shot: int | str = "auto",
                   max_depth: int | str = "auto",
                   progress: bool = True, section_shots: int = SECTION_SHOTS,
                   segment_options: dict | None = None, **simulate_options
                   ) -> list[BeamSummary]:
    """Simulate a granule section by section straight into its ATL03 (and ATL06) files, so
    memory is bounded by a section (``section_shots`` shots) for a track of any length.

    Arguments as :func:`simulate_granule`. Each section of each beam is an independent run
    (its own seed); ``max_depth="auto"`` and ``paths_per_shot="auto"`` are decided by each
    beam's first section (its pilot and scout) and kept for the rest. ATL06 segments are
    fitted across section boundaries (see :class:`_SegmentStream`). Both files are written
    atomically: a failure leaves neither. Returns each beam's running statistics.
    """
    import contextlib
    if isinstance(beams, str):
        beams = geotrack.select_beams(beams, sc_orient)
    if not (isinstance(section_shots, (int, np.integer)) and section_shots >= 1):
        raise ParameterError("section_shots", f"must be an integer >= 1 (got {section_shots!r})")
    ctx = _Context(surface, track, instrument_options, instrument)
    spacing = ctx.base.shot_spacing_m
    n_of = {b.name: track.beam_shot_count(b, shots) for b in beams}
    bounds = {b.name: section_bounds(n_of[b.name], spacing_m=spacing,
                                     section_shots=int(section_shots),
                                     along_m=_along_of(track, b, n_of[b.name], spacing))
              for b in beams}
    n_sections = max(len(v) for v in bounds.values())
    t_first, t_last = track.time_span_s(shots, prf_hz=ctx.base.prf_hz)
    meta = Granule(beams=[], sc_orient=int(sc_orient), crs=ctx.surface.dem.crs.to_string(),
                   frame_origin_m=ctx.origin, track=track,
                   config=ctx.config(shots=shots, seed=seed, sc_orient=sc_orient, beams=beams,
                                     sections=n_sections))
    instruments = [(b, ctx.instrument(b)) for b in beams]
    summaries = {b.name: BeamSummary(beam=b) for b in beams}
    depth = {b.name: max_depth for b in beams}
    paths = {b.name: paths_per_shot for b in beams}
    seg_options = dict(segment_options or {})
    if max(n_of.values()) * spacing / SEGMENT_M >= atl06.COMPILE_MIN_SEGMENTS:
        # one engine for every section of a long track (its short last section too)
        seg_options.setdefault("engine", "compiled")
    segs = {b.name: _SegmentStream(dict(seg_options)) for b in beams}
    bar = None
    if progress:
        from tqdm.auto import tqdm
        bar = tqdm(total=sum(n_of.values()), desc="granule", unit="shot", delay=2.0,
                   leave=False)
    try:
        with contextlib.ExitStack() as stack:
            f3 = stack.enter_context(atomic_h5file(atl03_path))
            _atl03_header(f3, meta, instruments, t_first, t_last)
            f6 = None
            if atl06_path is not None:
                f6 = stack.enter_context(atomic_h5file(atl06_path))
                _atl06_header(f6, meta, instruments, t_first, t_last)
            for k in range(n_sections):
                for beam in beams:
                    if k >= len(bounds[beam.name]):
                        continue
                    a, b = bounds[beam.name][k]
                    last = k == len(bounds[beam.name]) - 1
                    run = ctx.beam_run(beam, a, b - a, seed=_beam_seed(seed, beam, k),
                                       progress=False, paths_per_shot=paths[beam.name],
                                       max_depth=depth[beam.name], **simulate_options)
                    if run.result.config.get("snow") is None:   # a volume sets its own
                        depth[beam.name] = run.result.config["max_depth"]
                    paths[beam.name] = run.result.config["paths_per_shot"]
                    _beam_atl03(f3, run, sc_orient)
                    if f6 is not None:
                        table, along, lat, lon, t = segs[beam.name].fit(run, last=last)
                        _beam_atl06(f6, beam, sc_orient, table, along_m=along, lat_deg=lat,
                                    lon_deg=lon, delta_time_s=t)
                    summaries[beam.name].add(run.result)
                    if bar is not None:
                        bar.update(b - a)
                    del run
    finally:
        if bar is not None:
            bar.close()
    return list(summaries.values())
