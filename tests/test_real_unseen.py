"""Real files the realism matrix had not met (issue 41's hold-out): what public subsets and
old releases hold, each made small in the test as the fetched file had it. A file that
cannot be used stops ``validate --real`` in one line naming the option and the file (exit
2, nothing written); one that lacks a dataset is read with what stands in, said in the
file's line. Pure h5py; no rendering."""
from __future__ import annotations

import pathlib

import numpy as np
import pytest

from lidar_mitsuba.cli import main
from lidar_mitsuba.constants import ParameterError
from lidar_mitsuba.products import real
from lidar_mitsuba.studies import realism


def _atl08(path, *, rates=(4.0, 1.0), n: int = 12):
    """An ATL08 subset as a test suite keeps it: ``gtxx/land_segments`` only, no group
    attributes, no ``orbit_info`` (nsidc-icesat2gis tests/data/test_atl08.h5)."""
    import h5py
    with h5py.File(path, "w") as f:
        for name, rate in zip(("gt1l", "gt1r"), rates):
            s = f.create_group(f"{name}/land_segments")
            s["delta_time"] = 1.0e8 + np.arange(n) * 100.0 / 7000.0
            s["latitude"] = (45.0 + np.arange(n) * 100.0 / 111_000.0).astype(np.float32)
            s["longitude"] = np.full(n, -110.0, np.float32)
            s["terrain/h_te_best_fit"] = np.full(n, 1500.0, np.float32)
            s["terrain/photon_rate_te"] = np.full(n, rate, np.float32)
            s["canopy/photon_rate_can"] = np.full(n, 3.4028235e38, np.float32)   # fill
    return path


