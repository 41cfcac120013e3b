"""Photon clouds where point-cloud users work: LAS 1.4 / LAZ export of an ATL03 file's photons
(ours or NASA's) with their classes, time and beam, for PDAL, CloudCompare, QGIS and laspy.

Each photon becomes a point of format 6 (LAS 1.4 R15, ASPRS 2019: the first format with a WKT
coordinate system and 15 returns):

* **x, y, z**: longitude, latitude [deg] and height above the WGS 84 ellipsoid [m] (ATL03
  ``lon_ph``, ``lat_ph``, ``h_ph``), scaled by 1e-7 deg (~1 cm) and 1 mm; the coordinate
  system is EPSG:4979 (WGS 84 geographic 3D) as an OGC WKT VLR (global encoding bit 4).
* **gps_time**: adjusted standard GPS time (global encoding bit 0; LAS 1.4 sec. 2.4), GPS
  seconds less 1e9: ``delta_time + 1198800018 - 1e9`` (ATL03 ``atlas_sdp_gps_epoch``,
  1198800018 s, the GPS seconds of 2018-01-01T00:00:00 UTC).
* **classification** (ASPRS standard classes, LAS 1.4 table 17): with an ATL08
  classification (ours, :mod:`lidar_mitsuba.products.atl08`, when ``classify=True``):
  ground 2, canopy 4 (medium vegetation), top of canopy 5 (high vegetation), noise 7 (low
  point, noise); without, from ATL03's ``signal_conf_ph`` (land column): 1 (unclassified:
  signal of confidence 2-4) or 7 (noise, buffer or no confidence).
* **point_source_id**: the beam's ATLAS spot number (1-6, beam group attribute
  ``atlas_spot_number``); **user_data**: ATL03's signal confidence of the photon (0-4; 255
  where it has none).
* **return_number / number_of_returns**: the photon's rank by height within its shot (the
  highest first: the earliest to arrive) and the shot's photon count, capped at 15.

Written and read here with laspy (LAZ through lazrs); tests/test_las.py reads the files back
with an independent reader (the LAS header and records parsed with numpy from the
specification; LAZ chunks decompressed by lazrs directly).
"""
from __future__ import annotations

import os
import pathlib

import numpy as np

from ..constants import ParameterError

ATLAS_SDP_GPS_EPOCH_S = 1198800018.0
"""GPS seconds of the ATLAS Standard Data Product epoch 2018-01-01T00:00:00 UTC (ATL03
``ancillary_data/atlas_sdp_gps_epoch``)."""
ADJUSTED_GPS_OFFSET_S = 1e9
"""LAS adjusted standard GPS time is GPS seconds less 1e9 (LAS 1.4 R15, global encoding)."""
ATL08_TO_ASPRS = {0: 7, 1: 2, 2: 4, 3: 5}
"""ATL08 ``classed_pc_flag`` -> ASPRS class: noise 7, ground 2, canopy 4, top of canopy 5."""
UNCLASSIFIED, NOISE = 1, 7
XY_SCALE_DEG, Z_SCALE_M = 1e-7, 1e-3
POINT_FORMAT = 6


def _beams_in(f) -> list[str]:
    from .real import BEAM_NAMES
    return [b for b in BEAM_NAMES if b in f and "heights" in f[b]]


def photons(path: str | os.PathLike, *, beams: list[str] | None = None,
            classify: bool = True) -> dict:
    """The points of :func:`export` as numpy arrays (``lon``, ``lat``, ``h``, ``gps_time``,
    ``classification``, ``point_source_id``, ``user_data``, ``return_number``,
    ``number_of_returns``), every photon of the beams (default: all the file has)."""
    import h5py
    with h5py.File(path, "r") as f:
        have = _beams_in(f)
        beams = have if beams is None else list(beams)
        for b in beams:
            if b not in have:
                raise ParameterError("beams", f"{path}: no ATL03 beam {b!r} (it has "
                                     f"{', '.join(have) or 'none'})")
        parts = [_beam_points(f, b) for b in beams]
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]} if parts else {}
    if classify and parts:
        from . import atl08
        cls = []
        for b, p in zip(beams, parts):
            a = atl08.from_atl03(path, b)
            c = np.full(p["h"].size, atl08.NOISE, np.int8)      # outside 20 m segments: noise
            c[a.atl03_index] = a.classification.classes
            asprs = np.zeros(256, np.uint8)
            for k, v in ATL08_TO_ASPRS.items():
                asprs[k] = v
            cls.append(asprs[c])
        out["classification"] = np.concatenate(cls)
    return out


