"""A granule's ATL03 and ATL06 files: what the writer process runs (issue 43).

:func:`write_atl03` and :func:`write_atl06` write a simulated
:class:`~lidar_mitsuba.products.record.Granule` (:func:`lidar_mitsuba.granule.simulate_granule`);
the headers (:func:`_atl06_header`, and ATL03's from
:mod:`lidar_mitsuba.products.atl03.file`), a beam's ATL03 rows and ATL06 segments, the ATL06
fits across a streamed granule's sections (:class:`_SegmentStream`) and their thread
(:class:`_Fits`) are what :mod:`lidar_mitsuba.granule_writer` calls, section by section.
:mod:`lidar_mitsuba.granule` (the simulation) imports none of this: h5py and the product
writers are imported by the process that writes (the writer process, after its fork), not by
the one that simulates before its first granule. The file layouts are described in
:mod:`lidar_mitsuba.granule`.
"""
from __future__ import annotations

import json
import os
import pathlib

import numpy as np

from . import __version__
from .products import atl06, cloud_flags, h5template, h5write as h5chunks
from .products.atl03 import _ds, atomic_h5file
from .products.atl03.beam import (beam_attrs, noise_rate_hz,
                                   write_beam as _beam_atl03)  # noqa: F401
from .products.atl03.file import (ancillary as _ancillary, header as _atl03_header,
                                  orbit_info as _orbit_info, utc as _utc)
from .products.metadata import extend_extent as _extend_extent, write_metadata as _metadata
from .products.record import SEGMENT_M, BeamRun, Granule
from .geotrack import Beam


# --------------------------------------------------------------------------- ATL03
def _put(group, name, data, units, description):
    """Create a resizable, compressed dataset, or append ``data`` to it along axis 0 (a
    streamed granule writes each section's rows after the last); whole chunks are compressed
    on every core (:mod:`lidar_mitsuba.products.h5write`)."""
    return h5chunks.put(group, name, data, units, description, append=True)


def write_atl03(granule: Granule, path: str | os.PathLike) -> pathlib.Path:
    """Write ``granule`` as an ATL03 file (see the module docstring), atomically."""
    path = pathlib.Path(path)
    with atomic_h5file(path) as f:
        _atl03_header(f, granule, *granule.span(), path=path)
        for r in granule.beams:
            _beam_atl03(f, r, granule.sc_orient)
    return path


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
    "bckgrd": ("fit_statistics", "bckgrd_fit", np.float32),
    "x_atc": ("ground_track", "x_atc", np.float64),
    "h_ref_m": ("dem", "h_ref_m", np.float32),
}


_ATL06_PROCESS = ("40 m segments every 20 m fitted to each beam's simulated photons (the "
                  "photons of the run's ATL03) and corrected for the first-photon bias "
                  "(lidar_mitsuba.products.atl06).")


def write_atl06(granule: Granule, path: str | os.PathLike, **options) -> pathlib.Path:
    """Fit ATL06 segments to every beam (:func:`lidar_mitsuba.products.atl06.segments_from_result`,
    ``options`` passed on) and write them with ATL06's names, atomically."""
    path = pathlib.Path(path)
    with atomic_h5file(path) as f:
        _atl06_header(f, granule, *granule.span(), path=path)
        for r in granule.beams:
            table = atl06.segments_from_result(r.result, **options)
            _beam_atl06(f, r.beam, granule.sc_orient, table, along_m=r.result.along_track_m,
                        lat_deg=r.lat_deg, lon_deg=r.lon_deg, delta_time_s=r.delta_time_s,
                        rate_hz=noise_rate_hz(r.result), sky=cloud_flags.sky_of(r.result))
    return path


