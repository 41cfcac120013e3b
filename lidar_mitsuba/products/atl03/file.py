"""The file-level groups of our ATL03 (and ATL06) files: root attributes, ``ancillary_data``,
``orbit_info``, ``atlas_impulse_response``, the ISO 19115 ``METADATA`` group real granules
carry (:mod:`lidar_mitsuba.products.metadata`: ``DatasetIdentification``, ``Extent``,
``Lineage``, ``ProcessStep``, ...) with the granule's time bounds and latitude and longitude
bounds (:func:`extend_extent`, as beams are written), and the root dimension scales
``ds_surf_type`` and ``ds_xyz``."""
from __future__ import annotations

import datetime as _dt
import json

import numpy as np
from h5py import h5d, h5ds, h5o

from ... import __version__, geotrack
from .. import h5write as h5chunks, metadata as meta
from ...constants import FWHM_PER_SIGMA


def _ds(group, name, data, units, description):
    return h5chunks.put(group, name, data, units, description)


def utc(delta_time_s: float) -> bytes:
    """ISO 8601 UTC of ``delta_time_s`` [s since the ATLAS SDP epoch]."""
    t = geotrack.SDP_EPOCH_UTC + _dt.timedelta(seconds=float(delta_time_s))
    return t.strftime("%Y-%m-%dT%H:%M:%S.%fZ").encode()


def gps_week_sow(delta_time_s: float) -> tuple[int, float]:
    gps = geotrack.ATLAS_SDP_GPS_EPOCH + float(delta_time_s)
    return int(gps // 604800), gps % 604800


def header(f, granule, instruments, t_first, t_last, *, path=None) -> None:
    """Root attributes, ``ancillary_data``, ``orbit_info``, ``METADATA`` and the ``/truth``
    group's attributes of an ATL03 file. ``granule``: its ``config``, ``sc_orient``, ``crs``
    and ``frame_origin_m``; ``instruments``: ``[(beam, instrument), ...]``; ``t_first``,
    ``t_last``: the first and last shot times [s since 2018-01-01]; ``path``: where the file
    will be (its name gives the metadata's file name and release; default ``f``'s own)."""
    h5chunks.set_attrs(f, {
        "short_name": "ATL03",
        "title": "simulated ATLAS/ICESat-2 L2A Global Geolocated Photon Data",
        "description": ("Simulated by lidar_mitsuba (first-principles Monte Carlo): photon "
                        "heights over a simulated surface; /truth holds the simulation truth"),
        "Conventions": "CF-1.6", "featureType": "trajectory",
        "granule_type": "ATL03", "identifier_product_type": "ATL03",
        "level": "L2", "processing_level": "2A",
        "lidar_mitsuba_version": __version__, "config": json.dumps(granule.config),
        "time_coverage_start": utc(t_first), "time_coverage_end": utc(t_last)})
    ancillary(f, instruments, t_first, t_last)
    orbit_info(f, granule, t_first)
    metadata(f, granule, instruments, t_first, t_last,
             path=f.filename if path is None else path)
    column_scales(f)
    h5chunks.set_attrs(f.require_group("truth"), {
        "crs": granule.crs, "frame_origin_m": np.asarray(granule.frame_origin_m, np.float64),
        "description": "simulation truth per beam; positions x, y in the CRS of attribute crs "
                       "less frame_origin_m [m], z and heights above the heights' datum [m]"})


def ancillary(f, instruments, t_first, t_last) -> None:
    """``ancillary_data`` (times, release, dead times, TEP) and ``atlas_impulse_response``."""
    a = f.create_group("ancillary_data")
    _ds(a, "atlas_sdp_gps_epoch", np.array([geotrack.ATLAS_SDP_GPS_EPOCH]), "seconds since "
        "1980-01-06T00:00:00.000000Z", "GPS seconds of the ATLAS SDP epoch 2018-01-01")
    for key, t in (("data_start_utc", t_first), ("granule_start_utc", t_first),
                   ("data_end_utc", t_last), ("granule_end_utc", t_last)):
        _ds(a, key, np.array([utc(t)]), "1", f"{key[:-4].replace('_', ' ')} (UTC)")
    for when, t in (("start", t_first), ("end", t_last)):
        week, sow = gps_week_sow(t)
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
                                "event by event (lidar_mitsuba.products.first_photon_bias)")
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


