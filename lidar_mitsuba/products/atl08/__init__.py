"""ATL08-like land and vegetation product: photons classed noise, ground, canopy and top of
canopy, and 100 m segments of terrain and canopy heights, written as the real ATL08 lays
them out. Pure numpy/scipy/h5py; it runs on any ATL03 file, ours or NASA's.

* :mod:`~lidar_mitsuba.products.atl08.classify`: the photon classifier (noise filter,
  ground and top-of-canopy envelopes; its docstring gives the algorithm and the ATBD
  sections it follows);
* :mod:`~lidar_mitsuba.products.atl08.segments`: the 100 m segments' terrain and canopy
  metrics;
* :mod:`~lidar_mitsuba.products.atl08.fields`: names, dtypes, fill values and attributes of
  what we write (those of ATL08 release 006);
* here: :func:`from_atl03` (an ATL03 beam to an :class:`Atl08Beam`), :func:`write`,
  :func:`read`.

>>> from lidar_mitsuba.products import atl08
>>> beam = atl08.from_atl03("ATL03.h5", "gt1r")                    # doctest: +SKIP
>>> atl08.write(beam, "ATL08.h5")                                  # doctest: +SKIP
"""
from __future__ import annotations

import json
import os
import pathlib
from dataclasses import dataclass, field

import numpy as np

from .classify import (CANOPY, GROUND, NOISE, TOP_OF_CANOPY, Classification,  # noqa: F401
                       Settings, background_density_from_rate, classify_photons)
from .fields import GROUPS, NOT_WRITTEN, RH_PERCENTILES  # noqa: F401 (re-exported)
from . import segments  # noqa: F401
from .segments import SEGMENTS_PER_LAND_SEGMENT, land_segments

ATLAS_PRF_HZ = 10_000.0
"""ATLAS's pulse repetition frequency [Hz] (ATL03 ATBD; docs/guide/atlas.md): shots per
metre of track are this over the ground speed."""


@dataclass
class Atl08Beam:
    """One beam's ATL08: ``segments`` (``group/name`` -> array, :data:`GROUPS` but the
    photons), ``photons`` (``signal_photons`` fields), the ``classification`` of the ATL03
    photons inside 20 m segments and their 0-based ATL03 indices ``atl03_index``, the beam's
    group attributes, ``truth`` (``name`` -> (array, units, description), empty when the
    input has none), and the input's ``orbit_info`` datasets (icepyx reads them)."""
    beam: str
    segments: dict
    photons: dict
    classification: Classification
    atl03_index: np.ndarray
    attrs: dict = field(default_factory=dict)
    truth: dict = field(default_factory=dict)
    source: str = ""
    orbit_info: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.segments["land_segments/segment_id_beg"].size)


def _index_base(beg: np.ndarray, cnt: np.ndarray, n: int) -> int:
    """Whether ``ph_index_beg`` counts from 1 (NASA's granules and ours) or 0 (some clip
    tools rewrite it): the last non-empty segment ends at photon ``n`` in the first case."""
    nz = np.flatnonzero(cnt > 0)
    if nz.size == 0:
        return 1
    return int(beg[nz[-1]] + cnt[nz[-1]] - n)


ATL03_NEEDS = ("heights/h_ph", "heights/delta_time", "heights/dist_ph_along",
               "geolocation/segment_ph_cnt", "geolocation/ph_index_beg",
               "geolocation/segment_id", "geolocation/segment_dist_x",
               "geolocation/reference_photon_lat", "geolocation/reference_photon_lon",
               "geolocation/delta_time")
"""What :func:`read_atl03_beam` reads of an ATL03 beam (the photons and their 20 m segments)."""


def atl03_lacks(group) -> list[str]:
    """The datasets of :data:`ATL03_NEEDS` an ATL03 beam group (h5py) lacks (a subset dropped
    them)."""
    return [n for n in ATL03_NEEDS if n not in group]


