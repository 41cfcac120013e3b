"""Ice-sheet campaigns on Dask (issue 34): a small campaign (four repeat-orbit granules of one
beam pair, 400 shots per beam, snow from a grain-size raster binned to two levels) run in this
process, through a real ``dask scheduler`` with two ``dask worker`` processes, and killed and
resumed, gives the same segment table to the bit; the spec's errors, the ICESat-2 file names,
the repeat orbit's geometry and the raster's windowed reads."""
from __future__ import annotations

import json
import math
import os
import pathlib
import socket
import subprocess
import sys
import time
from datetime import datetime, timezone

import h5py
import numpy as np
import pandas as pd
import pytest

from lidar_mitsuba import campaign
from lidar_mitsuba.campaign import rasters, tracks as tk
from lidar_mitsuba.cli import main
from cli_checks import bad_call
from lidar_mitsuba.ground import dem as dems

ROOT = pathlib.Path(__file__).resolve().parents[1]
SPEC = """
[campaign]
name = "tiny"
seed = 7
map_bin_m = 200
kernel_cache = "kernels"

[dem]
path = "dem.tif"

[instrument]
preset = "paper"
beams = "gt1l,gt1r"

[run]
shots = 400
section_shots = 200         # two sections a beam: the grain raster resolved per section

[epochs]
cycles = [4]

[orbit]
passes = "both"

[snow]
grain_um = "grain.tif"
grain_levels_um = [150, 1000]
"""


@pytest.fixture(autouse=True, scope="module")
def _small_kernel_tables():
    """This module checks the campaign's plumbing (which tables, where, the same table to the
    bit however it is run), not a table's precision (tests/test_snow_kernel.py does): its
    tables, built here and read by the Dask workers it starts, have 2^13 walk photons a node."""
    from lidar_mitsuba.ground.snow import kernel
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("LIDAR_MITSUBA_KERNEL_PHOTONS", str(1 << 13))
        mp.setattr(kernel, "PHOTONS", 1 << 13)
        yield


@pytest.fixture(scope="module")
def spec_path(tmp_path_factory):
    """A 20 x 6 km DEM (80 m posting, no hole) that four repeat-orbit tracks cross with both
    beams of gt1, a grain-size raster rising from 100 um (west) to 1000 um (east), and the
    spec."""
    d = tmp_path_factory.mktemp("inputs")
    dems.synthetic_ice_sheet(d / "dem.tif", width_m=20000, length_m=6000, posting_m=80,
                             hole=False)
    rasters.gradient_raster(d / "grain.tif", like=d / "dem.tif", start=100, stop=1000,
                            posting_m=200)
    (d / "tiny.toml").write_text(SPEC)
    return d / "tiny.toml"


@pytest.fixture(scope="module")
def serial(spec_path, tmp_path_factory):
    """The campaign in this process (workers=0)."""
    return campaign.run(spec_path, out=tmp_path_factory.mktemp("serial") / "out", workers=0)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def scheduler(tmp_path_factory):
    """``dask scheduler`` and two ``dask worker`` processes (one thread each, no nanny) on
    127.0.0.1 at a free port: ``(address, worker pids)``; killed at the end."""
    dask = pathlib.Path(sys.executable).with_name("dask")
    if not dask.exists():
        pytest.skip("the dask command line is not installed")
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    logs = tmp_path_factory.mktemp("dask")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT)] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    cmds = [[str(dask), "scheduler", "--host", "127.0.0.1", "--port", str(port),
             "--no-dashboard"]]
    cmds += [[str(dask), "worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard",
              "--memory-limit", "0", "--name", f"w{i}", "--local-directory", str(logs),
              "--death-timeout", "60"] for i in range(2)]
    procs = []
    try:
        for k, cmd in enumerate(cmds):
            procs.append(subprocess.Popen(cmd, env=env, cwd=logs, stdout=open(
                logs / f"{k}.log", "w"), stderr=subprocess.STDOUT))
            if k == 0:
                time.sleep(1.0)
        from dask.distributed import Client
        with Client(address, timeout="60s") as c:
            c.wait_for_workers(2, timeout=120)
        yield address, {p.pid for p in procs[1:]}
    finally:      # a dask worker can take 20 s and more to stop on SIGTERM: then it is killed
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=3)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=20)


def test_the_serial_campaign_writes_named_granules_a_table_and_a_map(serial, spec_path):
    seg, tasks = serial.segments, serial.tasks
    assert len(tasks) == 4 and (tasks["status"] == "ok").all() and serial.failed == 0
    assert set(tasks["grain_um"]) == {150.0, 1000.0}          # both levels, one table each
    # one kernel table per level, built in the kernel cache before any granule started
    tables = sorted((spec_path.parent / "kernels" / "snow_kernel").glob("*.npz"))
    first = min(datetime.fromisoformat(t) for t in tasks["started_at"])
    assert len(tables) == 2 and all(datetime.fromtimestamp(f.stat().st_mtime, timezone.utc)
                                    < first for f in tables)
    assert len(seg) == tasks["n_segments"].sum() == 4 * 2 * 12
    assert list(seg.columns) == list(campaign.SEGMENT_COLUMNS)
    np.testing.assert_array_equal(seg["error"], seg["h_li"] - seg["h_truth"])
    assert serial.map is not None and serial.map.stat().st_size > 10000
    # a folder per product (icepyx.Read(folder) reads one product's granules), nothing else
    files = sorted(str(p.relative_to(serial.out / "granules"))
                   for p in (serial.out / "granules").rglob("*") if p.is_file())
    assert len(files) == 8 and all(f.startswith(("ATL03/ATL03_", "ATL06/ATL06_")) for f in files)
    assert sorted(p.name for p in (serial.out / "granules").iterdir()) == ["ATL03", "ATL06"]
    for _, t in tasks.iterrows():
        f3, f6 = serial.out / "granules" / t["atl03"], serial.out / "granules" / t["atl06"]
        name = tk.parse_product_name(f3.name)
        assert name["product"] == "ATL03" and tk.parse_product_name(f6.name)["product"] == "ATL06"
        assert (name["rgt"], name["cycle"], name["region"]) == (t["rgt"], t["cycle"],
                                                                t["region"])
        assert name["version"] == 1 and name["revision"] == 1 and name["cycle"] == 4
        assert name["region"] == (3 if t["ascending"] else 5)       # 59.5-80 N
        with h5py.File(f3, "r") as f:
            assert int(f["orbit_info/rgt"][0]) == t["rgt"]
            assert int(f["orbit_info/cycle_number"][0]) == 4
            assert {"gt1l", "gt1r"} <= set(f)
        # the file name's time is the first shot's
        epoch = json.loads(t["track_json"])["epoch_utc"]
        assert epoch[:19].replace("-", "").replace(":", "").replace("T", "") == \
            name["date"] + name["time"]
    # the files read as any of our granules: ATL06 fitted again from the ATL03 photons
    from lidar_mitsuba.products import atl06
    again = atl06.segments_from_atl03(serial.out / "granules" / tasks["atl03"][0])
    mine = seg[(seg["task_index"] == 0) & (seg["beam"] == "gt1l")]
    np.testing.assert_array_equal(again.segment_id, mine["segment_id"])
    assert np.nanmax(np.abs(again.h_li - mine["h_li"])) < 1e-3     # (the file holds float32)
    # the table is the files' segments
    first = campaign.granules.read_segments(serial.out / "granules" / tasks["atl06"][0])
    mine = seg[seg["task_index"] == 0]
    np.testing.assert_array_equal(mine["h_li"], first["h_li"])
    pd.testing.assert_frame_equal(pd.read_parquet(serial.out / "segments.parquet"), seg)