def _beam_points(f, beam: str) -> dict:
    """One beam's photons as LAS point fields (module docstring)."""
    h = f[f"{beam}/heights"]
    n = h["h_ph"].shape[0]
    t = h["delta_time"][()]
    conf = h["signal_conf_ph"][:, 0] if "signal_conf_ph" in h else np.full(n, -1)
    spot = f[beam].attrs.get("atlas_spot_number", 0)
    spot = int(spot[0] if isinstance(spot, np.ndarray) else
               (spot.decode() if isinstance(spot, bytes) else spot))
    height = h["h_ph"][()].astype(np.float64)
    order = np.lexsort((-height, t))                  # per shot, the highest first
    ts = t[order]
    start = np.r_[True, ts[1:] != ts[:-1]]
    run_start = np.maximum.accumulate(np.where(start, np.arange(n), 0))
    rank = np.empty(n, np.int64)
    rank[order] = np.arange(n) - run_start + 1
    size = np.empty(n, np.int64)
    size[order] = np.bincount(np.cumsum(start) - 1)[np.cumsum(start) - 1]
    return {"lon": h["lon_ph"][()].astype(np.float64), "lat": h["lat_ph"][()].astype(np.float64),
            "h": height, "gps_time": t + ATLAS_SDP_GPS_EPOCH_S - ADJUSTED_GPS_OFFSET_S,
            "classification": np.where(conf >= 2, UNCLASSIFIED, NOISE).astype(np.uint8),
            "point_source_id": np.full(n, spot, np.uint16),
            "user_data": np.where(conf >= 0, conf, 255).astype(np.uint8),
            "return_number": np.minimum(rank, 15).astype(np.uint8),
            "number_of_returns": np.minimum(size, 15).astype(np.uint8)}


def write(points: dict, path: str | os.PathLike) -> pathlib.Path:
    """Write :func:`photons`' arrays as LAS 1.4 point format 6 (``.laz``: compressed by
    lazrs) with the EPSG:4979 WKT."""
    import laspy
    import pyproj
    path = pathlib.Path(path)
    header = laspy.LasHeader(point_format=POINT_FORMAT, version="1.4")
    header.scales = np.array([XY_SCALE_DEG, XY_SCALE_DEG, Z_SCALE_M])
    n = points["lon"].size
    header.offsets = (np.array([np.floor(points["lon"].min()), np.floor(points["lat"].min()),
                                np.floor(points["h"].min())]) if n else np.zeros(3))
    header.add_crs(pyproj.CRS.from_epsg(4979))        # WKT VLR, global encoding bit 4
    header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
    header.generating_software = "lidar_mitsuba"
    las = laspy.LasData(header)
    las.x, las.y, las.z = points["lon"], points["lat"], points["h"]
    for key in ("gps_time", "classification", "point_source_id", "user_data",
                "return_number", "number_of_returns"):
        setattr(las, key, points[key])
    las.write(str(path))
    return path


def export(atl03_path: str | os.PathLike, out_path: str | os.PathLike, *,
           beams: list[str] | None = None, classify: bool = True) -> pathlib.Path:
    """Every photon of an ATL03 file (ours or NASA's) to LAS/LAZ (module docstring);
    ``classify``: run our ATL08 classifier for ground and vegetation classes, else classes
    from ATL03's signal confidence.

    >>> from lidar_mitsuba.products import las
    >>> las.export("ATL03.h5", "photons.laz")                       # doctest: +SKIP
    """
    return write(photons(atl03_path, beams=beams, classify=classify), out_path)
