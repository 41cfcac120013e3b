"""Subsets that dropped a dataset or hold fill in it (found by deleting, or filling with its
``_FillValue``, each dataset ``validate --real`` reads, one at a time, in copies of the
shipped real files): never a traceback, an error naming an option the user did not give, or
a verdict of *agrees* on nothing compared; a dataset that is fill everywhere reads as one
that is absent. Pure h5py and the lidar equation (``--signal-shots 0``); no rendering."""
from __future__ import annotations

import json
import pathlib
import re
import shutil

import h5py
import numpy as np
import pytest

from lidar_mitsuba.cli import main
from lidar_mitsuba.products import real

DATA = pathlib.Path(real.__file__).resolve().parents[1] / "data"
ATL03 = DATA / "ATL03_gt1l_20181014.h5"
PINE = DATA / "ATL06_20181015100401_02560110_003_01_pine_island.h5"
NIGHT = DATA / "ATL06_20181226035130_13520105_001_01_greenland_night.h5"
JAKOBSHAVN = DATA / "ATL06_20190420093051_03380303_005_01_jakobshavn.h5"


def _copy(src: pathlib.Path, dst: pathlib.Path, *, delete=(), fill=()) -> pathlib.Path:
    """``src`` copied to ``dst`` with each beam's datasets ``delete`` removed and ``fill``
    set to their ``_FillValue`` (their type's maximum where they have none)."""
    shutil.copy(src, dst)
    with h5py.File(dst, "r+") as f:
        for beam in [k for k in f if re.fullmatch(r"gt[123][lr]", k)]:
            for rel in delete:
                if f"{beam}/{rel}" in f:
                    del f[f"{beam}/{rel}"]
            for rel in fill:
                if f"{beam}/{rel}" not in f:
                    continue
                d = f[f"{beam}/{rel}"]
                v = d.attrs.get("_FillValue")
                if v is None:
                    v = (np.finfo(d.dtype).max if d.dtype.kind == "f"
                         else np.iinfo(d.dtype).max)
                d[...] = v
    return dst


def _rows(path, tmp_path, capsys) -> list[dict]:
    out = tmp_path / "out"
    assert main(["validate", "--real", str(path), "--signal-shots", "0", "--out",
                 str(out)]) == 0
    capsys.readouterr()
    return json.loads((out / "realism.json").read_text())["rows"]


@pytest.mark.parametrize("src, delete, fill, words", [
    (JAKOBSHAVN, ["land_ice_segments/latitude"], [], "no land_ice_segments/latitude"),
    (JAKOBSHAVN, [], ["land_ice_segments/delta_time"],
     "fewer than two segments with a finite land_ice_segments/delta_time"),
    (JAKOBSHAVN, ["land_ice_segments"], [], "no beam group (gt1l-gt3r) with two "
                                            "land_ice_segments segments (gt1l holds")])