def test_bias_follows_the_grain_size(serial):
    """Larger grains carry the light deeper: h_li lower (README's snow table: the bias grows
    with grain size), by far more than the Monte Carlo error."""
    t = serial.tasks.groupby("grain_um").agg(
        bias=("bias_m", "mean"), se=("bias_se_m", lambda s: math.sqrt((s ** 2).sum()) / s.size))
    fine, coarse = t.loc[150.0], t.loc[1000.0]
    assert fine["bias"] < 0 and coarse["bias"] < fine["bias"] - 4 * math.hypot(fine["se"],
                                                                              coarse["se"])
    seg = serial.segments
    assert np.isfinite(seg["grain_um_raster"]).all()
    assert seg.groupby("grain_um")["grain_um_raster"].mean().is_monotonic_increasing


def test_granule_metadata_is_the_file_name_s(serial):
    """Every granule's ``METADATA`` (issue 44) is its file name's: the product, the file name
    and its release as ``VersionID`` (the number icepyx and NSIDC's tools parse), a uuid of
    its own; its ``Extent`` holds every position; ``ProcessStep`` says "simulated"; an ATL06's
    ``Lineage/ATL03`` names the ATL03 of the same run (file name and uuid), as real ones do."""
    folder = serial.out / "granules"
    meta = {}
    for _, t in serial.tasks.iterrows():
        for product in ("atl03", "atl06"):
            path = folder / t[product]
            with h5py.File(path, "r") as f:
                m = {k: v.decode() for k, v in f["METADATA/DatasetIdentification"].attrs.items()}
                e = f["METADATA/Extent"].attrs
                lat = f["gt1l/heights/lat_ph" if product == "atl03" else
                        "gt1l/land_ice_segments/latitude"][()]
                assert e["southBoundLatitude"] <= lat.min() <= lat.max() <= e["northBoundLatitude"]
                lineage = {k: v.decode() for k, v in f["METADATA/Lineage/ATL03"].attrs.items()
                           } if product == "atl06" else None
                assert "simulated" in f["METADATA/ProcessStep/PGE"].attrs[
                    "processDescription"].decode().lower()
            assert (m["shortName"], m["fileName"], m["VersionID"]) == (
                product.upper(), path.name, f"{tk.parse_product_name(path.name)['version']:03d}")
            meta[path] = m
            if lineage is not None:
                atl03 = meta[folder / t["atl03"]]
                assert (lineage["fileName"], lineage["uuid"]) == (atl03["fileName"], atl03["uuid"])
    assert len({m["uuid"] for m in meta.values()}) == len(meta) == 8


def test_icesat2_readers_load_the_campaign_s_folders(serial, monkeypatch):
    """The ICESat-2 community's readers open a campaign's output as they open NSIDC's
    granules (issue 44). icepyx (2.0.2) takes the product and its release from ``METADATA``
    (a release that is not a number stops it) and loads a product's folder,
    ``icepyx.Read("out/granules/ATL03")``, into one dataset, ATL03 and ATL06, and one granule
    alone; SlideRule's pure-Python reader h5coro (1.0.7) reads both products' datasets and
    metadata. What they read is what h5py reads; neither opens a socket for local files (any
    connection here raises)."""
    import socket
    import warnings

    def no_network(*args, **kwargs):
        raise AssertionError(f"a reader went to the network: {args[1:]}")
    monkeypatch.setattr(socket.socket, "connect", no_network)
    monkeypatch.setattr(socket, "getaddrinfo", no_network)
    import icepyx as ipx
    from h5coro import filedriver, h5coro
    folder = serial.out / "granules"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")      # (xarray's FutureWarnings on icepyx's merge)
        for product, var, group in (("ATL03", "h_ph", "heights"),
                                    ("ATL06", "h_li", "land_ice_segments")):
            reader = ipx.Read(str(folder / product))
            assert reader.product == product and len(reader.filelist) == 4
            reader.variables.append(var_list=[var])
            assert reader.variables.version == "001"
            ds = reader.load()
            assert ds.sizes["gran_idx"] == 4 and sorted(ds["rgt"].values) == sorted(
                serial.tasks["rgt"])
            for g in range(4):
                with h5py.File(str(ds["source_file"].values[g]), "r") as f:
                    first = 0       # (icepyx numbers a granule's photons on, spot after spot)
                    for s in range(ds.sizes["spot"]):
                        ours = f[f"{ds['gt'].values[g, s]}/{group}/{var}"]
                        want = np.where(ours[()] == ours.attrs.get("_FillValue", np.nan),
                                        np.nan, ours[()])
                        got = ds[var].isel(spot=s, gran_idx=g).values
                        mine = np.arange(first, first + want.size)
                        np.testing.assert_array_equal(got[mine], want)
                        assert np.isnan(np.delete(got, mine)).all()
                        first += want.size if "photon_idx" in ds[var].dims else 0
        one = folder / serial.tasks["atl06"][0]        # (a granule alone: the same reader)
        reader = ipx.Read(str(one))
        reader.variables.append(var_list=["h_li", "h_li_sigma", "atl06_quality_summary"])
        ds = reader.load()
        assert ds.sizes["gran_idx"] == 1 and set(ds["gt"].values.ravel()) == {"gt1l", "gt1r"}
        assert (ds["atl06_quality_summary"] == 0).sum() > 0.8 * ds["h_li"].notnull().sum()
    for path, names in ((folder / serial.tasks["atl03"][0],
                         ["/gt1r/heights/h_ph", "/gt1r/heights/signal_conf_ph",
                          "/gt1r/geolocation/segment_ph_cnt", "/orbit_info/sc_orient"]),
                        (one, ["/gt1l/land_ice_segments/h_li", "/gt1l/land_ice_segments/latitude",
                               "/gt1l/land_ice_segments/fit_statistics/n_fit_photons"])):
        h5 = h5coro.H5Coro(str(path), filedriver.FileDriver, errorChecking=True, verbose=False)
        read = h5.readDatasets(names, block=True)
        with h5py.File(path, "r") as f:
            for name in names:
                np.testing.assert_array_equal(np.asarray(read[name]), f[name][()])
        attrs = h5.inspectPath("/METADATA/DatasetIdentification")[1]
        assert (attrs["shortName"], attrs["VersionID"]) == (path.name[:5], "001")