def test_a_file_it_cannot_use_stops_the_run_in_one_line(tmp_path, capsys):
    """ATL24 (harmony-trajectory-subsetter's variable subset) and an ATL03 cut to
    ``ph_index_beg``: exit 2, one line naming --real, the file and why; nothing written,
    even beside a good file."""
    import h5py
    bad = tmp_path / "variable_subset_ATL24_data.h5"
    with h5py.File(bad, "w") as f:
        f["gt1l/sensor_depth_exceeded"] = np.zeros(4, np.uint8)
    cut = tmp_path / "ATL03_index.h5"
    with h5py.File(cut, "w") as f:
        f["ph_index_beg"] = np.arange(4)
    good = _atl08(tmp_path / "ATL08_ok.h5")
    out = tmp_path / "out"
    assert main(["validate", "--real", str(good), str(bad), "--signal-shots", "0",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--real" in err and bad.name in err
    assert "ATL24 is not read" in err and "--like" not in err
    assert not out.exists() or not any(out.iterdir())
    with pytest.raises(ParameterError, match=r"ATL03_index.h5: no beam group .* \(it holds "
                       r"ph_index_beg\)") as e:
        realism.read_files([good, cut], twins=False)
    assert e.value.name == "real"
    with pytest.raises(ParameterError) as e:
        real.read_product(bad)
    assert e.value.name == "like"                  # the twin's own option, under simulate
    # the same files found in a folder the user named: the two it cannot use are passed
    # by, each with its reason in the report's Files; a folder of nothing usable stops it
    folder = tmp_path / "folder"
    folder.mkdir()
    for p in (good, bad, cut):
        p.rename(folder / p.name)
    assert main(["validate", "--real", str(folder), "--signal-shots", "0",
                 "--out", str(out)]) == 0
    md = (out / "realism.md").read_text()
    assert f"{bad.name}: passed by (" in md and "ATL24 is not read" in md
    assert f"{cut.name}: passed by (" in md and "ATL08_ok.h5 (ATL08)" in md
    (folder / good.name).unlink()
    with pytest.raises(ParameterError, match="no usable file: .*ATL24 is not read"):
        realism.read_files(realism.real_files([folder]), twins=False,
                           skippable=realism.real_files([folder]))


def test_strength_from_the_pairs_when_the_file_says_nothing(tmp_path):
    """No atlas_beam_type, no sc_orient: the pair's 4:1 signal makes gt1l strong (spot 1,
    backward), said in the file's line; rates that do not tell stop it in one line."""
    rf = real.read_product(_atl08(tmp_path / "ATL08_a.h5"))
    assert [(b.name, b.strength, b.spot, b.strength_from) for b in rf.beams] == [
        ("gt1l", "strong", 1, "signal rates"), ("gt1r", "weak", 2, "signal rates")]
    assert rf.sc_orient == 0 and "pairs' signal rates" in rf.missing_line()
    assert "a background rate (ATL08 has none)" in rf.missing_line()
    assert [b.name for b in real.read_product(tmp_path / "ATL08_a.h5", beams="weak").beams] \
        == ["gt1r"]
    swapped = real.read_product(_atl08(tmp_path / "ATL08_b.h5", rates=(1.0, 4.0)))
    assert [b.strength for b in swapped.beams] == ["weak", "strong"] and swapped.sc_orient == 1
    with pytest.raises(ParameterError, match=r"ATL08_c.h5: neither .* \(left / right: 1.20\)"):
        real.read_product(_atl08(tmp_path / "ATL08_c.h5", rates=(1.2, 1.0)))


def test_an_atl03_clip_without_confident_photons_measures_no_signal(tmp_path):
    """An ATL03 clip whose photons are all of confidence <= 2 (ICESat2VegR's earlier
    atl03_clip.h5): its signal is not read as 0 per shot but as missing, and said."""
    import h5py
    path = tmp_path / "atl03_clip.h5"
    n_seg, per = 4, 30
    with h5py.File(path, "w") as f:
        g = f.create_group("gt1r")
        g.attrs["atlas_beam_type"] = "weak"
        geo = g.create_group("geolocation")
        geo["delta_time"] = 1.0e8 + np.arange(n_seg) * 20.0 / 7000.0
        geo["reference_photon_lat"] = 59.0 + np.arange(n_seg) * 20.0 / 111_000.0
        geo["reference_photon_lon"] = np.full(n_seg, -103.0)
        geo["segment_ph_cnt"] = np.full(n_seg, per, np.int32)
        geo["ph_index_beg"] = 1 + np.arange(n_seg) * per
        m = n_seg * per
        g["heights/h_ph"] = np.full(m, 300.0, np.float32)
        conf = np.zeros((m, 5), np.int8)
        conf[::3, 0] = 2
        g["heights/signal_conf_ph"] = conf
        g["heights/pce_mframe_cnt"] = (np.arange(m) // 120).astype(np.uint32)
        g["heights/ph_id_pulse"] = (np.arange(m) % 120 // 4 + 1).astype(np.uint8)
    rf = real.read_product(path)
    assert rf.beams[0].signal_per_shot is None
    assert np.isfinite(rf.beams[0].surface_h_m).all()     # heights from confidence 2
    assert "a signal rate (no photon of signal_conf_ph >= 3)" in rf.missing_line()


def _atl06_dem(path, *, flag: int, dem_h: float):
    """An ATL06 of release 209 over the open Pacific (the 2018 hackweek tutorial's file):
    dem_flag 2 (``gmted``) with the DEM at the geoid, r_eff 0.02, the cloud flags clear."""
    import h5py
    n = 8
    with h5py.File(path, "w") as f:
        for name in ("gt1l", "gt1r"):
            g = f.create_group(name)
            g.attrs["atlas_beam_type"] = "strong" if name == "gt1l" else "weak"
            s = g.create_group("land_ice_segments")
            s["delta_time"] = 2.4e7 + np.arange(n) * 20.0 / 7000.0
            s["latitude"] = -24.0 + np.arange(n) * 20.0 / 111_000.0
            s["longitude"] = np.full(n, -124.5)
            s["h_li"] = np.full(n, -9.0, np.float32)
            s["geophysical/r_eff"] = np.full(n, 0.02, np.float32)
            s["geophysical/cloud_flg_asr"] = np.zeros(n, np.int8)
            s["geophysical/cloud_flg_atm"] = np.zeros(n, np.int8)
            d = s.create_dataset("dem/dem_flag", data=np.full(n, flag, np.int8))
            d.attrs["flag_meanings"] = np.bytes_(b"none gimp gmted mss antarctic")
            d.attrs["flag_values"] = np.arange(5, dtype=np.int8)
            s["dem/dem_h"] = np.full(n, dem_h, np.float32)
            s["dem/geoid_h"] = np.full(n, -9.7, np.float32)
    return path


@pytest.mark.parametrize("flag, dem_h, surface", [(2, -9.8, "ocean"), (2, 250.0, "land"),
                                                  (3, -9.8, "ocean"), (1, 1200.0, "land ice")])
def test_atl06_over_ocean_or_land_is_not_read_as_cloudy_snow(tmp_path, flag, dem_h, surface):
    """The surface from dem_flag's own meanings: off an ice sheet r_eff is not held against
    snow's 0.9 (which would call every segment cloudy, tau ~2), the cloud flags decide."""
    rf = real.read_product(_atl06_dem(tmp_path / f"ATL06_x_006_01_{flag}.h5", flag=flag,
                                      dem_h=dem_h))      # (209's all-0 flags: unseen3)
    b = rf.beams[0]
    assert b.surface == surface
    assert b.clear.all() == (surface != "land ice")
    assert (b.reflectance is None) == (surface != "land ice")
    # a subset that dropped fit_statistics (Snowblower's ATL06 v001): the line names it
    assert "a signal rate (no fit_statistics/n_fit_photons, n_seg_pulses)" in rf.missing_line()


def test_a_signal_not_measured_is_said_not_shown_as_a_dash():
    """A row's reason says why a ratio is missing; a file without ``solar_elevation`` shows
    the model's sun in the matrix, marked."""
    from lidar_mitsuba.studies.realism_report import _sun
    assert _sun({"solar_elevation_deg": None}, {"solar_elevation_deg": -41.8}) == "-41.8 (model)"
    assert _sun({"solar_elevation_deg": 12.0}, {"solar_elevation_deg": 11.9}) == "12.0"
    assert realism.ratio_words(0.97, 4.3e6, None, None) == (
        "background x0.97, signal not measured (the file gives no signal rate here)")
    assert realism.ratio_words(None, None, None, 0.0).endswith("signal not compared "
                                                               "(measured 0)")


def test_a_rewritten_sc_orient_does_not_swap_the_beams(tmp_path):
    """ICESat2VegR's earlier clip: ``sc_orient`` 1.0 (a float) where the groups'
    ``atlas_beam_type`` (one-element object arrays) make gt1l strong: the twin lays its
    beams out and picks ``--beams weak`` by the beam types, and the line says so."""
    import h5py
    from lidar_mitsuba import twin
    p = _atl08(tmp_path / "ATL08_clip.h5")
    with h5py.File(p, "a") as f:
        f["orbit_info/sc_orient"] = np.array([1.0])
        for name, kind in (("gt1l", "strong"), ("gt1r", "weak")):
            f[name].attrs["atlas_beam_type"] = np.array([kind], dtype=h5py.string_dtype())
    g = twin.read(p)
    assert g.sc_orient == 0 and [b.name for b in g.select_beams("weak")] == ["gt1r"]
    assert "sc_orient (1 contradicts atlas_beam_type: 0 taken)" in g.missing_line()


def test_a_clips_empty_beam_groups_are_not_paired(tmp_path):
    """ICESat2VegR's clips keep all six beam groups, five of them empty (attributes only):
    the forest twin and the ATL08 comparison pass them by instead of a KeyError."""
    import h5py
    from lidar_mitsuba.studies import atl08_real, forest_twin
    for name in ("ATL03_clip.h5", "ATL08_clip.h5"):
        with h5py.File(tmp_path / name, "w") as f:
            f.create_group("gt1l").attrs["atlas_beam_type"] = "strong"
    assert forest_twin.twins([tmp_path], progress=None) == []
    assert atl08_real.run([tmp_path], None, progress=None) == []


def test_a_restructured_file_says_what_its_beam_groups_hold(tmp_path):
    """Snowblower's ``..._reduced.h5`` keeps the six beam groups but flattens them
    (``gt1l/h_li``, ``gt1l/lat``) and its ``test_granule.h5`` keeps only
    ``gt1l/land_ice_segments/dem/dem_h``: the line names what the beam group holds, not
    the beam groups themselves."""
    import h5py
    flat = tmp_path / "processed_ATL06_20181015021234_02510110_001_01_reduced.h5"
    with h5py.File(flat, "w") as f:
        for name in ("gt1l", "gt1r"):
            f[f"{name}/h_li"] = np.zeros(4, np.float32)
            f[f"{name}/lat"] = np.zeros(4)
    with pytest.raises(ParameterError, match=r"_reduced.h5: no beam group .* \(gt1l holds "
                       r"h_li, lat; no land_ice_segments\)$"):
        real.read_product(flat)
    dem = tmp_path / "test_granule.h5"
    with h5py.File(dem, "w") as f:
        f.attrs["short_name"] = np.bytes_(b"ATL06")
        f.create_group("gt1r")                                    # an empty group: not named
        f["gt3l/land_ice_segments/dem/dem_h"] = np.zeros(4, np.float32)
    with pytest.raises(ParameterError, match=r"\(gt3l/land_ice_segments holds dem; no "
                       r"delta_time\)$"):
        real.read_product(dem)


def test_a_beam_judged_on_its_cloudy_segments_says_so_in_its_line():
    """A beam with no clear segment (Snowblower's ATL06 03200112, r_eff 0.1-0.3 on five
    beams) is judged on its cloudy background with the cloud: the run's line shows those,
    not a dash beside the clear sky's prediction under the verdict."""
    row = {"file": "ATL06_x.h5", "beam": "gt1l", "strength": "weak", "verdict": "agrees",
           "measured": {"background_clear_hz": None, "background_cloudy_hz": 4.86e6,
                        "signal_clear": None, "signal_cloudy": None},
           "predicted": {"background_hz": 3.33e6, "background_cloudy_hz": 2.99e6,
                         "signal_per_shot": 3.09, "signal_cloudy": 0.065}}
    line = realism.format_row(row)
    assert "bg cloudy 4860.0/2990.0 kHz" in line and "sig -/3.09" in line
    row["measured"].update(background_clear_hz=4.79e6)
    assert "bg 4790.0/3330.0 kHz" in realism.format_row(row)


def test_a_stand_in_for_a_dropped_dataset_is_said(tmp_path):
    """Snowblower's jeffdata ATL06 v001 subsets keep no ``dem`` group: the surface is taken
    as land ice (r_eff held against snow's), said; Floes-are-Swell's ATL07 v001 subsets
    keep ``height_segment_height`` without ``geophysical/height_segment_mss``: heights above
    the mean sea surface stand in for ellipsoidal ones, said. A file that has them says
    neither."""
    import h5py
    p = _atl06_dem(tmp_path / "ATL06_x_001_01.h5", flag=4, dem_h=1200.0)
    assert "dem/dem_flag" not in real.read_product(p).missing_line()
    with h5py.File(p, "a") as f:                  # a conversion that kept no attributes
        for name in ("gt1l", "gt1r"):
            del f[f"{name}/land_ice_segments/dem/dem_flag"].attrs["flag_meanings"]
    assert "dem/dem_flag's flag_meanings (the surface taken as land ice" in \
        real.read_product(p).missing_line()
    with h5py.File(p, "a") as f:
        for name in ("gt1l", "gt1r"):
            del f[f"{name}/land_ice_segments/dem"]
    rf = real.read_product(p)
    assert rf.beams[0].surface == "land ice"
    assert "dem/dem_flag (the surface taken as land ice" in rf.missing_line()
    q = tmp_path / "processed_ATL07-01_20181201123226_09760101_001_01.h5"
    with h5py.File(q, "w") as f:
        for name, kind in (("gt1l", "weak"), ("gt1r", "strong")):
            f.create_group(name).attrs["atlas_beam_type"] = np.bytes_(kind.encode())
            s = f.create_group(f"{name}/sea_ice_segments")
            s["delta_time"] = 2.9e7 + np.arange(6) * 0.01
            s["latitude"] = np.full(6, 75.0)
            s["longitude"] = np.full(6, -150.0)
            s["heights/height_segment_height"] = np.full(6, 0.3, np.float32)
    line = real.read_product(q).missing_line()
    assert "geophysical/height_segment_mss (heights above the mean sea surface" in line
    with h5py.File(q, "a") as f:
        for name in ("gt1l", "gt1r"):
            f[f"{name}/sea_ice_segments/geophysical/height_segment_mss"] = np.full(6, 2.0)
    rf = real.read_product(q)
    assert "height_segment_mss" not in rf.missing_line()
    assert np.allclose(rf.beams[0].surface_h_m, 2.3)


def test_an_atl03_atl08_pair_is_found_by_its_names_as_tools_write_them(tmp_path):
    """ICESat2VegR's clips are ``atl03_clip.h5`` and ``atl08_clip.h5``; the NSIDC
    subsetter writes ``processed_ATL03_...`` and ``processed_ATL08_...`` (icesat2R's
    vignette pair); a granule's ATL03 and ATL08 may differ in revision. Each is one pair
    (the forest twin judges their rows; before, only names starting ``ATL08`` paired, and
    the clip's ATL03 was judged over ice-sheet snow by its surf_type, 'agrees' x0.97)."""
    from lidar_mitsuba.studies.atl08_real import pairs
    names = ["atl03_clip.h5", "atl08_clip.h5",
             "processed_ATL03_20200821122613_08730802_004_01.h5",
             "processed_ATL08_20200821122613_08730802_004_01.h5",
             "ATL03_20220401221822_01501506_006_02.h5", "ATL08_20220401221822_01501506_006_01.h5",
             "ATL08_20190101000000_00010101_006_01.h5"]                    # no ATL03 beside it
    for n in names:
        (tmp_path / n).write_bytes(b"")
    got = {(pathlib.Path(a).name, pathlib.Path(b).name) for a, b in pairs([tmp_path])}
    assert got == {(names[0], names[1]), (names[2], names[3]), (names[4], names[5])}
    assert pairs([tmp_path / names[3]]) == [(str(tmp_path / names[2]), str(tmp_path / names[3]))]


def test_a_folder_gives_its_netcdf4_named_icesat2_files_too(tmp_path):
    """The NSIDC subsetter's reformatting writes ``processed_ATL03_..._005_01.nc`` and
    ``processed_ATL10-01_..._006_01.nc`` (NetCDF-4: HDF5 files): found in a folder they are
    read (or passed by and listed) as ``.h5`` files are, not left out unsaid; other files
    are not taken."""
    nc = _atl08(tmp_path / "processed_ATL08_20200821122613_08730802_004_01.nc")
    (tmp_path / "notes.txt").write_text("not a product")
    assert realism.real_files([tmp_path]) == [nc]
    out = tmp_path / "out"
    assert main(["validate", "--real", str(tmp_path), "--signal-shots", "0",
                 "--out", str(out)]) == 0
    assert f"{nc.name} (ATL08)" in (out / "realism.md").read_text()
    assert real.read_product(nc).release == "004"           # from the name, as for .h5
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ParameterError,
                       match=r"no HDF5 file \(.h5, .hdf5, .he5, .hdf, .nc, .nc4\)"):
        realism.real_files([empty])


def test_two_subsets_of_one_granule_are_told_apart(tmp_path):
    """Snowblower keeps two subsets of ATL06 04950110 under one name, in Outputs/... and
    jeffdata/: run together, their rows and strong:weak pairs carried one name (the second
    file's pairs replaced the first's, 3 of 6 shown); now each is named by as much of its
    path as tells them apart, and a file named twice (itself and in its folder) is read
    once."""
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    fa = _atl08(a / "ATL08_x.h5")
    _atl08(b / "ATL08_x.h5", rates=(8.0, 2.0))
    assert realism.real_files([a, fa]) == [fa]
    doc = realism.run([a, b], signal_shots=0)
    assert {f["file"] for f in doc["files"]} == {"a/ATL08_x.h5", "b/ATL08_x.h5"}
    assert [q["file"] for q in doc["pairs"]] == ["a/ATL08_x.h5", "b/ATL08_x.h5"]
    assert doc["files"][0]["missing"].startswith("a/ATL08_x.h5 (ATL08) lacks: ")
    assert realism.labels([a / "x.h5", tmp_path / "c.h5"]) == {a / "x.h5": "x.h5",
                                                                tmp_path / "c.h5": "c.h5"}


def _atl03(path, *, n_seg: int = 6, per: int = 30, drop=(), cut_photons: int = 0,
           bg_rows: int = 3):
    """A small ATL03 beam as NASA writes it (one weak beam, photons of confidence 4 and 0,
    a background table), less the datasets ``drop`` names, its photons cut short by
    ``cut_photons`` (a subset that cut ``heights`` and not ``geolocation``)."""
    import h5py
    m = n_seg * per
    with h5py.File(path, "w") as f:
        g = f.create_group("gt1l")
        g.attrs["atlas_beam_type"] = "weak"
        d = {"geolocation/delta_time": 1.0e8 + np.arange(n_seg) * 20.0 / 7000.0,
             "geolocation/reference_photon_lat": 70.0 + np.arange(n_seg) * 20.0 / 111_000.0,
             "geolocation/reference_photon_lon": np.full(n_seg, -50.0),
             "geolocation/segment_ph_cnt": np.full(n_seg, per, np.int32),
             "geolocation/ph_index_beg": 1 + np.arange(n_seg) * per,
             "heights/h_ph": np.where(np.arange(m) % 3, 100.0, 700.0)[:m - cut_photons],
             "heights/lat_ph": np.repeat(70.0 + np.arange(n_seg) * 20.0 / 111_000.0, per),
             "heights/lon_ph": np.full(m, -50.0),
             "heights/pce_mframe_cnt": (np.arange(m) // 200).astype(np.uint32),
             "heights/ph_id_pulse": (np.arange(m) % 200 // 2 + 1).astype(np.uint8),
             "bckgrd_atlas/delta_time": 1.0e8 + np.arange(bg_rows) * 0.005,
             "bckgrd_atlas/bckgrd_rate": np.full(bg_rows, 2.0e5, np.float32)}
        conf = np.zeros((m, 5), np.int8)
        conf[np.arange(m) % 3 > 0, 0] = 4                       # one photon in 3: background
        d["heights/signal_conf_ph"] = conf
        for k, v in d.items():
            if k not in drop:
                g[k] = v
    return path


def test_an_atl03_subset_reads_what_its_photons_can_say(tmp_path):
    """Variable and spatial subsets of ATL03 as the tools leave them: without
    ``signal_conf_ph`` every photon would count as signal (the background with it: 1.5x
    here, x100 in daylight), so no signal rate is read, said; photons cut short of their
    index stopped the run with an IndexError, now no photon is read, said; an empty
    ``bckgrd_atlas`` (a clip shorter than one 50-shot row) was an IndexError, now no
    background, said; without ``reference_photon_lat``/``_lon`` (a subset of the photons'
    own places) a TypeError in the twin, now each segment's first photon's place; with no
    place at all, one line."""
    whole = real.read_product(_atl03(tmp_path / "ATL03_a.h5")).beams[0]
    assert np.nanmedian(whole.signal_per_shot) == pytest.approx(4 / 3)  # 20 of 30, 15 pulses
    rf = real.read_product(_atl03(tmp_path / "ATL03_b.h5", drop=["heights/signal_conf_ph"]))
    assert rf.beams[0].signal_per_shot is None
    assert "a signal rate (no heights/signal_conf_ph)" in rf.missing_line()
    rf = real.read_product(_atl03(tmp_path / "ATL03_c.h5", cut_photons=50))
    assert rf.beams[0].signal_per_shot is None and not np.isfinite(rf.beams[0].surface_h_m).any()
    assert "heights/h_ph (130 photons) does not fit geolocation/ph_index_beg" in rf.missing_line()
    rf = real.read_product(_atl03(tmp_path / "ATL03_d.h5", bg_rows=0))
    assert rf.beams[0].background_hz is None
    assert "a background rate (bckgrd_atlas holds 0 rows)" in rf.missing_line()
    rf = real.read_product(_atl03(tmp_path / "ATL03_e.h5", drop=[
        "geolocation/reference_photon_lat", "geolocation/reference_photon_lon"]))
    assert np.allclose(rf.beams[0].lat_deg, whole.lat_deg)
    assert "each segment's first photon's lat_ph, lon_ph" in rf.missing_line()
    nowhere = _atl03(tmp_path / "ATL03_f.h5", drop=[
        "geolocation/reference_photon_lat", "geolocation/reference_photon_lon",
        "heights/lat_ph", "heights/lon_ph"])
    with pytest.raises(ParameterError, match=r"with a time and place \(gt1l: no geolocation/"
                       r"reference_photon_lat \(or heights/lat_ph\), geolocation/"
                       r"reference_photon_lon \(or heights/lon_ph\)\)$"):
        real.read_product(nowhere)
    out = tmp_path / "out"
    for p in tmp_path.glob("ATL03_[a-e].h5"):           # none stops the matrix
        assert main(["validate", "--real", str(p), "--signal-shots", "0", "--out",
                     str(out)]) == 0


def test_a_segment_product_without_its_heights_reads_the_rest(tmp_path):
    """An ATL06 variable subset without ``h_li`` stopped the matrix with a TypeError (its
    heights None where ATL07's and ATL08's stand as NaN), now 'surface heights' is said; an
    ATL07 without ``heights/height_segment_type`` reads ``photon_rate`` on every segment
    (leads too: Baffin's low-sun gt1r 2.58 photons a shot against 2.10 on snow-covered
    ice), said."""
    import h5py
    p = _atl06_dem(tmp_path / "ATL06_x_005_01.h5", flag=4, dem_h=1200.0)
    with h5py.File(p, "a") as f:
        for name in ("gt1l", "gt1r"):
            del f[f"{name}/land_ice_segments/h_li"]
            f[f"{name}/land_ice_segments/geophysical/bckgrd"] = np.full(8, 1.0e5, np.float32)
    assert "surface heights" in real.read_product(p).missing_line()
    assert main(["validate", "--real", str(p), "--signal-shots", "0",
                 "--out", str(tmp_path / "out")]) == 0
    q = tmp_path / "ATL07-01_x_003_02.h5"
    with h5py.File(q, "w") as f:
        for name, kind in (("gt1l", "strong"), ("gt1r", "weak")):
            f.create_group(name).attrs["atlas_beam_type"] = kind
            s = f.create_group(f"{name}/sea_ice_segments")
            s["delta_time"] = 3.5e7 + np.arange(6) * 0.01
            s["latitude"] = np.full(6, 69.4)
            s["longitude"] = np.full(6, -60.0)
            s["stats/photon_rate"] = np.full(6, 8.0 if kind == "strong" else 2.0, np.float32)
    assert "heights/height_segment_type (the signal's photon_rate on every segment" in \
        real.read_product(q).missing_line()


def test_an_atl06_signal_with_its_window_background_left_in_says_so(tmp_path):
    """An ATL06 subset with ``fit_statistics`` but without ``geophysical/bckgrd`` (or the
    window ``w_surface_window_final``) reads its signal with the window's background left
    in (by day ~0.06-0.6 photons a pulse), said; with both, nothing said."""
    import h5py
    p = _atl06_dem(tmp_path / "ATL06_x_005_01.h5", flag=4, dem_h=1200.0)
    with h5py.File(p, "a") as f:
        for name in ("gt1l", "gt1r"):
            s = f[f"{name}/land_ice_segments"]
            s["fit_statistics/n_fit_photons"] = np.full(8, 200, np.int32)
            s["fit_statistics/n_seg_pulses"] = np.full(8, 57.0, np.float32)
            s["fit_statistics/w_surface_window_final"] = np.full(8, 30.0, np.float32)
    line = real.read_product(p).missing_line()
    assert "geophysical/bckgrd (the fitted photons' background not taken off" in line
    with h5py.File(p, "a") as f:
        for name in ("gt1l", "gt1r"):
            f[f"{name}/land_ice_segments/geophysical/bckgrd"] = np.full(8, 3.0e6, np.float32)
    rf = real.read_product(p)
    assert "not taken off" not in rf.missing_line()
    assert rf.beams[0].signal_per_shot[0] == pytest.approx(200 / 57 - 3.0e6 * 60 / 2.998e8,
                                                           rel=1e-3)


def test_a_file_of_flattened_group_names_says_so_in_its_line(tmp_path):
    """OPeNDAP's CF option and netCDF conversions flatten the beam groups into dataset
    names (``gt1l_land_ice_segments_h_li``; NSIDC's OPeNDAP ATL13 requests name
    ``/gt3r_segment_...``): the line says so, not only what the file holds, and names the
    product from the flattened names where the file's name does not."""
    import h5py
    p = tmp_path / "granule_subset.nc4"
    with h5py.File(p, "w") as f:
        f["gt1l_land_ice_segments_h_li"] = np.zeros(4, np.float32)
        f["gt1l_land_ice_segments_delta_time"] = np.zeros(4)
        f["orbit_info_sc_orient"] = np.zeros(1, np.int8)
    with pytest.raises(ParameterError, match=r"granule_subset.nc4: no beam group .* "
                       r"land_ice_segments segments \(its groups are flattened into names "
                       r"\(gt1l_land_ice_segments_delta_time, ...: an OPeNDAP"):
        real.read_product(p)


def test_an_integer_flag_at_its_fill_value_is_missing_not_cloudy(tmp_path):
    """ICESat-2's int8 datasets fill with 127 (ATL07's ``bsnow_con`` on 287 of 882 Baffin
    segments): a cloud flag at its ``_FillValue`` (no ATL09 there) was read as 127, 'cloudy'
    (127 > 2) and 127 layers; now it is missing and does not vote."""
    import h5py
    from lidar_mitsuba.studies.realism_inputs import layer_count
    p = _atl06_dem(tmp_path / "ATL06_x_209_01.h5", flag=2, dem_h=250.0)     # land: flags only
    with h5py.File(p, "a") as f:
        for name in ("gt1l", "gt1r"):
            gp = f[f"{name}/land_ice_segments/geophysical"]
            for key, v in (("cloud_flg_asr", 1), ("cloud_flg_atm", 0)):
                del gp[key]
                a = np.full(8, v, np.int8)
                a[:3] = 127
                a[6:] = 4 if key == "cloud_flg_asr" else 2       # two cloudy segments
                gp.create_dataset(key, data=a, fillvalue=127)
                gp[key].attrs["_FillValue"] = np.int8(127)
    b = real.read_product(p).beams[0]
    assert b.clear.tolist() == [True] * 6 + [False] * 2
    assert np.isnan(b.layer_count[:3]).all() and layer_count(b) == 2


def test_an_atl08_without_its_canopy_rate_says_its_signal_is_the_terrains(tmp_path):
    """An ATL08 subset that kept ``terrain`` and dropped ``canopy`` (nsidc-icesat2gis's
    earlier test_atl08.h5 kept canopy heights only; a variable subset can do the reverse)
    reads its signal from the terrain's photons alone, said: a forest's canopy photons
    would be missing from it silently."""
    import h5py
    p = _atl08(tmp_path / "ATL08_x.h5")
    assert "photon_rate_can" not in real.read_product(p).missing_line()
    with h5py.File(p, "a") as f:
        for name in ("gt1l", "gt1r"):
            del f[f"{name}/land_segments/canopy"]
    assert "canopy/photon_rate_can (the signal the terrain's photons alone)" in \
        real.read_product(p).missing_line()



def test_two_clip_pairs_of_one_name_each_get_their_own_forest_twin(tmp_path, monkeypatch):
    """ICESat2VegR's Saskatchewan and Wyoming clips are both ``atl03_clip.h5`` +
    ``atl08_clip.h5`` (two versions of the package): run from two folders, both pairs' rows
    took the last twin (the forest rows were keyed by file name: Saskatchewan judged against
    Wyoming's 6.0 m stand, 1158 shots); now each pair's rows take their own."""
    from lidar_mitsuba.studies import forest_twin
    folders = [tmp_path / "sk", tmp_path / "wy"]
    for d in folders:
        d.mkdir()
        for n in ("atl03_clip.h5", "atl08_clip.h5"):
            (d / n).write_bytes(b"")
    monkeypatch.setattr(forest_twin, "twins", lambda paths, **kw: [
        {"beam": "gt1r", "site": pathlib.Path(paths[0]).parent.name}])
    docs, by_row, paired = realism._forest_twins(folders, signal_shots=1, seed=0,
                                                 progress=None)
    assert [d["site"] for d in docs] == ["sk", "wy"]
    for d in folders:
        for n in ("atl03_clip.h5", "atl08_clip.h5"):
            assert by_row[(str((d / n).resolve()), "gt1r")]["site"] == d.name
            assert str((d / n).resolve()) in paired