def read_atl03_beam(path: str | os.PathLike, beam: str) -> dict:
    """The photons and 20 m segments of one ATL03 beam (ours or NASA's): per photon ``x_m``
    (along track: ``segment_dist_x + dist_ph_along``), ``h_m``, ``delta_time_s``,
    ``segment`` (index into the segment arrays), ``indx`` (1-based within its segment); per
    segment ``seg_id``, ``seg_x_m``, ``seg_lat_deg``, ``seg_lon_deg``, the sun, ``beg0``
    (0-based first photon); the background rate at each photon ``bckgrd_hz`` (None when the
    file has none), ``shots_per_m``, the beam group's attributes and, for our files, the
    truth (``truth_along_m``, ``truth_surface_z_m``, ``truth_is_signal``)."""
    import h5py
    from ...constants import ParameterError
    with h5py.File(path, "r") as f:
        if beam not in f or "heights" not in f[beam]:
            raise ParameterError("beam", f"{path}: no ATL03 beam {beam!r}")
        g = f[beam]
        lacks = atl03_lacks(g)
        if lacks:
            raise ParameterError("beam", f"{path}: ATL03 beam {beam} lacks "
                                 f"{', '.join(lacks)} (a subset dropped them)")
        hts, geo = g["heights"], g["geolocation"]
        h = hts["h_ph"][()].astype(np.float64)
        cnt = geo["segment_ph_cnt"][()].astype(np.int64)
        beg = geo["ph_index_beg"][()].astype(np.int64)
        beg0 = beg - _index_base(beg, cnt, h.size)
        seg = np.full(h.size, -1, np.int64)
        for i in np.flatnonzero(cnt > 0):
            seg[beg0[i]:beg0[i] + cnt[i]] = i
        out = {"h_m": h, "delta_time_s": hts["delta_time"][()], "segment": seg,
               "seg_id": geo["segment_id"][()].astype(np.int64),
               "seg_x_m": geo["segment_dist_x"][()].astype(np.float64),
               "seg_lat_deg": geo["reference_photon_lat"][()],
               "seg_lon_deg": geo["reference_photon_lon"][()],
               "seg_dt_s": geo["delta_time"][()], "beg0": beg0,
               "attrs": {k: v for k, v in g.attrs.items()}}
        for key in ("solar_elevation", "solar_azimuth"):
            out[key] = geo[key][()] if key in geo else None
        ok = seg >= 0
        out["x_m"] = np.where(ok, out["seg_x_m"][np.maximum(seg, 0)], np.nan) + \
            hts["dist_ph_along"][()].astype(np.float64)
        out["indx"] = np.where(ok, np.arange(h.size) - beg0[np.maximum(seg, 0)] + 1, 0)
        out["bckgrd_hz"] = None
        if ("bckgrd_atlas" in g and "bckgrd_rate" in g["bckgrd_atlas"]
                and "delta_time" in g["bckgrd_atlas"]):
            b = g["bckgrd_atlas"]
            out["bckgrd_hz"] = np.interp(out["delta_time_s"], b["delta_time"][()],
                                         b["bckgrd_rate"][()])
        out["shots_per_m"] = _shots_per_m(out["seg_x_m"], out["seg_dt_s"])
        out["orbit_info"] = ({k: v[()] for k, v in f["orbit_info"].items()}
                             if "orbit_info" in f else {})
        t = f.get(f"truth/{beam}")
        if t is not None and "shots" in t:
            out["truth_along_m"] = t["shots/along_track_m"][()]
            out["truth_surface_z_m"] = t["shots/surface_z_m"][()]
            out["truth_is_signal"] = t["photons/is_signal"][()].astype(bool)
    return out


def _shots_per_m(seg_x_m: np.ndarray, seg_dt_s: np.ndarray) -> float:
    """Shots per metre of track: ATLAS's PRF over the ground speed, the latter from the
    20 m segments' times and along-track positions."""
    if seg_x_m.size < 2 or np.ptp(seg_dt_s) <= 0:
        return ATLAS_PRF_HZ / 7000.0          # ICESat-2's ~7 km/s ground speed
    return ATLAS_PRF_HZ * float(np.ptp(seg_dt_s) / np.ptp(seg_x_m))