def test_two_dask_workers_give_the_serial_table_to_the_bit(serial, spec_path, scheduler,
                                                           tmp_path, capsys):
    address, pids = scheduler
    out = tmp_path / "out"
    tables = {f: f.stat().st_mtime_ns for f in (spec_path.parent / "kernels").rglob("*.npz")}
    assert main(["campaign", str(spec_path), "--out", str(out), "--scheduler", address,
                 "--no-progress", "--no-map"]) == 0
    text = capsys.readouterr().out
    assert "connected to" in text and "2 workers" in text and "4 granules, 4 run now" in text
    seg = pd.read_parquet(out / "segments.parquet")
    pd.testing.assert_frame_equal(seg, serial.segments, check_exact=True)
    tasks = pd.read_parquet(out / "tasks.parquet")
    ran_on = {int(w.rsplit(":", 1)[1]) for w in tasks["worker"]}
    assert ran_on <= pids and os.getpid() not in ran_on
    # the workers read the tables the first run built (none built again)
    assert {f: f.stat().st_mtime_ns for f in (spec_path.parent / "kernels").rglob("*.npz")} \
        == tables and len(tables) == 2
    for name in tasks["atl06"]:      # the same files, byte for byte in their data
        a = campaign.granules.read_segments(out / "granules" / name)
        b = campaign.granules.read_segments(serial.out / "granules" / name)
        for k in a:
            np.testing.assert_array_equal(a[k], b[k])


def test_a_killed_campaign_resumes_to_the_same_table(serial, spec_path, tmp_path):
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        campaign.run(spec_path, out=out, workers=0, plot=False, _stop_after=2)
    assert len(list((out / "rows").glob("*.parquet"))) == 2
    seg, tasks = campaign.load(out)
    assert len(tasks) == 2 and set(seg["task_index"]) == set(tasks["task_index"])
    again = campaign.run(spec_path, out=out, workers=0, plot=False)
    assert again.ran == 2 and again.skipped == 2
    pd.testing.assert_frame_equal(again.segments, serial.segments, check_exact=True)
    assert campaign.run(spec_path, out=out, workers=0, plot=False).ran == 0
    # a granule whose segments were lost runs again, here on a LocalCluster of one worker
    # from the command line, as the docs show it
    (out / "segments" / f"{again.tasks['task_id'][1]}.parquet").unlink()
    assert main(["campaign", str(spec_path), "--out", str(out), "--workers", "1",
                 "--no-progress", "--no-map"]) == 0
    seg, tasks = campaign.load(out)
    assert len(tasks) == 4
    pd.testing.assert_frame_equal(seg, serial.segments, check_exact=True)


def test_failing_granules_are_recorded_and_the_rest_go_on(spec_path, serial, tmp_path):
    """A track of the spec's own that runs off the DEM's north edge fails in its run (no files
    left for it); one wholly off the grain raster is refused before running; the orbit's four
    granules are those of the serial run."""
    tracks = ('[[tracks]]\nstart = [70.025, -45.0]\nazimuth_deg = 0.0\nrgt = 9\n\n'
              '[[tracks]]\nstart = [70.3, -45.0]\nazimuth_deg = 0.0\nrgt = 10\n\n[orbit]')
    spec = spec_path.with_name("with_bad_tracks.toml")
    spec.write_text(SPEC.replace("[orbit]", tracks).replace('name = "tiny"', 'name = "bad"'))
    res = campaign.run(spec, out=tmp_path / "out", workers=0, plot=False)
    bad = res.tasks[res.tasks["status"] == "failed"].set_index("rgt")
    assert sorted(bad.index) == [9, 10] and res.failed == 2
    assert "off the DEM" in bad.loc[9, "error"] and bad.loc[9, "error"].startswith("track")
    assert bad.loc[10, "error"].startswith("the grain_um raster has no value along the track")
    assert not list((tmp_path / "out" / "granules").rglob("*_00090*")) and \
        not list((tmp_path / "out" / "granules").rglob(".*"))
    ok = res.segments[res.segments["rgt"] != 9].drop(columns="task_index").reset_index(drop=True)
    pd.testing.assert_frame_equal(ok, serial.segments.drop(columns="task_index"),
                                  check_exact=True)


def test_the_demo_spec_flies_seven_tracks_of_six_beams_over_a_grain_gradient(tmp_path):
    demo = tmp_path / "demo.toml"
    demo.write_text((ROOT / "campaigns" / "demo.toml").read_text())
    assert main(["make-dem", "--out", str(tmp_path / "demo_dem.tif"), "--width-m", "40000",
                 "--length-m", "30000", "--posting-m", "40"]) == 0
    assert main(["make-raster", "--like", str(tmp_path / "demo_dem.tif"), "--out",
                 str(tmp_path / "demo_grain_um.tif"), "--start", "100", "--stop", "1000"]) == 0
    spec = campaign.load_spec(demo)
    tasks = campaign.expand(spec)
    assert spec.beams == "all" and spec.grain.raster and len(tasks) == 7
    assert sum(t.ascending for t in tasks) == 3 and len({t.rgt for t in tasks}) == 7
    assert 2000 * 6 * len(tasks) <= 100000
    assert len({t.grain_um for t in tasks}) >= 4 and all(not t.invalid for t in tasks)
    # each beam pair sees its own level: the granules' 6.6 km of beams span the gradient
    assert any(len({g for row in t.grain_sections.values() for g in row}) >= 2 for t in tasks)
    west_east = sorted(tasks, key=lambda t: json.loads(json.dumps(t.track))["polyline"][0][1])
    assert west_east[0].grain_um < west_east[-1].grain_um


