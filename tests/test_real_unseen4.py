"""The fourth hold-out round (session 29): public files the realism matrix had not met
(harmony-trajectory-subsetter's ATL03 v006 cut ``ATL03_gt1l.h5``, OPeNDAP's ATL16 ``.nc4``,
Floes-are-Swell's ``atl012.nc``, Snowblower's and Floes-are-Swell's earlier v001 outputs),
each reading bug made small. Pure h5py; no rendering."""
from __future__ import annotations

import numpy as np
import pytest

from lidar_mitsuba.cli import main
from lidar_mitsuba.products import real
from real_subsets import atl06_pair


def _atl06_cut(path, *, version: str | None, n: int = 8):
    """An ATL06 beam pair as a trajectory subsetter leaves it: the beam groups and
    ``METADATA`` (its ``DatasetIdentification`` naming the release), no ``ancillary_data``,
    the file renamed without the granule's ``_RRR_VV`` tail (harmony-trajectory-subsetter's
    ``ATL03_gt1l.h5`` of ``ATL03_20181014002445_02350104_006_02``). Release 001's cloud
    flags, 0 on every segment, over GMTED land (``dem_flag`` 2), r_eff 0.08."""
    return atl06_pair(path, version=version, n=n)


def test_the_release_of_a_renamed_cut_is_read_from_its_metadata(tmp_path):
    """harmony-trajectory-subsetter's cut keeps ``METADATA`` (``VersionID`` 006) but neither
    ``ancillary_data`` nor the granule's name: the line said it lacked its release, and a
    release-001 ATL06 cut so kept had its unfilled cloud flags (0 everywhere) read as a clear
    sky. The release is now read from ``METADATA/DatasetIdentification``."""
    rf = real.read_product(_atl06_cut(tmp_path / "ATL06_gt1l.h5", version="001"))
    assert rf.release == "001"
    assert rf.beams[0].clear is None                       # (the flags not read: no flag)
    assert "as release 001 and the pre-releases leave them" in rf.missing_line()
    assert "release (" not in rf.missing_line()
    none = real.read_product(_atl06_cut(tmp_path / "ATL06_cut.h5", version=None))
    assert none.release is None and "release (ancillary_data/release" in none.missing_line()


def test_a_name_with_three_digits_after_atl_is_not_atl0x(tmp_path, capsys):
    """Floes-are-Swell's ``atl012.nc`` (a user's name for an ATL12 table: ``h``, ``swh``,
    ``seg_dist``, no ``short_name``) was refused as an ATL01; now it is no product we read,
    saying what it holds."""
    import h5py
    path = tmp_path / "atl012.nc"
    with h5py.File(path, "w") as f:
        for k in ("seg_dist", "h", "swh", "lat", "lon", "delta_time"):
            f[k] = np.zeros(4)
    rc = main(["validate", "--real", str(path), "--signal-shots", "0",
               "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--real" in err[0] and "atl012.nc" in err[0]
    assert "ATL01" not in err[0] and "(it holds delta_time, h, lat, lon, seg_dist" in err[0]


@pytest.mark.parametrize("value", [np.zeros(0, np.int8), np.array([2], np.int8),
                                   np.array([127], np.int8)])
def test_an_empty_transition_or_fill_sc_orient_gives_no_layout(tmp_path, value):
    """``orbit_info/sc_orient`` as a subset can leave it: empty (its ``sc_orient_time`` rows
    cut), 2 (the yaw flip's transition) or its fill 127. Empty raised an IndexError (a
    traceback); 2 and 127 were taken as backward, the strengths said to come "from
    sc_orient". Now none gives a layout: without ``atlas_beam_type`` the pairs' signal rates
    decide, said in the line."""
    import h5py
    path = _atl06_cut(tmp_path / "ATL06_20181027014737_04340110_001_01.h5", version="001")
    with h5py.File(path, "a") as f:
        f["orbit_info/sc_orient"] = value
        for name in ("gt1l", "gt1r"):
            del f[name].attrs["atlas_beam_type"]
            s = f[name]["land_ice_segments"]
            s["fit_statistics/n_fit_photons"] = np.full(8, 150 if name == "gt1r" else 40,
                                                        np.int32)
            s["fit_statistics/w_surface_window_final"] = np.full(8, 3.0, np.float32)
            s["fit_statistics/n_seg_pulses"] = np.full(8, 57.0, np.float32)
    rf = real.read_product(path)
    assert rf.sc_orient == 1                         # (a strong right beam: forward)
    assert [b.strength for b in rf.beams] == ["weak", "strong"]
    assert "strength from sc_orient" not in rf.missing_line()