def _atl06_header(f, granule, instruments, t_first, t_last, *, path, atl03_path=None):
    h5chunks.set_attrs(f, {
        "short_name": "ATL06", "title": "simulated ATLAS/ICESat-2 L3A Land Ice Height",
        "description": ("Simulated land-ice heights (lidar_mitsuba.products.atl06: 40 m "
                        "segments every 20 m, first-photon-bias corrected)"),
        "lidar_mitsuba_version": __version__, "config": json.dumps(granule.config)})
    _ancillary(f, instruments, t_first, t_last)
    li = f["ancillary_data"].create_group("land_ice")
    _ds(li, "t_dead", np.array([instruments[0][1].effective_dead_time_ns * 1e-9]),
        "seconds", "dead time used by the first-photon-bias correction")
    _orbit_info(f, granule, t_first)
    _metadata(f, short_name="ATL06", path=path, config=granule.config, instruments=instruments,
              t_first=_utc(t_first), t_last=_utc(t_last), process=_ATL06_PROCESS,
              inputs={"ATL03": atl03_path} if atl03_path is not None else None)
    qa = f.create_group("quality_assessment")
    _ds(qa, "qa_granule_pass_fail", np.array([0], np.int8), "1", "0: pass")


def _beam_atl06(f, beam: Beam, sc_orient: int, table, *, along_m, lat_deg, lon_deg,
                delta_time_s, rate_hz, sky: dict | None = None):
    """Append ``table``'s segments to the beam's ``land_ice_segments``; positions, times and
    the background rate are those of the shot nearest each segment centre among ``along_m``
    [m] (with their ``lat_deg``, ``lon_deg``, ``delta_time_s``, ``rate_hz``: the modelled
    noise rate [Hz], :func:`~lidar_mitsuba.products.atl03.beam.noise_rate_hz`); ``sky``: the
    run's :func:`~lidar_mitsuba.products.cloud_flags.sky_of`, for ``geophysical``'s cloud
    flags.

    ``geophysical/bckgrd`` is NASA's: "Background count rate, derived from the ATL03
    50-shot-average, interpolated to the segment center" [hz], here the rate our ATL03's
    ``bckgrd_rate`` rows average, at the segment centre's shot. Our fit's own estimate
    (``SegmentTable.bckgrd``, from the photons outside its window, dead-time corrected: what
    its first-photon-bias correction subtracts) is ``fit_statistics/bckgrd_fit`` [hz]; until
    session 29 it was written as ``geophysical/bckgrd`` in MHz, which read as a million
    times too small to any reader of NASA's units."""
    if beam.name not in f:                                # (the first section's)
        h5chunks.set_attrs(f.create_group(beam.name), beam_attrs(beam, sc_orient))
    i = np.clip(np.searchsorted(along_m, table.x_atc), 0, max(along_m.size - 1, 0))
    _extend_extent(f, lat_deg[i], lon_deg[i])
    n = len(table)
    columns = [
        ("segment_id", np.asarray(table.segment_id, np.int32), "1",
         "segment number: the segment spans 20 m ATL03 segments segment_id and segment_id + 1"),
        ("latitude", lat_deg[i], "degrees_north", "latitude of the segment centre"),
        ("longitude", lon_deg[i], "degrees_east", "longitude of the segment centre"),
        ("delta_time", delta_time_s[i], "seconds since 2018-01-01", "time of the segment centre"),
        ("sigma_geo_h", np.zeros(n, np.float32), "meters",
         "height error from geolocation (none in a simulation)")]
    columns = [c + ({}, None) for c in columns]
    f4_fill = {"_FillValue": np.finfo(np.float32).max}
    columns.append(("geophysical/bckgrd", np.asarray(rate_hz, np.float32)[i], "hz",
                    "Background count rate, derived from the ATL03 50-shot-average, "
                    "interpolated to the segment center: the modelled rate of noise events the "
                    "detector records (ATL03's bckgrd_rate) at the segment centre's shot",
                    f4_fill, None))
    for ours, (sub, name, dtype) in _ATL06_NAMES.items():
        units, desc = atl06.FIELDS[ours]
        v = np.asarray(getattr(table, ours))
        if ours == "bckgrd":                      # our fit's estimate, in NASA's unit
            units, desc, v = "hz", desc + " (our fit's estimate, not in NASA's ATL06)", v * 1e6
        attrs = {}
        if np.issubdtype(dtype, np.floating):
            v = np.where(np.isfinite(v), v, np.finfo(dtype).max)   # ATL06's fill value
            attrs = {"_FillValue": np.finfo(dtype).max.astype(dtype)}
        columns.append((f"{sub}/{name}" if sub else name, v.astype(dtype), units, desc, attrs,
                        None))
    columns.append(("ground_track/y_atc", np.full(n, beam.across_m, np.float32), "meters",
                    "across-track offset of the beam from the reference ground track", {}, None))
    if sky is not None:         # ATL09-style cloud flags (r_eff, cloud_flg_asr, cloud_flg_atm)
        columns += cloud_flags.atl06_datasets(cloud_flags.atl06_columns(table, sky))
    # (a new group's datasets copied from a template: products.h5template)
    h5template.put_group(f[beam.name], "land_ice_segments", columns)