BAD = [
    ("[campaigns]\n", "[campaigns]"),
    ("[campaign]\nworkers = 2\n", "[campaign] workers"),
    ("[campaign]\nformat = \"xlsx\"\n", "[campaign] format"),
    ("[dem]\npath = \"none.tif\"\n", "[dem] path"),
    ("[instrument]\npreset = \"laser\"\n", "[instrument] preset"),
    ("[instrument]\nbeams = \"gt4l\"\n", "[instrument] beams"),
    ("[instrument]\noptions = { pde = 2.0 }\n", "[instrument] options.pde"),
    ("[run]\nshots = 0\n", "[run] shots"),
    ("[run]\nmax_depth = 2\n", "[run] max_depth"),
    ("[epochs]\ncycles = [0]\n", "[epochs] cycles"),
    ("[epochs]\ncycles = []\n", "[epochs] cycles"),
    ("[orbit]\npasses = \"up\"\n", "[orbit] passes"),
    ("[orbit]\ninclination_deg = 200\n", "[orbit] inclination_deg"),
    ("[orbit]\nnodal_day_s = 86400000\n", "[orbit] nodal_day_s"),
    ("[snow]\ngrain_levels_um = []\n", "[snow] grain_levels_um"),
    ("[snow]\ngrain_levels_um = [1, 2]\n", "[snow] grain_levels_um"),
    ("[snow]\ngrain_um = \"none.tif\"\n", "[snow] grain_um"),
    ("[snow]\nmodel = \"fast\"\n", "[snow] model"),
    ("[[tracks]]\nstart = [70.0]\n", "[[tracks]] 1 start"),
    ("[[tracks]]\nazimuth_deg = 3\n", "[[tracks]] 1"),
    ("[[tracks]]\nstart = [70.0, -45.0]\nepoch_utc = \"yesterday\"\n", "[[tracks]] 1 epoch_utc"),
]


def _replace(text: str, section_text: str) -> str:
    """The spec with ``section_text``'s keys set in their section (added if new)."""
    head = section_text.split("\n", 1)[0]
    if head.startswith("[[") or head not in text:
        return text + "\n" + section_text
    lines = text.split("\n")
    i = lines.index(head)
    keys = {ln.split("=")[0].strip(): ln for ln in section_text.split("\n")[1:] if "=" in ln}
    j = i + 1
    while j < len(lines) and not lines[j].startswith("["):
        k = lines[j].split("=")[0].strip()
        if k in keys:
            lines[j] = keys.pop(k)
        j += 1
    lines[j:j] = list(keys.values())
    return "\n".join(lines)


@pytest.mark.parametrize("text,key", BAD, ids=[k for _, k in BAD])
def test_bad_spec_is_one_line_naming_the_key(spec_path, tmp_path, capsys, text, key):
    spec = spec_path.with_name(f"bad_{abs(hash(text))}.toml")
    body = SPEC.replace("grain_levels_um = [150, 1000]\n", "") if "grain_levels" in text \
        else SPEC
    spec.write_text(_replace(body, text))
    out = tmp_path / "out"
    err = bad_call(["campaign", str(spec), "--out", str(out), "--workers", "0"], capsys)
    assert f"error: {spec}: {key}" in err, err
    assert not out.exists()


def test_bad_campaign_runs_are_refused_before_writing(spec_path, tmp_path, capsys):
    out = tmp_path / "out"
    narrow = spec_path.with_name("narrow.tif")      # narrower than the beam pair's offset
    dems.synthetic_ice_sheet(narrow, width_m=3000, length_m=3000, posting_m=80, hole=False)
    spec = spec_path.with_name("narrow.toml")
    spec.write_text(SPEC.replace("dem.tif", "narrow.tif").replace('"gt1l,gt1r"', '"all"')
                    .replace('grain_um = "grain.tif"\ngrain_levels_um = [150, 1000]',
                             "grain_um = 200"))
    err = bad_call(["campaign", str(spec), "--out", str(out), "--workers", "0"], capsys)
    assert "no granules: no track crosses the DEM" in err and not out.exists()
    for args, option in ((["--scheduler", "tcp://127.0.0.1:1", "--workers", "2"], "--workers"),
                         (["--workers", "-1"], "--workers"), (["--threads", "0"], "--threads"),
                         (["--out", str(tmp_path / "missing" / "o")], "--out")):
        err = bad_call(["campaign", str(spec_path), "--out", str(out), *args], capsys)
        assert f"error: {option}" in err and not out.exists()
    err = bad_call(["campaign", str(tmp_path / "none.toml"), "--out", str(out)], capsys)
    assert "error: SPEC" in err


# --------------------------------------------------------------------------- names and orbit
def test_icesat2_file_names_and_granule_regions():
    t = (tk.parse_utc("2019-06-01T12:34:56Z") - tk.SDP_EPOCH_UTC).total_seconds()
    name = tk.product_name("ATL03", t_s=t, rgt=123, cycle=3, region=5, version=6, revision=1)
    assert name == "ATL03_20190601123456_01230305_006_01.h5"
    assert tk.parse_product_name(name) == {
        "product": "ATL03", "date": "20190601", "time": "123456", "rgt": 123, "cycle": 3,
        "region": 5, "version": 6, "revision": 1}
    assert tk.parse_product_name("ATL03_2019_0123_006_01.h5") is None
    # the metadata's file name and release (VersionID) are the name's, also from the
    # campaign's temporary name around it; a name without a release gets 001
    from lidar_mitsuba.products.metadata import release_of
    assert release_of(f"/out/granules/ATL03/{name}") == (name, "006")
    assert release_of(f"/out/.{name}.part.h5") == (name, "006")
    assert release_of("run/ATL03_sim.h5") == ("ATL03_sim.h5", "001")
    asc = [tk.granule_region(lat, ascending=True) for lat in (10, 40, 70, 85, -10, -40, -60, -85)]
    desc = [tk.granule_region(lat, ascending=False) for lat in (10, 40, 70, 85, -10, -40, -60,
                                                                -85)]
    assert asc == [1, 2, 3, 4, 14, 13, 12, 11] and desc == [7, 6, 5, 4, 8, 9, 10, 11]