def from_atl03(path: str | os.PathLike, beam: str = "gt1l", *,
               settings: Settings | None = None) -> Atl08Beam:
    """Classify one ATL03 beam's photons and make its 100 m segments (module docstring).

    The background density comes from the file's ``bckgrd_atlas/bckgrd_rate`` when it has
    one (:func:`~lidar_mitsuba.products.atl08.classify.background_density_from_rate`), else
    from the photon cloud. Photons outside every 20 m segment are left out.
    """
    d = read_atl03_beam(path, beam)
    ok = d["segment"] >= 0
    rho = (None if d["bckgrd_hz"] is None
           else background_density_from_rate(d["bckgrd_hz"][ok], d["shots_per_m"]))
    x, h = d["x_m"][ok], d["h_m"][ok]
    c = classify_photons(x_m=x, h_m=h, background_per_m2=rho, settings=settings)
    seg = d["segment"][ok]
    first = int(seg.min()) if seg.size else 0
    sel = slice(first, None)
    segs = land_segments(
        x_m=x, h_m=h, classes=c.classes, ground_h_m=c.ground_h_m, is_signal=c.is_signal,
        photon_segment=seg - first, delta_time_s=d["delta_time_s"][ok],
        seg_id=d["seg_id"][sel], seg_x_m=d["seg_x_m"][sel], seg_lat_deg=d["seg_lat_deg"][sel],
        seg_lon_deg=d["seg_lon_deg"][sel],
        seg_solar_elevation_deg=None if d["solar_elevation"] is None
        else d["solar_elevation"][sel],
        seg_solar_azimuth_deg=None if d["solar_azimuth"] is None else d["solar_azimuth"][sel],
        shots_per_m=d["shots_per_m"])
    s = c.is_signal
    photons = {"classed_pc_flag": c.classes[s], "classed_pc_indx": d["indx"][ok][s],
               "ph_segment_id": d["seg_id"][seg[s]], "delta_time": d["delta_time_s"][ok][s],
               "ph_h": np.nan_to_num(c.h_rel_m[s], nan=np.finfo(np.float32).max),
               "d_flag": np.ones(int(s.sum()), np.int8)}
    truth = _truth(d, ok, s, segs, seg_len_m=float(np.median(np.diff(d["seg_x_m"])))
                   if d["seg_x_m"].size > 1 else 20.0)
    return Atl08Beam(beam=beam, segments=segs, photons=photons, classification=c,
                     atl03_index=np.flatnonzero(ok), attrs=d["attrs"], truth=truth,
                     source=os.fspath(path), orbit_info=d["orbit_info"])


def _truth(d: dict, ok: np.ndarray, s: np.ndarray, segs: dict, *, seg_len_m: float) -> dict:
    """What the simulation knows, beside the segments: the true surface height under each
    segment (mean of the shots' ``surface_z_m``) and each written photon's signal truth;
    empty for a file without ``/truth`` (a real one)."""
    if "truth_surface_z_m" not in d:
        return {}
    x0 = d["seg_x_m"][np.searchsorted(d["seg_id"], segs["land_segments/segment_id_beg"])]
    length = SEGMENTS_PER_LAND_SEGMENT * seg_len_m
    along, z = d["truth_along_m"], d["truth_surface_z_m"]
    h_true = np.full(x0.size, np.nan)
    for k, a in enumerate(x0):
        m = (along >= a) & (along < a + length)
        if m.any():
            h_true[k] = z[m].mean()
    out = {"land_segments/h_surface_true": (
        h_true, "meters", "mean true surface height under the segment's shots (the "
        "simulated surface at the footprint centres)")}
    if d["truth_is_signal"].size == ok.size:
        out["signal_photons/is_signal"] = (
            d["truth_is_signal"][ok][s].astype(np.int8), "1",
            "1: a simulated signal photon (a return of the laser), 0: background")
    return out