# --------------------------------------------------------------------------- streamed granules
class _Fits:
    """A granule's ATL06 fits on a thread of their own: a section's segments are fitted (the
    compiled fit runs without the GIL) while the simulating thread lays out and traces the
    next one, and are written to ``f6`` by the simulating thread (:meth:`write`), in the
    order they were submitted: each beam's sections in order, each fit after the one before
    (one thread: a beam's fit continues from the previous one's tail)."""

    def __init__(self, f6, sc_orient: int):
        from concurrent.futures import ThreadPoolExecutor
        self.f6, self.sc_orient, self.jobs = f6, sc_orient, []
        self.pool = ThreadPoolExecutor(1, thread_name_prefix="lidar-atl06")

    def submit(self, beam: Beam, segments: "_SegmentStream", run: BeamRun, *, last: bool):
        self.jobs.append((beam, self.pool.submit(segments.fit, run, last=last),
                          cloud_flags.sky_of(run.result)))

    def write(self, *, wait: bool = False) -> None:
        """Write the finished fits (``wait``: all of them) to the ATL06 file."""
        while self.jobs and (wait or self.jobs[0][1].done()):
            beam, job, sky = self.jobs.pop(0)
            table, along, lat, lon, t, rate = job.result()
            _beam_atl06(self.f6, beam, self.sc_orient, table, along_m=along, lat_deg=lat,
                        lon_deg=lon, delta_time_s=t, rate_hz=rate, sky=sky)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.pool.shutdown(wait=True, cancel_futures=True)


class _SegmentStream:
    """ATL06 segments of one beam, fitted section by section. Each fit sees the previous
    section's last 20 m (the tail), so a 40 m segment across a section boundary holds all
    its photons; segments are on the whole track's grid (centres 20, 40, ... m from the
    first shot) and every one is fitted once, when its whole span has been simulated."""

    SHOT_KEYS = ("along", "zref", "lat", "lon", "time", "rate")
    PHOTON_KEYS = ("shot", "h", "channel")

    def __init__(self, options: dict):
        self.options = options
        self.next_centre = SEGMENT_M       # the first centre: 20 m from the first shot
        self.tail = None

    def fit(self, run: BeamRun, *, last: bool):
        """The segments completed by this section: ``(table, along, lat, lon, time, rate)``
        (``rate``: each shot's modelled noise rate [Hz], :func:`noise_rate_hz`)."""
        res = run.result
        det = res.detections
        shots = {"along": res.along_track_m, "zref": res.z_ref_m, "lat": run.lat_deg,
                 "lon": run.lon_deg, "time": run.delta_time_s, "rate": noise_rate_hz(res)}
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
        return table, along, shots["lat"], shots["lon"], shots["time"], shots["rate"]