def orbit_info(f, granule, t_first) -> None:
    o = f.create_group("orbit_info")
    _ds(o, "sc_orient", np.array([granule.sc_orient], np.int8), "1",
        "spacecraft orientation: 0 backward (left beams strong), 1 forward, 2 transition")
    _ds(o, "sc_orient_time", np.array([t_first]), "seconds since 2018-01-01",
        "time of the orientation")
    orbit = granule.orbit
    for key, dtype in (("rgt", np.int16), ("cycle_number", np.int8), ("orbit_number", np.uint16)):
        if key in orbit:
            _ds(o, key, np.array([orbit[key]], dtype), "1",
                f"{key} of the repeat-orbit track the granule flies")
        else:
            _ds(o, key, np.array([0], dtype), "1", f"{key}: not applicable to a simulated track")


def metadata(f, granule, instruments, t_first, t_last, *, path) -> None:
    """The ``METADATA`` group of an ATL03 file to be found at ``path``
    (:func:`lidar_mitsuba.products.metadata.write_metadata`); ``Extent`` starts with the times
    and grows with the beams written (:func:`extend_extent`)."""
    meta.write_metadata(
        f, short_name="ATL03", path=path, config=granule.config, instruments=instruments,
        t_first=utc(t_first), t_last=utc(t_last),
        process="Photons traced by a first-principles Monte Carlo simulation (Mitsuba 3) "
        "over the simulated surface, detected by a modelled ATLAS detector (dead time, "
        "background), geolocated along the track and classified by histogram signal finding.")


extend_extent = meta.extend_extent


_COLUMN_SCALES = {5: "ds_surf_type", 3: "ds_xyz"}
"""The root dimension scales of a real granule's second axes: the surface types of
``signal_conf_ph`` and ``surf_type``, the east-north-up components of ``velocity_sc``."""


def column_scales(f) -> None:
    """The root dimension scales ``/ds_surf_type`` (1-5) and ``/ds_xyz`` (1-3)."""
    for n, name in _COLUMN_SCALES.items():
        ds = f.create_dataset(name, data=np.arange(1, n + 1, dtype=np.int32))
        ds.attrs["description"] = ("dimension scale of the surface types (land, ocean, sea "
                                   "ice, land ice, inland water)" if n == 5 else
                                   "dimension scale of the east, north, up components")
        ds.make_scale(name)


def dimension_scale(g) -> None:
    """Make ``g/delta_time`` the dimension scale of axis 0 of every dataset of group ``g``, and
    the root ``ds_surf_type`` or ``ds_xyz`` that of a second axis, as in real granules (xarray
    then names those dimensions ``delta_time``, ``ds_surf_type``, ``ds_xyz``)."""
    # (HDF5's own calls, as h5py's make_scale and attach_scale make them, in its order: the
    # group's members by name; h5py's objects for each member cost ~5x more. The datasets
    # the writer made are not opened again: h5write holds their ids and row shapes)
    fileno, prefix = g.id.fileno, g.name + "/"
    columns = {}

    def opened(name: bytes):
        known = h5chunks.dataset_id(fileno, prefix + name.decode())
        if known is not None:
            return known
        obj = h5o.open(g.id, name)
        return (obj, obj.shape[1:]) if isinstance(obj, h5d.DatasetID) else (None, None)

    t = opened(b"delta_time")[0]
    h5ds.set_scale(t, b"delta_time")
    for name in g.id:
        if name == b"delta_time":
            continue
        ds, tail = opened(name)
        if ds is None:
            continue
        h5ds.attach_scale(ds, t, 0)
        if len(tail) == 1:
            if tail[0] not in columns:
                columns[tail[0]] = h5d.open(g.id, f"/{_COLUMN_SCALES[tail[0]]}".encode())
            h5ds.attach_scale(ds, columns[tail[0]], 1)
