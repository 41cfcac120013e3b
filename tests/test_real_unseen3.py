"""The third hold-out round (session 28): public files the realism matrix had not met
(glaciersat2's ATL06 v001 over the Juneau Icefield, the same granule's v003 from
crossovers, xtrak's, GrIMP's v006, other tools' outputs), each reading bug made small.
Pure h5py; no rendering."""
from __future__ import annotations

import pathlib

import numpy as np
import pytest

from lidar_mitsuba.cli import main
from lidar_mitsuba.products import real
from lidar_mitsuba.studies import realism
from real_subsets import atl06_pair


def _atl06(path, *, release: str | None, dem: int = 2, asr=0, atm=0, n: int = 8):
    """An ATL06 beam pair as glaciersat2's NSIDC subsets of release 001 keep it: both cloud
    flags 0 on every segment (``ATL06_20181014001049_02350102_001_01``, where the granule's
    release 003 has ``cloud_flg_asr`` 5 on every segment), ``dem_flag`` 2 (``gmted``: land,
    the Juneau Icefield) or 4 (``antarctic``: land ice), r_eff 0.08."""
    return atl06_pair(path, release=release, dem=dem, asr=asr, atm=atm, n=n)


def test_release_001_cloud_flags_left_at_0_are_not_read_as_clear(tmp_path):
    """Release 001 (and the pre-release 209) left cloud_flg_asr and cloud_flg_atm at 0 on
    every segment: off an ice sheet, where the flags alone decide, they called every
    segment of a cloudy pass clear (Juneau, r_eff 0.08 on a glacier; release 003 of the same
    granule: cloudy everywhere). Now they are not filled: no cloud flag, said in the line."""
    rf = real.read_product(_atl06(tmp_path / "ATL06_20181014001049_02350102_001_01.h5",
                                  release="001"))
    b = rf.beams[0]
    assert b.surface == "land" and b.clear is None and b.layer_count is None
    line = rf.missing_line()
    assert "cloud flags (all segments taken as clear)" in line
    assert "0 on every segment, as release 001 and the pre-releases leave them" in line
    pre = real.read_product(_atl06(tmp_path / "ATL06_20181013235645_02340114_209_01.h5",
                                   release=None))             # (the release from the name)
    assert pre.release == "209" and pre.beams[0].clear is None
    # a later release's zeros are the flags' word: clear; a 001 flag that moves is read
    later = real.read_product(_atl06(tmp_path / "ATL06_x_006_01.h5", release="006"))
    assert later.beams[0].clear.all() and "release 001" not in later.missing_line()
    moved = real.read_product(_atl06(tmp_path / "ATL06_y_001_01.h5", release="001", atm=1))
    assert not moved.beams[0].clear.any()
    # on an ice sheet r_eff decides with the flags (the seven files' polar-night v001):
    # nothing changes there, nothing is said
    ice = real.read_product(_atl06(tmp_path / "ATL06_z_001_01.h5", release="001", dem=4))
    assert ice.beams[0].surface == "land ice" and not ice.beams[0].clear.any()
    assert ice.beams[0].layer_count is not None and "release 001" not in ice.missing_line()


def test_a_folder_gives_its_hdf_named_files_too(tmp_path, capsys):
    """ICESat-2_SVDA names its ATL03 cuts ``ATL03_Ground_..._gt1l.hdf``: a folder of them was
    'no HDF5 file' though each can be named; now ``.hdf`` is found, and one that is not HDF5
    (an HDF4 file of that name) is passed by with its reason."""
    import h5py
    good = _atl06(tmp_path / "ATL06_20181128031527_09240105_006_01_gt1l.hdf", release=None,
                  dem=4)
    (tmp_path / "MOD35_L2.A2023001.hdf").write_bytes(b"\x0e\x03\x13\x01" + b"\0" * 64)
    found = realism.real_files([tmp_path])
    assert [p.name for p in found] == ["ATL06_20181128031527_09240105_006_01_gt1l.hdf",
                                       "MOD35_L2.A2023001.hdf"]
    assert real.read_product(good).release == "006"            # from the name, as for .h5
    out = tmp_path / "out"
    assert main(["validate", "--real", str(tmp_path), "--signal-shots", "0",
                 "--out", str(out)]) == 0
    md = (out / "realism.md").read_text()
    assert f"{good.name} (ATL06)" in md
    assert "MOD35_L2.A2023001.hdf: passed by (" in md and "not an HDF5 file" in md
    with h5py.File(good, "a") as f:                             # (a flattened table only)
        del f["gt1l"], f["gt1r"]
        f["Ground_20200320133708_gt1l/block0_values"] = np.zeros((4, 3))
    with pytest.raises(Exception, match="it holds Ground_20200320133708_gt1l"):
        realism.read_files(realism.real_files([tmp_path]), twins=False,
                           skippable=realism.real_files([tmp_path]))