def test_a_beam_without_a_time_or_place_stops_the_run_in_one_line(tmp_path, capsys, src,
                                                                   delete, fill, words):
    """No latitude (was: a TypeError deep in the matrix; ATL03 stands in its photons'
    lat_ph, tests/test_real_unseen.py), times all fill (was: an error on
    --pulse-energy-uj, an option nobody gave), the segment group gone (was: "ATL06 is not
    read" of an ATL06): exit 2, one line naming --real, the file and what it lacks."""
    (tmp_path / "cut").mkdir()
    bad = _copy(src, tmp_path / "cut" / src.name, delete=delete, fill=fill)
    assert main(["validate", "--real", str(bad), "--signal-shots", "0",
                 "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--real" in err and src.name in err
    assert words in err and "is not read" not in err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_atl03_fill_in_its_photon_ids_and_rows_is_no_rate(tmp_path):
    """``ph_index_beg``, the pulse ids and the background rows' times all fill (was: a
    ValueError; a signal rate from garbage pulse counts; a background from garbage rows):
    those rates are missing and said so; ``surf_type`` fill is an unknown surface, not land
    ice."""
    f = real.read_product(_copy(ATL03, tmp_path / "a.h5", fill=["geolocation/ph_index_beg"]))
    b = f.beams[0]
    assert b.signal_per_shot is None and not np.isfinite(b.surface_h_m).any()
    assert "geolocation/ph_index_beg" in f.missing_line()
    f = real.read_product(_copy(ATL03, tmp_path / "b.h5", fill=["heights/ph_id_pulse"]))
    assert f.beams[0].signal_per_shot is None and "ph_id_pulse hold fill" in f.missing_line()
    f = real.read_product(_copy(ATL03, tmp_path / "c.h5", fill=["bckgrd_atlas/delta_time"]))
    assert f.beams[0].background_hz is None
    assert "bckgrd_atlas/delta_time holds fill" in f.missing_line()
    f = real.read_product(_copy(ATL03, tmp_path / "d.h5", fill=["geolocation/surf_type"]))
    assert f.beams[0].surface == "unknown" and "surf_type" in f.missing_line()
    whole = real.read_product(ATL03).beams[0]
    assert whole.surface == "sea ice" and whole.signal_per_shot is not None


@pytest.mark.parametrize("name", ["cloud_flg_asr", "cloud_flg_atm", "r_eff"])
def test_a_flag_that_is_fill_everywhere_reads_as_one_that_is_absent(tmp_path, name):
    """Jakobshavn's clear segments with a cloud flag all fill are those without it (was:
    every segment cloudy, "cloud missing" on a clear day)."""
    rel = f"land_ice_segments/geophysical/{name}"
    filled = real.read_product(_copy(JAKOBSHAVN, tmp_path / "f.h5", fill=[rel]))
    gone = real.read_product(_copy(JAKOBSHAVN, tmp_path / "g.h5", delete=[rel]))
    for a, b in zip(filled.beams, gone.beams):
        assert np.array_equal(a.clear, b.clear)
        assert a.clear.mean() > 0.9            # (the day is clear: 0.96-1.0 by every flag)


def test_no_background_and_no_signal_compared_is_not_measured(tmp_path, capsys):
    """Pine Island's beams are all cloudy and ATL06's signal is not compared (r_eff is made
    from it): without ``bckgrd`` nothing is compared (was: "agrees")."""
    rows = _rows(_copy(PINE, tmp_path / "p.h5", delete=["land_ice_segments/geophysical/"
                                                         "bckgrd"]), tmp_path, capsys)
    assert rows and all(r["verdict"] == "not measured" for r in rows)
    assert any("nothing to compare" in r["reason"] for r in rows)


def test_a_cloud_without_its_height_is_run_inside_and_above_the_band(tmp_path, capsys):
    """The polar-night file without ``msw_flag``: the cloud's height is unknown, so it is run
    in the lowest class (inside the band) and above the band, and the verdict says the file
    does not place it (was: the default inside the band alone, "disagrees" x5.7, x11)."""
    base = {r["beam"]: r for r in _rows(NIGHT, tmp_path, capsys)}
    assert all(not any(a.get("height_unknown") for a in r["predicted"]["cloud_alternatives"])
               for r in base.values())            # (the file places its layer: msw_flag 1)
    cut = _copy(NIGHT, tmp_path / "n.h5", delete=["land_ice_segments/geophysical/msw_flag"])
    out = tmp_path / "cut_out"
    assert main(["validate", "--real", str(cut), "--signal-shots", "0", "--out",
                 str(out)]) == 0
    capsys.readouterr()
    rows = json.loads((out / "realism.json").read_text())["rows"]
    assert {r["beam"] for r in rows} == set(base)
    for r in rows:
        alts = r["predicted"]["cloud_alternatives"]
        assert any(a["above_band"] and a["height_unknown"] for a in alts)
        assert r["verdict"] == "cloud uncertain" and "no msw_flag" in r["reason"]


def test_bad_values_name_their_own_option_and_leave_nothing(tmp_path, capsys):
    """Found by a fuzz of every option with -1, nan, abc, 1e30, 0: ``make-dem --lat nan``
    named --lon; ``simulate --slope-azimuth-deg nan`` named --azimuth-deg (the plane's own
    field); ``atl08 --plot NAME`` with a bad name wrote the ATL08 file and then stopped."""
    cases = [(["make-dem", "--out", str(tmp_path / "d.tif"), "--lat", "nan"], "--lat", "d.tif"),
             (["simulate", "--surface", "flat", "--shots", "10", "--out", str(tmp_path / "s.h5"),
               "--slope-azimuth-deg", "nan"], "--slope-azimuth-deg", "s.h5"),
             (["atl08", str(ATL03), "--out", str(tmp_path / "a.h5"), "--plot", "pic"],
              "--plot", "a.h5")]
    for args, option, made in cases:
        assert main(args) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"error: {option}:" in err, err
        assert not (tmp_path / made).exists()


BAFFIN_LOWSUN = DATA / "ATL07-01_20190225115500_09020201_003_02_baffin_lowsun.h5"


@pytest.mark.parametrize("src", [JAKOBSHAVN, BAFFIN_LOWSUN], ids=["ATL06", "ATL07"])
def test_every_dataset_it_reads_dropped_or_filled(tmp_path, src):
    """The fuzz this file's cases came from, kept: each dataset of the shipped (trimmed: only
    what the matrix reads) ATL06 and ATL07 deleted, then set to its fill, one at a time. The
    matrix either runs, with no row agreeing on nothing compared, or stops with a one-line
    ParameterError; nothing else (a traceback, an error on another option) is allowed."""
    from lidar_mitsuba.constants import ParameterError
    from lidar_mitsuba.studies import realism
    with h5py.File(src) as f:
        rels = set()
        f.visititems(lambda name, obj: rels.add(name.split("/", 1)[1]) if (
            isinstance(obj, h5py.Dataset) and re.fullmatch(r"gt[123][lr]", name.split("/")[0])
            and "/" in name) else None)
    assert len(rels) >= 10
    ratios = ("background_ratio", "signal_ratio", "background_cloudy_ratio",
              "signal_cloudy_ratio")
    for rel in sorted(rels):
        for op in ("delete", "fill"):
            copy = _copy(src, tmp_path / f"{op}.h5", **{op: [rel]})
            try:
                doc = realism.run([copy], None, signal_shots=0)
            except ParameterError as e:      # (the file's option, not another's)
                assert e.name in ("real", "like") and "\n" not in str(e), (op, rel, str(e))
                continue
            for r in doc["rows"]:
                if r["verdict"] == "agrees":
                    assert any(r.get(k) is not None for k in ratios), (op, rel, r["reason"])