def write(beams: Atl08Beam | list, path: str | os.PathLike, *,
          instrument=None) -> pathlib.Path:
    """Write one or several :class:`Atl08Beam` to ``path`` atomically, laid out as the real
    ATL08 (``<beam>/land_segments``, ``.../terrain``, ``.../canopy``,
    ``<beam>/signal_photons``; dtypes, fill values, ``units``/``long_name``/``description``
    attributes of :data:`GROUPS`), with ``METADATA`` (:mod:`lidar_mitsuba.products.metadata`)
    the input's ``orbit_info``, ``ancillary_data/atlas_sdp_gps_epoch``, and the truth under
    ``/truth/<beam>``. ``instrument``: the ATLAS of the METADATA's acquisition (default
    :meth:`~lidar_mitsuba.instrument.Instrument.atlas`)."""
    from ...instrument import Instrument
    from ..atl03 import atomic_h5file
    from ..atl03.file import utc
    from ..metadata import extend_extent, write_metadata
    beams = [beams] if isinstance(beams, Atl08Beam) else list(beams)
    path = pathlib.Path(path)
    inst = instrument or Instrument.atlas()
    times = np.concatenate([b.photons["delta_time"] for b in beams] + [np.zeros(0)])
    t0, t1 = (float(times.min()), float(times.max())) if times.size else (0.0, 0.0)
    with atomic_h5file(path) as f:
        f.attrs.update({"short_name": "ATL08", "granule_type": "ATL08", "level": "L3A",
                        "Conventions": "CF-1.6", "featureType": "trajectory",
                        "title": "simulated-processing ATLAS/ICESat-2 L3A Land and "
                                 "Vegetation Height (lidar_mitsuba)",
                        "description": "ATL08-like 100 m land segments made by lidar_mitsuba's "
                                       "own classifier (products.atl08) from an ATL03 file",
                        "time_coverage_start": utc(t0), "time_coverage_end": utc(t1)})
        write_metadata(f, short_name="ATL08", path=path,
                       config={"settings": repr(Settings()),
                               "sources": sorted({b.source for b in beams})},
                       instruments=[(_beam_of(b), inst) for b in beams],
                       t_first=utc(t0), t_last=utc(t1),
                       process="Photons of an ATL03 file classified and aggregated into "
                       "100 m segments by lidar_mitsuba.products.atl08 (not NASA's ATL08 "
                       "software): " + ", ".join(sorted({b.source for b in beams})))
        _orbit_and_ancillary(f, beams[0].orbit_info, t0, t1)
        for b in beams:
            _write_beam(f, b)
            lat = b.segments["land_segments/latitude"]
            extend_extent(f, lat, b.segments["land_segments/longitude"])
    return path


def _orbit_and_ancillary(f, orbit: dict, t0: float, t1: float) -> None:
    """``orbit_info`` (the input's: icepyx reads it) and the ``ancillary_data`` times a
    real ATL08 carries (icepyx reads the epoch and the data's start and end)."""
    from ..atl03.file import gps_week_sow, utc
    from ..las import ATLAS_SDP_GPS_EPOCH_S
    for k, v in orbit.items():
        f.create_dataset(f"orbit_info/{k}", data=v)
    a = f.create_group("ancillary_data")

    def put(name, value, units):
        a.create_dataset(name, data=np.array([value])).attrs["units"] = np.bytes_(units)
    put("atlas_sdp_gps_epoch", ATLAS_SDP_GPS_EPOCH_S, "seconds since 1980-01-06T00:00:00Z")
    for when, t in (("start", t0), ("end", t1)):
        put(f"data_{when}_utc", utc(t), "1")
        put(f"granule_{when}_utc", utc(t), "1")
        put(f"{when}_delta_time", t, "seconds since 2018-01-01")
        week, sow = gps_week_sow(t)
        put(f"{when}_gpsweek", np.int32(week), "weeks")
        put(f"{when}_gpssow", sow, "seconds")
        for key, src in (("rgt", "rgt"), ("cycle", "cycle_number"), ("orbit", "orbit_number")):
            v = orbit.get(src)
            put(f"{when}_{key}", np.int32(v[0] if v is not None and np.size(v) else 0), "1")