def test_repeat_orbit_heading_spacing_and_times():
    """The ground track's heading against the closed form (derived in tracks' docstring),
    measured on a sphere between points 1 m apart; Clairaut's relation without the Earth's
    rotation; the RGTs' nodes on a 360/1387 deg grid; times a period apart."""
    from pyproj import Geod
    sphere = Geod(a=tk.EARTH_RADIUS_M, b=tk.EARTH_RADIUS_M)
    o = tk.RepeatOrbit()
    assert o.q == pytest.approx(91 / 1387)
    du = 1.0 / tk.EARTH_RADIUS_M
    for rotating in (True, False):
        orb = o if rotating else tk.RepeatOrbit(days=0)
        for u in np.radians([5.0, 30.0, 60.0, 80.0, 100.0, 150.0, 200.0, 300.0]):
            lat, lon = orb.ground_track(np.array([u - du, u + du]), 17)
            az = sphere.inv(lon[0], lat[0], lon[1], lat[1])[0] % 360
            mid = orb.ground_track(u, 17)[0]
            ascending = math.cos(u) > 0
            closed = float(orb.heading_deg(mid, ascending=ascending))
            assert abs((az - closed + 180) % 360 - 180) < 1e-3, (u, az, closed)
            if not rotating:      # Clairaut: sin(heading) = cos(i) / cos(lat)
                assert math.sin(math.radians(closed)) == pytest.approx(
                    math.cos(math.radians(92.0)) / math.cos(math.radians(mid)), abs=1e-9)
    assert float(o.heading_deg(70.0, ascending=True)) == pytest.approx(352.87, abs=0.01)
    assert float(o.heading_deg(70.0, ascending=False)) == pytest.approx(187.13, abs=0.01)
    nodes = np.sort(o.rgt_node_lon_deg(np.arange(1, 1388)))
    np.testing.assert_allclose(np.diff(nodes), 360 / 1387, atol=1e-9)
    shift = (o.rgt_node_lon_deg(2) - o.rgt_node_lon_deg(1)) % 360
    assert shift == pytest.approx(360 - 360 * 91 / 1387)
    assert o.time_s(2, 4, 0.0) - o.time_s(1, 4, 0.0) == pytest.approx(91 * 86228.458 / 1387)
    assert o.cycle_of(o.cycle_start_s(4) + 1.0) == 4 and o.cycle_of(0.0) == 0


#: NASA's reference ground track KML of cycle 14 (ICESat-2 technical specifications,
#: icesat-2.gsfc.nasa.gov/science/specs), RGT 1's first points, one a minute from 07:57:49 UTC
#: on 2021-12-22 (as the IceSat2R R package's RGT_cycle_14 data and its "ICESat-2 Mission
#: Orbits" vignette print them): (latitude, longitude) [deg]
RGT1_CYCLE14 = [(0.02795893, -0.1318472), (3.868758, -0.5162124), (7.709809, -0.901809),
                (11.55065, -1.289879), (15.39082, -1.681755), (19.2299, -2.078916),
                (23.06748, -2.483051), (26.90316, -2.896146), (30.73662, -3.3206),
                (34.56754, -3.759374)]
WGS84_E2 = 6.69437999014e-3


def _u(o, lat_deg, ascending=True):
    """The argument of latitude [rad, in [0, 2 pi)] at which the model's track is at
    ``lat_deg`` (its sphere's latitude taken as geodetic, as the model does)."""
    a = math.asin(math.sin(math.radians(lat_deg)) / math.sin(math.radians(o.inclination_deg)))
    return (a if ascending else math.pi - a) % (2 * math.pi)


def _lat_error_deg(lat_deg):
    """How far the model's latitude may be off a geodetic one [deg]: it is the sphere's (a
    geocentric latitude), which differs from the geodetic by (e^2 / 2) sin(2 lat) rad to first
    order in WGS84's e^2 (0.19 deg at 45 deg)."""
    return math.degrees(WGS84_E2 / 2 * abs(math.sin(2 * math.radians(lat_deg))))


def test_the_orbit_phase_is_icesat2s_as_published():
    """RGT 1 of the default orbit runs through NASA's published points of RGT 1 (cycle 14) and
    passes them at their times, and the real ATL03 granule this package ships names the times
    at which RGT 235 of cycle 1 entered its granule regions 3, 4 and 5 (its lineage's ATL02
    files and its own name): the model's node longitude and times are the mission's.

    Tolerances, from what the model leaves out: (a) longitude at a published latitude: the
    model's latitude is the sphere's, off the geodetic by up to (e^2 / 2) sin(2 lat), which
    moves the track by that times its slope |dlon/dlat| (the model's own, here), plus 0.002
    deg for the node's rounding (to 0.001 deg) and the KML's digits. (b) Time at a published
    latitude: the same latitude error over the model's dlat/dt, plus 1 s (times given to whole
    seconds: published and the anchors'), plus 5 s for the real orbit's non-uniform motion
    along a revolution that a circular orbit at a uniform rate leaves out (the frozen orbit's
    eccentricity, e ~ -J3 / (2 J2) (R / a) sin(i) = 0.0011, advances the satellite by up to
    2e rad, 2.0 s; J2's short-period terms by ~1.5 J2 (R / a)^2 rad, 1.3 s; and the nodal day's
    rounding, 0.5 s by cycle 14: together 3.8 s, taken as 5)."""
    from lidar_mitsuba.geotrack import parse_utc
    o = tk.RepeatOrbit()
    assert (o.node_lon_deg, o.cycle1_utc, o.nodal_day_s) == (-0.129, "2018-09-28T16:20:02Z",
                                                            86228.458)
    t0 = (parse_utc("2021-12-22T07:57:49Z") - tk.SDP_EPOCH_UTC).total_seconds()
    rate = 360.0 / o.period_s          # deg of argument of latitude per second
    for k, (lat, lon) in enumerate(RGT1_CYCLE14):
        u = _u(o, lat)
        _, model_lon = o.ground_track(u, 1)
        du = 1e-4
        slope = abs(float(np.diff(o.ground_track(np.array([u - du, u + du]), 1)[1])[0])
                    / float(np.diff(o.ground_track(np.array([u - du, u + du]), 1)[0])[0]))
        err = _lat_error_deg(lat)
        assert abs((float(model_lon) - lon + 180) % 360 - 180) <= slope * err + 0.002, (lat, lon)
        dlat_du = math.sin(math.radians(92.0)) * math.cos(u) / math.cos(math.radians(lat))
        tol = err / dlat_du / rate + 1.0 + 5.0
        assert abs(o.time_s(1, 14, u) - (t0 + 60.0 * k)) <= tol, (lat, o.time_s(1, 14, u) - t0)
    # the old nominal phase (node at 0 deg) misses the first point by 0.13 deg: the check bites
    assert abs(float(tk.RepeatOrbit(node_lon_deg=0.0).ground_track(_u(o, 0.028), 1)[1])
               + 0.1318) > 0.1
    # the granule regions' start times, cycle 1, from the shipped granule's metadata
    from lidar_mitsuba.twin import REAL_SUBSET
    with h5py.File(REAL_SUBSET, "r") as f:
        lineage = f["METADATA/Lineage/ATL02"].attrs["fileName"]
        names = [n.decode() for n in lineage] + [
            f["METADATA/DatasetIdentification"].attrs["fileName"].decode()]
        begin = f["METADATA/Extent"].attrs["rangeBeginningDateTime"].decode()
    boundary = {3: (59.5, True), 4: (80.0, True), 5: (80.0, False)}   # ATL03's regions
    seen = set()
    for name in names:
        fields = tk.parse_product_name(name)
        assert (fields["rgt"], fields["cycle"]) == (235, 1)
        lat, asc = boundary[fields["region"]]
        stamp = fields["date"] + fields["time"]
        t = (parse_utc(f"{stamp[:4]}-{stamp[4:6]}-{stamp[6:8]}T{stamp[8:10]}:{stamp[10:12]}:"
                       f"{stamp[12:]}Z") - tk.SDP_EPOCH_UTC).total_seconds()
        if name.startswith("ATL03"):
            assert begin.startswith(f"{stamp[:4]}-{stamp[4:6]}-{stamp[6:8]}T{stamp[8:10]}")
        u = _u(o, lat, asc)
        dlat_du = abs(math.sin(math.radians(92.0)) * math.cos(u) / math.cos(math.radians(lat)))
        tol = _lat_error_deg(lat) / dlat_du / rate + 1.0 + 5.0
        assert abs(o.time_s(235, 1, u) - t) <= tol, (name, o.time_s(235, 1, u) - t, tol)
        seen.add(fields["region"])
    assert seen == {3, 4, 5}
    assert o.cycle_of((parse_utc("2018-10-14T00:24:44Z") - tk.SDP_EPOCH_UTC)
                      .total_seconds()) == 1


