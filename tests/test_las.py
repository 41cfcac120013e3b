"""LAS/LAZ export of photons (issue 42), read back by a reader independent of laspy's: the
LAS 1.4 header, VLRs and point records parsed here with numpy from the specification (ASPRS
LAS 1.4 R15, tables 3, 4 and 18), LAZ chunks decompressed by lazrs directly (the Rust
LASzip, which laspy only calls to compress)."""
from __future__ import annotations

import io
import pathlib
import struct

import numpy as np
import pytest

from lidar_mitsuba.products import las

REAL_ATL03 = (pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "real"
              / "ATL03_gt1r_20220401_forest_wyoming.h5")
pytestmark = pytest.mark.skipif(not REAL_ATL03.exists(),
                                reason="the real forest clip is not on this machine")

POINT6 = np.dtype([("X", "<i4"), ("Y", "<i4"), ("Z", "<i4"), ("intensity", "<u2"),
                   ("returns", "u1"), ("flags", "u1"), ("classification", "u1"),
                   ("user_data", "u1"), ("scan_angle", "<i2"), ("point_source_id", "<u2"),
                   ("gps_time", "<f8")])
"""Point data record format 6, 30 bytes (LAS 1.4 R15 table 18)."""


def read_las(path) -> tuple[dict, list, np.ndarray]:
    """(header fields, VLRs as (user_id, record_id, data), points) of a LAS 1.4 file or LAZ."""
    raw = open(path, "rb").read()
    assert raw[:4] == b"LASF"
    hd = {"global_encoding": struct.unpack_from("<H", raw, 6)[0],
          "version": struct.unpack_from("<BB", raw, 24),
          "header_size": struct.unpack_from("<H", raw, 94)[0],
          "offset_to_points": struct.unpack_from("<I", raw, 96)[0],
          "n_vlrs": struct.unpack_from("<I", raw, 100)[0],
          "format": struct.unpack_from("<B", raw, 104)[0],
          "record_length": struct.unpack_from("<H", raw, 105)[0],
          "scale": np.frombuffer(raw, "<f8", 3, 131), "offset": np.frombuffer(raw, "<f8", 3, 155),
          "n_points": struct.unpack_from("<Q", raw, 247)[0]}
    vlrs, pos = [], hd["header_size"]
    for _ in range(hd["n_vlrs"]):
        user = raw[pos + 2:pos + 18].rstrip(b"\0").decode()
        rec, length = struct.unpack_from("<HH", raw, pos + 18)
        vlrs.append((user, rec, raw[pos + 54:pos + 54 + length]))
        pos += 54 + length
    body = raw[hd["offset_to_points"]:]
    if hd["format"] & 0x80:                     # LAZ: bit 7 of the format id
        import lazrs
        vlr = next(d for u, r, d in vlrs if u == "laszip encoded" and r == 22204)
        out = bytearray(hd["n_points"] * hd["record_length"])
        # LAZ point data (the chunk table's absolute offset, the chunks, the table): the
        # whole file as the stream, at the point data
        src = io.BytesIO(raw)
        src.seek(hd["offset_to_points"])
        lazrs.LasZipDecompressor(src, vlr).decompress_many(out)
        body = bytes(out)
    pts = np.frombuffer(body, POINT6, hd["n_points"])
    return hd, vlrs, pts


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_export_reads_back_independently(tmp_path, suffix):
    """Every photon of the real clip's gt1r, classed by signal confidence (fast: no
    classifier), written and read back: coordinates within half a scale step, GPS time,
    classes, beam, confidence, returns, and the WKT of EPSG:4979."""
    pts = las.photons(REAL_ATL03, classify=False)
    path = las.write(pts, tmp_path / f"photons{suffix}")
    hd, vlrs, got = read_las(path)
    assert hd["version"] == (1, 4) and hd["format"] & 0x7F == 6 and hd["record_length"] == 30
    assert hd["n_points"] == pts["lon"].size == 6809
    assert hd["global_encoding"] & 0b10001 == 0b10001          # WKT, standard GPS time
    wkt = [d for u, r, d in vlrs if u == "LASF_Projection" and r == 2112]
    assert wkt and b"4979" in wkt[0]
    xyz = [got[k] * hd["scale"][i] + hd["offset"][i] for i, k in enumerate("XYZ")]
    for v, key, half in zip(xyz, ("lon", "lat", "h"), hd["scale"] / 2):
        assert np.max(np.abs(v - pts[key])) <= half * (1 + 1e-6), key
    assert np.array_equal(got["gps_time"], pts["gps_time"])
    # 2022-04-01 in adjusted standard GPS time: 1.333e9 - 1e9 ~ 3.33e8 s
    assert 3.3e8 < got["gps_time"].min() < 3.4e8
    assert np.array_equal(got["classification"], pts["classification"])
    assert set(np.unique(got["classification"])) <= {1, 7}
    assert np.all(got["point_source_id"] == 2)                  # gt1r is spot 2 here
    assert np.array_equal(got["user_data"], pts["user_data"])
    ret, nret = got["returns"] & 0x0F, got["returns"] >> 4
    assert np.all((ret >= 1) & (ret <= nret))


def test_export_with_atl08_classes(tmp_path):
    """With our ATL08 classes: ASPRS ground 2, vegetation 4 and 5, noise 7 only, and each
    of ground, vegetation and noise present in the forest clip."""
    path = las.export(REAL_ATL03, tmp_path / "classed.laz")
    _, _, got = read_las(path)
    classes = set(np.unique(got["classification"]))
    assert classes <= {2, 4, 5, 7} and {2, 7} <= classes and classes & {4, 5}