def _beam_of(b: Atl08Beam):
    from ...geotrack import beam_layout
    for layout in beam_layout(0):
        if layout.name == b.beam:
            return layout
    raise ValueError(f"unknown beam {b.beam!r}")


def _write_beam(f, b: Atl08Beam) -> None:
    g = f.create_group(b.beam)
    for k, v in b.attrs.items():
        g.attrs[k] = v
    for group, spec in GROUPS.items():
        grp = g.require_group(group)
        src = b.photons if group == "signal_photons" else {
            name: b.segments[f"{group}/{name}"] for name in spec}
        for name, fld in spec.items():
            data = np.asarray(src[name]).astype(fld.dtype)
            kw = {} if fld.fill is None else {"fillvalue": fld.fill}
            # chunked and deflated as the real product is: (10000, ...) chunks, gzip
            ds = grp.create_dataset(name, data=data, chunks=(10000,) + data.shape[1:],
                                    maxshape=(None,) + data.shape[1:], compression="gzip",
                                    **kw)
            ds.attrs["units"] = np.bytes_(fld.units)
            ds.attrs["long_name"] = np.bytes_(fld.long_name)
            ds.attrs["description"] = np.bytes_(fld.description)
            ds.attrs["source"] = np.bytes_("lidar_mitsuba.products.atl08")
            if fld.fill is not None:
                ds.attrs.create("_FillValue", fld.fill, dtype=fld.dtype)
    _scales(f, g)
    if b.truth:
        t = f.require_group(f"truth/{b.beam}")
        for name, (data, units, desc) in b.truth.items():
            ds = t.create_dataset(name, data=data)
            ds.attrs["units"], ds.attrs["description"] = units, desc


COLUMN_SCALES = {"ds_metrics": len(RH_PERCENTILES), "ds_geosegments": SEGMENTS_PER_LAND_SEGMENT}
"""The root dimension scales of a real ATL08's second axes: the 18 canopy metrics, the five
20 m geosegments."""


def _scales(f, g) -> None:
    """Dimension scales as in real granules: ``land_segments/delta_time`` for axis 0 of every
    dataset of ``land_segments`` and its ``terrain`` and ``canopy`` groups,
    ``signal_photons/delta_time`` for the photons', and the root :data:`COLUMN_SCALES` for
    second axes (xarray and icepyx then open the nested groups on the segments' times)."""
    for name, n in COLUMN_SCALES.items():
        if name not in f:
            f.create_dataset(name, data=np.arange(1, n + 1, dtype=np.int32)).make_scale(name)
    by_columns = {n: f[name] for name, n in COLUMN_SCALES.items()}
    for top, groups in (("land_segments", ("land_segments", "land_segments/terrain",
                                           "land_segments/canopy")),
                        ("signal_photons", ("signal_photons",))):
        t = g[f"{top}/delta_time"]
        t.make_scale("delta_time")
        for grp in groups:
            for name, ds in g[grp].items():
                if name == "delta_time" and grp == top or not hasattr(ds, "dims"):
                    continue
                ds.dims[0].attach_scale(t)
                if ds.ndim == 2:
                    ds.dims[1].attach_scale(by_columns[ds.shape[1]])


def read(path: str | os.PathLike, beam: str) -> dict:
    """One beam of an ATL08 file (ours or NASA's): ``group/name`` -> array for every dataset
    of :data:`GROUPS` the file has."""
    import h5py
    out = {}
    with h5py.File(path, "r") as f:
        for group, spec in GROUPS.items():
            for name in spec:
                key = f"{beam}/{group}/{name}"
                if key in f:
                    out[f"{group}/{name}"] = f[key][()]
    return out