def test_crossings_keep_every_beam_over_the_dem(spec_path, serial):
    from lidar_mitsuba.geotrack import beam_layout, select_beams
    dem = dems.DEM.open(spec_path.with_name("dem.tif"))
    cs = tk.crossings(dem, tk.RepeatOrbit(), beams=select_beams("gt1l,gt1r"), margin_m=130)
    assert [(c.rgt, c.ascending) for c in cs] == [(414, True), (856, True), (864, False),
                                                  (1306, False)]
    for c in cs:
        h = tk.RepeatOrbit().heading_at_u_deg(c.u_rad)
        assert np.all(np.abs(((h - (352.9 if c.ascending else 187.1)) + 180) % 360 - 180) < 0.2)
    # every segment the campaign simulated lies on valid DEM; fewer tracks fit six beams
    seg = serial.segments
    surf = dems.DEMSurface(dem)
    from pyproj import Transformer
    x, y = Transformer.from_crs("EPSG:4326", dem.crs, always_xy=True).transform(
        seg["longitude"].to_numpy(), seg["latitude"].to_numpy())
    assert np.isfinite(surf.height_m(np.asarray(x), np.asarray(y))).all()
    six = tk.crossings(dem, tk.RepeatOrbit(), beams=beam_layout(0), margin_m=130)
    assert {(c.rgt, c.ascending) for c in six} < {(c.rgt, c.ascending) for c in cs}


# --------------------------------------------------------------------------- rasters
def test_a_property_raster_is_read_by_window(tmp_path, monkeypatch):
    """Values along a 2 km track come from one small window of a 40 x 30 km raster (read by
    rasterio's window, not whole, as a raster above ``WHOLE_DEM_MAX_BYTES`` is: smaller ones
    are read whole once), bilinear (exact on a linear gradient)."""
    monkeypatch.setattr(dems, "WHOLE_DEM_MAX_BYTES", 0)
    dem = dems.synthetic_ice_sheet(tmp_path / "dem.tif", width_m=40000, length_m=30000,
                                   posting_m=100, hole=False)
    path = rasters.gradient_raster(tmp_path / "g.tif", like=dem, start=100, stop=1000)
    r = rasters.PropertyRaster(path)
    reads = []
    real = dems._open_for_reading

    def spy(p):
        ds = real(p)

        class Spy:
            def read(self, *a, **kw):
                reads.append(kw["window"])
                return ds.read(*a, **kw)
        return Spy()
    monkeypatch.setattr(dems, "_open_for_reading", spy)
    from lidar_mitsuba.geotrack import GeoTrack, select_beams
    g = GeoTrack(start_lat_deg=70.0, start_lon_deg=-45.05, azimuth_deg=0.0)
    lat, lon, shot = rasters.track_points(g, select_beams("gt2l"), n_shots=2858,
                                          spacing_m=0.7)
    assert shot[0] == 0 and shot[-1] == 2857 and np.all(np.diff(shot) > 0)
    v = r.at(lat, lon)
    assert len(reads) == 1 and reads[0].width * reads[0].height < 0.002 * 400 * 300
    from pyproj import Transformer
    x, _ = Transformer.from_crs("EPSG:4326", "EPSG:3413", always_xy=True).transform(lon, lat)
    d = dems.DEM.open(path)
    x0 = d.transform.c + d.posting_m / 2
    x1 = x0 + (d.width - 1) * d.posting_m
    expect = 100 + 900 * (np.asarray(x) - x0) / (x1 - x0)
    np.testing.assert_allclose(v, expect, rtol=1e-5)
    m = rasters.median_along(r, lat, lon)
    assert rasters.snap(m, [100, 500, 1000]) == 500 and math.isnan(rasters.snap(math.nan, [1]))
    assert np.isnan(r.at(np.array([80.0]), np.array([0.0]))).all()        # off the raster


def test_make_raster_cli(tmp_path, capsys):
    dem = dems.synthetic_ice_sheet(tmp_path / "dem.tif", width_m=4000, length_m=3000,
                                   posting_m=100)
    out = tmp_path / "g.tif"
    assert main(["make-raster", "--like", str(dem), "--out", str(out), "--start", "100",
                 "--stop", "1000", "--direction-deg", "0", "--log"]) == 0
    r = dems.DEM.open(out)
    z, _ = r.read_window(*r.bounds_m)
    z = z[1:-1, 1:-1]                           # (the window's pad off the raster: NaN)
    col = z.mean(axis=1)                        # rows south to north: rising northward
    assert col[0] == pytest.approx(100, rel=0.05) and col[-1] == pytest.approx(1000, rel=0.05)
    assert np.all(np.diff(col) > 0)
    capsys.readouterr()
    for args, option in ((["--start", "0", "--log"], "--log"),
                         (["--posting-m", "-1"], "--posting-m")):
        err = bad_call(["make-raster", "--like", str(dem), "--out", str(tmp_path / "b.tif"),
                        "--start", "1", "--stop", "2", *args], capsys)
        assert f"error: {option}" in err and not (tmp_path / "b.tif").exists()