FOREST_PAIR = ("ATL03_gt1r_20220401_forest_wyoming.h5", "ATL08_gt1r_20220401_forest_wyoming.h5")


@pytest.mark.parametrize("name,mode,expect", [
    ("land_segments/segment_landcover", "delete", "agrees|disagrees"),
    ("land_segments/canopy/segment_cover", "fill", "surface missing"),
    ("land_segments/canopy/n_toc_photons", "delete", "ATL08 not measured"),
    ("signal_photons/ph_h", "delete", "ATL03 signal not measured"),
    ("signal_photons/classed_pc_flag", "fill", "agrees|disagrees"),
    ("land_segments/segment_id_beg", "delete", "agrees|disagrees"),
    ("ATL03 geolocation/ph_index_beg", "delete", "surface missing"),
    ("ATL03 bckgrd_atlas/delta_time", "delete", "agrees|disagrees"),
])
def test_a_forest_pairs_atl08_missing_a_dataset_or_at_fill(tmp_path, name, mode, expect):
    """Every dataset of the forest pair's ATL08 deleted, then set to its fill, one at a time
    (session 28: 12 of 93 deleted and 2 filled raised a traceback or stopped with an error on
    an option nobody gave, ``--cover``): these six stand for the paths they took. The twin is
    not made without its stand's inputs (the rows: *surface missing*); NASA's counts or
    ground missing leave the rows' signal *not measured*, said; the classifier comparison
    passes a beam by, said; a fill class is no class."""
    import shutil
    import h5py
    from lidar_mitsuba.studies import atl08_real
    src = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "real"
    if not all((src / f).exists() for f in FOREST_PAIR):
        pytest.skip("the real forest pair is not here (../shared/real)")
    for f in FOREST_PAIR:
        shutil.copy(src / f, tmp_path / f)
    target = FOREST_PAIR[0] if name.startswith("ATL03 ") else FOREST_PAIR[1]
    name = name.removeprefix("ATL03 ")
    with h5py.File(tmp_path / target, "a") as f:
        key = f"gt1r/{name}"
        if mode == "delete":
            del f[key]
        else:
            ds = f[key]
            ds[...] = 127 if ds.dtype.kind in "iu" else np.finfo(np.float32).max
    lines = []
    doc = realism.run([tmp_path], tmp_path / "out", signal_shots=200, progress=lines.append)
    atl08_real.run([tmp_path], tmp_path / "out", progress=lines.append)
    rows = {r["product"]: r for r in doc["rows"]}
    if expect == "surface missing":
        assert {r["verdict"] for r in rows.values()} == {"surface missing"}
        assert any(name.split("/")[-1] in line and ("forest twin" in line or "passed by" in line)
                   for line in lines)
    elif expect == "ATL08 not measured":
        r = rows["ATL08"]
        assert r["measured"]["signal_forest"] is None and r["verdict"] == "not measured"
    elif expect == "ATL03 signal not measured":
        r = rows["ATL03"]
        assert r["measured"]["signal_forest"] is None and "signal not measured" in r["reason"]
    else:
        assert {r["verdict"] for r in rows.values()} <= {"agrees", "disagrees"}
    if mode == "delete" and (name in atl08_real.NEEDS or target == FOREST_PAIR[0]
                             and name.startswith(("heights", "geolocation"))):
        assert any("passed by" in line and name in line for line in lines)   # (what it reads)


def test_our_atl08_of_an_atl03_lacking_its_segments_is_a_one_line_error(tmp_path, capsys):
    """``lidar-mitsuba atl08`` of an ATL03 beam a subset stripped of what ATL08 reads (its 20 m
    segments' photon index) stops in one line naming the datasets, exit 2, no output."""
    import shutil
    import h5py
    src = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "real"
    if not (src / FOREST_PAIR[0]).exists():
        pytest.skip("the real forest pair is not here (../shared/real)")
    a03 = tmp_path / FOREST_PAIR[0]
    shutil.copy(src / FOREST_PAIR[0], a03)
    with h5py.File(a03, "a") as f:
        del f["gt1r/geolocation/ph_index_beg"]
    out = tmp_path / "ATL08.h5"
    rc = main(["atl08", str(a03), "--beams", "gt1r", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "ph_index_beg" in err[0]
    assert "Traceback" not in err[0] and not out.exists()