def test_grain_size_is_resolved_per_beam_and_section(spec_path, serial):
    """With a grain-size raster each beam's section has its own level (what its photons
    see), and every segment's ``grain_um`` is the level of its beam's section."""
    from lidar_mitsuba.granule import section_bounds
    tasks = campaign.expand(spec_path)
    seg = serial.segments
    for t in tasks:
        bounds = section_bounds(t.shots, spacing_m=0.7,
                                section_shots=campaign.load_spec(spec_path).run["section_shots"])
        assert t.section_bounds == tuple(map(tuple, bounds)) and t.shot_spacing_m == 0.7
        assert set(t.grain_sections) == {"gt1l", "gt1r"}
        assert all(len(row) == len(bounds) for row in t.grain_sections.values())
        mine = seg[seg["task_index"] == t.task_index]
        for beam, row in t.grain_sections.items():
            assert set(mine.loc[mine["beam"] == beam, "grain_um"]) <= set(row)


def _step_raster(path, like, task, table, posting_m=10.0):
    """A raster over the DEM ``like`` stepping across ``task``'s track between its two beams
    and along it at its first section boundary: ``table[across][along]`` (across 0: gt1l's
    side, along 0: the first section's), constant on each side of the two lines through the
    beams' midpoint at the boundary shot (along the track's chord and square to it)."""
    from pyproj import Transformer

    from lidar_mitsuba.geotrack import GeoTrack, beam_shots, select_beams
    dem = dems.DEM.open(like)
    to_crs = Transformer.from_crs("EPSG:4326", dem.crs, always_xy=True)
    g = GeoTrack(**{**task.track, "polyline": tuple(map(tuple, task.track["polyline"]))})
    lat, lon, az, _ = g.shots(task.shots, spacing_m=task.shot_spacing_m)
    f = task.section_bounds[1][0]
    xy = {}
    for b in select_beams("gt1l,gt1r"):
        blat, blon = beam_shots(lat, lon, az, b)
        xy[b.name] = np.array(to_crs.transform(blon, blat))            # (2, shots)
    p0 = 0.5 * (xy["gt1l"][:, f] + xy["gt1r"][:, f])
    d = xy["gt1l"][:, -1] - xy["gt1l"][:, 0]
    d /= np.hypot(*d)
    n = np.array([-d[1], d[0]])
    n *= np.sign(np.dot(xy["gt1r"][:, f] - p0, n))          # gt1r on the + side
    x0, x1, y0, y1 = dem.bounds_m
    nx, ny = int((x1 - x0) // posting_m), int((y1 - y0) // posting_m)
    X, Y = np.meshgrid(x0 + (np.arange(nx) + 0.5) * posting_m,
                       y1 - (np.arange(ny) + 0.5) * posting_m)
    across = (X - p0[0]) * n[0] + (Y - p0[1]) * n[1] > 0
    along = (X - p0[0]) * d[0] + (Y - p0[1]) * d[1] > 0
    z = np.asarray(table, np.float64)[across.astype(int), along.astype(int)]
    return dems.write_geotiff(path, z, x0_m=x0, y1_m=y1, posting_m=posting_m,
                              crs=dem.crs.to_string())


def test_density_and_roughness_are_resolved_per_beam_and_section(spec_path, monkeypatch,
                                                                  tmp_path):
    """A density raster with a step between the two beams and another along the track (four
    levels, one per beam and section) and a roughness raster stepping along the track: each
    beam's section is planned with its own snow density and roughness (a plan per section,
    seen by a spy on the planner), one kernel table per (grain, density) pair is built, and
    the segment table's density_kg_m3 and roughness_relief_m are each segment's own.

    The run uses the kernel with tables of 1024 walk photons a node (the fewest a node takes:
    this test checks which table and plan each section gets, not a table's precision), four
    tables in ~8 CPU-s, where walking the 150 um snow of 800 shots took ~35 CPU-s."""
    first = campaign.expand(spec_path)[0]
    d = spec_path.parent
    dens = _step_raster(d / "density_steps.tif", d / "dem.tif", first, [[200, 300], [400, 500]])
    rough = _step_raster(d / "rough_steps.tif", d / "dem.tif", first, [[0.0, 2.0], [0.0, 2.0]])
    poly = json.dumps([list(p) for p in first.track["polyline"]])
    spec = d / "steps.toml"
    spec.write_text(SPEC.replace('name = "tiny"', 'name = "steps"')
                    .replace("[orbit]\npasses = \"both\"\n",
                             f"[[tracks]]\npolyline = {poly}\nrgt = {first.rgt}\n")
                    .replace('grain_um = "grain.tif"\ngrain_levels_um = [150, 1000]',
                             f'grain_um = 150\ndensity_kg_m3 = "{dens.name}"\n'
                             'density_levels_kg_m3 = [200, 300, 400, 500]')
                    + f'\n[surface]\nroughness_relief_m = "{rough.name}"\n'
                      'roughness_levels_m = [0, 2]\n')
    (task,) = campaign.expand(spec)
    assert task.section_bounds == first.section_bounds and len(task.section_bounds) == 2
    assert task.density_sections == {"gt1l": [200.0, 300.0], "gt1r": [400.0, 500.0]}
    assert task.roughness_sections == {"gt1l": [0.0, 2.0], "gt1r": [0.0, 2.0]}
    assert task.grain_sections is None and task.grain_um == 150.0
    # one kernel table per (grain, density) pair (the parent's; counted here, then built by
    # the run below, at 1024 walk photons a node)
    built = []
    from lidar_mitsuba.ground.snow import kernel
    with monkeypatch.context() as m:
        m.setattr(kernel, "table", lambda snow, **kw: built.append(
            (snow.grain_radius_um, snow.density_kg_m3)))
        assert campaign.build_kernels([task], campaign.load_spec(spec)) == 4
    assert built == [(150.0, 200.0), (150.0, 300.0), (150.0, 400.0), (150.0, 500.0)]
    walk_spec = d / "steps_walk.toml"          # the walk's sections are the kernel's
    walk_spec.write_text(spec.read_text().replace("[snow]\n", '[snow]\nmodel = "walk"\n'))
    (walked,) = campaign.expand(walk_spec)
    assert walked.density_sections == task.density_sections
    monkeypatch.setattr(kernel, "PHOTONS", 1024)
    monkeypatch.setenv("LIDAR_MITSUBA_KERNEL_PHOTONS", "1024")
    from lidar_mitsuba import planning
    planned, real_plan = [], planning.plan

    def spy(**kw):
        r = kw["surface"].roughness
        planned.append((kw["track"].info["beam"], kw["track"].info["first_shot"],
                        kw["snow"].density_kg_m3, 0.0 if r is None else r.relief_m))
        return real_plan(**kw)
    monkeypatch.setattr(planning, "plan", spy)
    res = campaign.run(spec, out=tmp_path / "out", workers=0, plot=False)
    assert res.failed == 0
    from lidar_mitsuba_plugins import kernel_table      # one table per (grain, density) pair
    small = [t for t in (d / "kernels").rglob("*.npz")   # (the module's others: 2^13 a node)
             if kernel_table.load(t)["photons"].max() == 1024]
    assert len(small) == 4, small
    f = task.section_bounds[1][0]
    assert sorted(planned) == [("gt1l", 0, 200.0, 0.0), ("gt1l", f, 300.0, 2.0),
                               ("gt1r", 0, 400.0, 0.0), ("gt1r", f, 500.0, 2.0)]
    seg = res.segments
    sec = (seg["x_atc"] / task.shot_spacing_m).astype(int) >= f
    for beam in ("gt1l", "gt1r"):
        for k in (0, 1):
            mine = seg[(seg["beam"] == beam) & (sec == bool(k))]
            assert len(mine) >= 4
            assert set(mine["density_kg_m3"]) == {task.density_sections[beam][k]}
            assert set(mine["roughness_relief_m"]) == {task.roughness_sections[beam][k]}
    assert np.isfinite(seg["density_kg_m3_raster"]).all()
    # the ATL03 file records each section's own model: the first in config, the second
    # (planned anew) in section_configs
    (a3,) = (tmp_path / "out" / "granules" / "ATL03").glob("ATL03_*.h5")
    with h5py.File(a3) as h5:
        for beam in ("gt1l", "gt1r"):
            attrs = h5["truth"][beam].attrs
            first = json.loads(attrs["config"])
            (later,) = json.loads(attrs["section_configs"])
            assert later["first_shot"] == f
            got = [(c["snow"]["density_kg_m3"], c["surface"].get("roughness", {}).get(
                "relief_m", 0.0)) for c in (first, later["config"])]
            assert got == [(task.density_sections[beam][k], task.roughness_sections[beam][k])
                           for k in (0, 1)]


def test_uniform_sections_keep_one_value_per_granule(spec_path):
    """A density or roughness raster whose level is the same in every beam's section leaves
    the task as with one value (no sections, the same task id and seeds): a constant raster
    gives the table of its number."""
    d = spec_path.parent
    const = rasters.gradient_raster(d / "density_const.tif", like=d / "dem.tif", start=300,
                                    stop=300, posting_m=400)
    number = spec_path.with_name("number.toml")
    number.write_text(SPEC.replace("grain_levels_um = [150, 1000]",
                                   "grain_levels_um = [150, 1000]\ndensity_kg_m3 = 300"))
    raster = spec_path.with_name("raster.toml")
    raster.write_text(SPEC.replace("grain_levels_um = [150, 1000]",
                                   f'grain_levels_um = [150, 1000]\ndensity_kg_m3 = '
                                   f'"{const.name}"\ndensity_levels_kg_m3 = [200, 300]'))
    a, b = campaign.expand(number), campaign.expand(raster)
    assert [t.task_id for t in a] == [t.task_id for t in b]
    assert all(t.density_sections is None and t.density_kg_m3 == 300.0 for t in b)


def test_segments_are_labelled_by_the_task_s_section_bounds():
    """The worker labels each segment with the section the task says the granule streamed
    (its bounds and shot spacing), not with bounds of its own: here shots 0.5 m apart and a
    second section from shot 100 (50 m)."""
    from lidar_mitsuba.campaign.granules import _section_values
    p = {"section_bounds": ((0, 100), (100, 250)), "shot_spacing_m": 0.5}
    seg = {"x_atc": np.array([20.0, 49.9, 50.0, 60.0, 120.0, np.nan]),
           "beam": np.array(["gt1l", "gt1r", "gt1l", "gt1r", "gt1l", "gt1r"], object)}
    got = _section_values(seg, p, {"gt1l": [1.0, 2.0], "gt1r": [3.0, 4.0]})
    np.testing.assert_array_equal(got, [1.0, 3.0, 2.0, 4.0, 2.0, 3.0])


REAL_FOREST = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "real"


@pytest.mark.skipif(not (REAL_FOREST / "ATL03_gt1r_20220401_forest_wyoming.h5").exists(),
                    reason="the real forest clip is not beside the repository")
def test_icepyx_reads_our_atl08_offline(tmp_path, monkeypatch):
    """icepyx (2.0.2; here, where the readers test has imported it) reads our ATL08 of the real
    forest ATL03 clip from the disk with no network (any connection raises): the product and
    release from METADATA, the orbit from orbit_info, the nested terrain group on the
    segments' times (dimension scales, as in real granules), to the values h5py reads. NASA's
    clip it cannot read: its subsetter dropped METADATA, where icepyx parses the release."""
    import socket
    import warnings
    from lidar_mitsuba.products import atl08

    def no_network(*args, **kwargs):
        raise AssertionError(f"a reader went to the network: {args[1:]}")
    monkeypatch.setattr(socket.socket, "connect", no_network)
    monkeypatch.setattr(socket, "getaddrinfo", no_network)
    import icepyx as ipx
    beam = atl08.from_atl03(REAL_FOREST / "ATL03_gt1r_20220401_forest_wyoming.h5", "gt1r")
    path = atl08.write(beam, tmp_path / "ATL08_ours.h5")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = ipx.Read(str(path))
        assert reader.product == "ATL08"
        reader.variables.append(var_list=["h_te_best_fit", "terrain_slope"])
        ds = reader.load()
        with pytest.raises(Exception, match="version"):
            ipx.Read(str(REAL_FOREST / "ATL08_gt1r_20220401_forest_wyoming.h5"))\
                .variables.append(var_list=["h_te_best_fit"])
    with h5py.File(path) as f:
        want = f["gt1r/land_segments/terrain/h_te_best_fit"][()]
    got = ds["h_te_best_fit"].values.ravel()
    np.testing.assert_array_equal(got[np.isfinite(got)], want[want < atl08.fields.F4_FILL])
    assert int(ds["rgt"].values[0]) == 150
