"""The CLI: bad input gives one line naming the option, exit 2, no traceback, no output file;
good input writes ATL03-layout HDF5 that `stats` reads."""
import json
import subprocess
import sys

import h5py
import mitsuba as mi
import numpy as np
import pytest

from lidar_mitsuba import plotting
from lidar_mitsuba.cli import main


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "lidar_mitsuba.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


# Bad input, each refused with one line naming the option, exit 2, no traceback and no output
# file. "{in}/NAME.xml" are the scene files of BAD_XML (written to a folder of their own).
BAD = [
    (["--shots", "0"], "--shots"),
    (["--shots", "ten"], "--shots"),
    (["--shots", "1e8"], "--shots"),
    (["--pde", "1.5"], "--pde"),
    (["--fill-factor", "-0.1"], "--fill-factor"),
    (["--dead-time-ns", "-3"], "--dead-time-ns"),
    (["--dead-time-ns", "fast"], "--dead-time-ns"),
    (["--channels", "3"], "--channels"),
    (["--signal-photons", "-1"], "--signal-photons"),
    (["--surface", "slope", "--slope-deg", "95"], "--slope-deg"),
    (["--surface", "fractal", "--slope-deg", "5"], "--slope-deg"),
    (["--surface", "fractal", "--p", "-1"], "--p"),
    (["--surface", "fractal", "--grid-m", "0"], "--grid-m"),
    (["--surface", "fractal", "--relief-m", "-2"], "--relief-m"),
    (["--surface", "hill"], "--surface"),
    (["--rho-d", "0.99", "--rho-s", "0.05"], "--rho-d"),
    (["--alpha", "0"], "--alpha"),
    (["--variant", "cuda_ad_mono"], "--variant"),
    (["--variant", "nonsense"], "--variant"),
    (["--beam", "medium"], "--beam"),
    (["--paths-per-shot", "0"], "--paths-per-shot"),
    (["--chunk-shots", "0"], "--chunk-shots"),
    (["--max-depth", "0"], "--max-depth"),
    (["--max-depth", "two"], "--max-depth"),
    (["--window", "0"], "--window"),
    (["--background-mhz", "-1"], "--background-mhz"),
    (["--dark-count-hz", "-1"], "--dark-count-hz"),
    (["--range-gate-m", "0"], "--range-gate-m"),
    (["--seed", "-1"], "--seed"),
    (["--terrain-seed", "-1"], "--terrain-seed"),
    (["--altitude-m", "5"], "--altitude-m"),
    (["--footprint-diameter-m", "-10"], "--footprint-diameter-m"),
    (["--heading-deg", "nan"], "--heading-deg"),
    (["--start-xy-m", "1"], "--start-xy-m"),
    (["--out", "{out}/x.txt"], "--out"),
    (["--out", "{out}"], "--out"),
    (["--out", "/proc/lidar_mitsuba_test.h5"], "--out"),
    (["--out", "{out}/missing/x.h5"], "--out"),
    (["--plot", "{out}"], "--plot"),
    (["--plot", "/proc/lidar_mitsuba_test.png"], "--plot"),
    (["--surface", "fractal", "--grid-m", "1e-3", "--size-m", "8"], "--grid-m"),
    (["-D", "roof_m=20"], "-D"),
    (["--scene", "{in}/building.xml", "-D", "roof_m"], "-D"),
    (["--scene", "{in}/building.xml", "-D", "nope=1"], "--scene"),
    (["--scene", "{in}/building.xml", "--rho-d", "0.5"], "--rho-d"),
    (["--scene", "{in}/building.xml", "--p", "2.0"], "--p"),
    (["--scene", "{in}/building.xml", "--surface", "flat"], "--surface"),
    (["--scene", "{in}/integrator.xml", "--altitude-m", "400000"], "--altitude-m"),
    (["--scene", "{in}/integrator.xml", "--max-depth", "2"], "--max-depth"),
    (["--scene", "{in}/building.xml", "--shots", "2000"], "--shots"),
    (["--scene", "missing.xml"], "--scene"),
    (["--scene", "{in}"], "--scene"),
    (["--scene", "{in}/above_spacecraft.xml"], "--altitude-m"),
] + [(["--scene", f"{{in}}/{name}.xml"], "--scene") for name in (
    "malformed", "empty", "notxml", "noversion", "unknown_plugin", "unknown_parameter",
    "missing_ply", "rho_d_1_2", "alpha_0", "no_shapes", "nan_transform")]

BAD_XML = {
    "malformed": '<scene version="3.0.0"><shape type="rectangle"</scene>',
    "empty": "",
    "notxml": "this is not XML",
    "noversion": '<scene><shape type="rectangle"/></scene>',
    "unknown_plugin": '<scene version="3.0.0"><shape type="nosuch"/></scene>',
    "unknown_parameter": '<scene version="3.0.0"><shape type="rectangle"><float name="bogus" '
                         'value="1"/></shape></scene>',
    "missing_ply": '<scene version="3.0.0"><shape type="ply"><string name="filename" '
                   'value="missing.ply"/></shape></scene>',
    "rho_d_1_2": '<scene version="3.0.0"><shape type="rectangle"><bsdf type="ward"><float '
                 'name="rho_d" value="1.2"/></bsdf></shape></scene>',
    "alpha_0": '<scene version="3.0.0"><shape type="rectangle"><bsdf type="ward"><float '
               'name="alpha" value="0"/></bsdf></shape></scene>',
    "no_shapes": '<scene version="3.0.0"></scene>',
    "nan_transform": '<scene version="3.0.0"><shape type="rectangle"><transform name="to_world">'
                     '<scale value="500"/><translate z="nan"/></transform></shape></scene>',
    "above_spacecraft": '<scene version="3.0.0"><shape type="rectangle"><transform '
                        'name="to_world"><scale value="500"/><translate z="600000"/></transform>'
                        '</shape></scene>',
    "integrator": '<scene version="3.0.0"><integrator type="pathlength"><integer name="max_depth" '
                  'value="1"/><float name="altitude_m" value="300000"/></integrator><shape '
                  'type="rectangle"><transform name="to_world"><scale value="500"/></transform>'
                  '<bsdf type="ward"/></shape></scene>',
}
SCENES = __import__("pathlib").Path(__file__).resolve().parents[1] / "scenes"


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """The bad scene files, and a copy of scenes/building.xml, in a folder of their own."""
    d = tmp_path_factory.mktemp("inputs")
    for name, text in BAD_XML.items():
        (d / f"{name}.xml").write_text(text)
    (d / "building.xml").write_text((SCENES / "building.xml").read_text())
    return d


def call(argv):
    """main()'s exit status, whether it returns it or argparse raises SystemExit."""
    try:
        return main(argv)
    except SystemExit as e:
        return e.code


def test_the_catalogue_is_large():
    assert len(BAD) >= 40


@pytest.mark.parametrize("args,option", BAD, ids=[o + ":" + " ".join(a) for a, o in BAD])
def test_bad_simulate_input(tmp_path, capsys, inputs, monkeypatch, args, option):
    from lidar_mitsuba import machine as resources
    monkeypatch.setattr(resources, "available_memory_bytes", lambda: 8 * 2 ** 30)   # 8 GB
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    out = out_dir / "out.h5"
    args = [a.replace("{in}", str(inputs)).replace("{out}", str(out_dir)) for a in args]
    # a later --shots or --out in args overrides these
    code = call(["simulate", "--shots", "5", "--out", str(out), *args, "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert f"error: {option}" in err and "Traceback" not in err
    assert list(out_dir.iterdir()) == []


def test_bad_input_real_process(tmp_path):
    """Exit code and stderr as a shell user sees them."""
    out = tmp_path / "o.h5"
    r = run("simulate", "--pde", "2", "--out", str(out))
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "--pde" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()
    r = run("simulate", "--shots", "5", "--out", str(tmp_path / "nodir" / "o.h5"))
    assert r.returncode == 2 and "--out" in r.stderr
    r = run("stats", str(tmp_path / "nothere.h5"))
    assert r.returncode == 2 and r.stderr.count("\n") == 1


def test_simulate_then_stats(tmp_path, capsys, monkeypatch):
    out = tmp_path / "run.h5"
    png = tmp_path / "run.png"
    figs = []
    photon_cloud = plotting.photon_cloud

    def keep_figure(**kw):                        # the Figure that --plot draws
        figs.append(photon_cloud(**kw))
        return figs[-1]
    monkeypatch.setattr(plotting, "photon_cloud", keep_figure)
    assert main(["simulate", "--surface", "fractal", "--p", "1.8", "--beam", "weak",
                 "--shots", "300", "--seed", "3", "--out", str(out), "--plot", str(png),
                 "--no-progress", "--size-m", "256"]) == 0
    printed = capsys.readouterr().out
    assert "bias [cm]" in printed and png.stat().st_size > 10_000
    # the figure (paper's Fig. 10) shows the file's photons over the file's surface profile
    (fig,) = figs
    (ax,) = fig.axes
    lines = {ln.get_label().split(" (")[0]: ln for ln in ax.get_lines()}
    with h5py.File(out) as f:                  # (the truth: float64 heights, whole-track x)
        sig = f["truth/gt1r/photons/is_signal"][()].astype(bool)
        shots = {k: f[f"truth/gt1r/shots/{k}"][()]
                 for k in ("along_track_m", "surface_z_m", "z_ref_m")}
        along = shots["along_track_m"][f["truth/gt1r/photons/shot"][()]]
        h = f["truth/gt1r/photons/h_m"][()]
    assert sig.all() and "noise photons" not in lines           # no background: all signal
    assert lines["signal photons"].get_label() == f"signal photons ({sig.size})"
    np.testing.assert_array_equal(lines["signal photons"].get_xdata(), along)
    np.testing.assert_array_equal(lines["signal photons"].get_ydata(), h)
    for label, key in (("surface along track", "surface_z_m"), ("reference elevation", "z_ref_m")):
        np.testing.assert_array_equal(lines[label].get_xdata(), shots["along_track_m"])
        np.testing.assert_array_equal(lines[label].get_ydata(), shots[key])
    assert ax.get_xlabel() == "along-track distance [m]" and ax.get_ylabel() == "elevation [m]"
    title = ax.get_title()
    with h5py.File(out) as f:
        assert f["gt1r"].attrs["atlas_beam_type"] == "weak"
        for name in ("h_ph", "delta_time", "dist_ph_along", "signal_conf_ph"):
            assert "units" in f[f"gt1r/heights/{name}"].attrs
        n = f["gt1r/heights/h_ph"].shape[0]
        assert f["gt1r/heights/signal_conf_ph"].shape == (n, 5)
        assert f["truth/gt1r/photons/shot"].shape == (n,)
        assert f["truth/gt1r/shots/z_ref_m"].shape == (300,)
        cfg = json.loads(f.attrs["config"])
        assert cfg["instrument"]["channels"] == 4 and cfg["surface"]["p"] == 1.8
    assert main(["stats", str(out), "--json", "--window", "100"]) == 0
    doc = json.loads(capsys.readouterr().out)
    for key in ("bias_m", "std_m", "photons_per_shot", "shots"):
        assert key in doc
    assert doc["shots"] == 300 and len(doc["windows"]) == 3 and len(doc["channels"]) == 4
    # stats reads back what simulate wrote: the signal photons' h - z_ref, recomputed here
    with h5py.File(out) as f:
        sig = f["truth/gt1r/photons/is_signal"][()].astype(bool)
        dh = (f["truth/gt1r/photons/h_m"][()]
              - f["truth/gt1r/shots/z_ref_m"][()][f["truth/gt1r/photons/shot"][()]])[sig]
    assert doc["bias_m"] == pytest.approx(dh.mean(), rel=1e-9)
    assert doc["std_m"] == pytest.approx(dh.std(ddof=1), rel=1e-9)
    assert abs(doc["bias_m"]) < 0.1
    assert title.startswith("weak beam over fractal surface")   # the plot's title: the stats
    assert (f"bias {100 * doc['bias_m']:.1f} cm" in title
            and f"precision {100 * doc['std_m']:.1f} cm" in title), title
    # same seed, same numbers
    out2 = tmp_path / "run2.h5"
    main(["simulate", "--surface", "fractal", "--p", "1.8", "--beam", "weak", "--shots", "300",
          "--seed", "3", "--out", str(out2), "--no-progress", "--size-m", "256"])
    capsys.readouterr()
    with h5py.File(out) as a, h5py.File(out2) as b:
        assert np.array_equal(a["gt1r/heights/h_ph"][()], b["gt1r/heights/h_ph"][()])


def test_terrain_command(tmp_path, capsys):
    npy = tmp_path / "t.npy"
    assert main(["terrain", "--p", "2.0", "--size-m", "128", "--relief-m", "4", "--seed", "2",
                 "--out", str(npy)]) == 0
    z = np.load(npy)
    assert z.shape == (128, 128) and abs(np.ptp(z) - 4.0) < 1e-9
    ply = tmp_path / "t.ply"
    assert main(["terrain", "--p", "2.0", "--size-m", "64", "--out", str(ply)]) == 0
    scene = mi.load_dict({"type": "scene", "t": {"type": "ply", "filename": str(ply)}})
    assert scene.shapes()[0].face_count() == 2 * 63 * 63
    assert main(["terrain", "--p", "9", "--out", str(tmp_path / "bad.npy")]) == 2
    err = capsys.readouterr().err
    assert "--p" in err and not (tmp_path / "bad.npy").exists()


def test_atomic_write_leaves_nothing(tmp_path, monkeypatch):
    from lidar_mitsuba.products import atl03
    from lidar_mitsuba.run import simulate
    from lidar_mitsuba.ground.surface import SurfaceSpec
    res = simulate(surface=SurfaceSpec(kind="flat"), shots=20, progress=False)
    from lidar_mitsuba.products import h5write
    real = h5write.append                       # (the beam writer's rows)

    def failing(group, columns):
        if any(path == "dist_ph_along" for path, _ in columns):
            raise OSError("disk full")
        return real(group, columns)

    monkeypatch.setattr(h5write, "append", failing)
    with pytest.raises(OSError):
        atl03.write(res, tmp_path / "x.h5")
    assert list(tmp_path.iterdir()) == []


def test_noise_options_and_segments(tmp_path, capsys):
    out = tmp_path / "noisy.h5"
    assert main(["simulate", "--surface", "fractal", "--size-m", "256", "--beam", "strong",
                 "--shots", "3000", "--background-mhz", "5", "--dark-count-hz", "1e4",
                 "--dead-time-ns", "atlas", "--paralyzable", "--out", str(out),
                 "--no-progress"]) == 0
    assert "false alarms" in capsys.readouterr().out
    with h5py.File(out) as f:
        cfg = json.loads(f.attrs["config"])["instrument"]
        assert cfg["dead_time_ns"] == 3.2 and cfg["paralyzable"] and cfg["background_mhz"] == 5.0
        sig = f["truth/gt1l/photons/is_signal"][()]
        assert 0 < sig.mean() < 1
        assert set(np.unique(f["gt1l/heights/signal_conf_ph"][()])) <= {0, 2, 3, 4}
    seg = tmp_path / "seg.h5"
    assert main(["segments", str(out), "--json", "--out", str(seg)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["n_segments"] > 50 and doc["n_good"] > 0.9 * doc["n_segments"]
    # detected noise rate: background after fill factor and PDE, plus 16 channels of dark
    # counts; its Poisson error from the ~3000 shots x 200 ns x 2.16 MHz = 1300 noise photons
    # (about 80 % of them outside the surface windows): 4.5 / sqrt(0.8 * 1300) = 14 %
    truth = 5 * 0.8 * 0.5 + 16 * 1e4 / 1e6
    assert abs(doc["mean_bckgrd"] - truth) < 0.14 * truth
    with h5py.File(seg) as f:
        for name in ("h_li", "h_li_sigma", "dh_fit_dx", "x_atc", "fpb_corr_m", "bckgrd"):
            assert "units" in f[f"land_ice_segments/{name}"].attrs
    assert call(["segments", str(tmp_path / "none.h5")]) == 2
    assert call(["segments", str(out), "--out", str(tmp_path / "no" / "s.h5")]) == 2


def test_explain_reports_choices_and_warns(tmp_path, capsys):
    out = tmp_path / "e.h5"
    assert main(["simulate", "--surface", "fractal", "--size-m", "256", "--shots", "200",
                 "--explain", "--out", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "max_depth 2 pilot on 200 shots" in text and "Monte Carlo error" in text
    assert "corridor" in text and "footprint sigma / 2.5" in text
    assert "too few" not in text
    assert main(["simulate", "--surface", "flat", "--shots", "50", "--signal-photons", "300",
                 "--paths-per-shot", "128", "--explain", "--out", str(out),
                 "--no-progress"]) == 0
    c = capsys.readouterr()
    assert "too few paths, photons share paths" in c.err and "of 50 shots ran out" in c.out
    assert main(["simulate", "--surface", "flat", "--shots", "50", "--signal-photons", "300",
                 "--explain", "--out", str(out), "--no-progress"]) == 0   # auto: enough paths
    text = capsys.readouterr().out
    assert "too few" not in text and "0 of 50 shots ran out" in text
    assert main(["simulate", "--surface", "fractal", "--size-m", "128", "--shots", "100",
                 "--full-tile", "--explain", "--out", str(out), "--no-progress"]) == 0
    assert "whole 128 m tile" in capsys.readouterr().out


def test_no_command_lists_the_commands_and_version(capsys):
    assert call([]) == 0
    out = capsys.readouterr().out
    for name in ("simulate", "stats", "segments", "terrain", "bench", "reproduce"):
        assert name in out
    assert call(["--version"]) == 0
    assert capsys.readouterr().out.startswith("lidar-mitsuba 0.1.0 (mitsuba ")


def test_generated_options_show_the_api_defaults(capsys):
    """Options come from the dataclasses and simulate(): the help shows their defaults."""
    from lidar_mitsuba.instrument import Instrument
    from lidar_mitsuba.ground.surface import SurfaceSpec
    assert call(["simulate", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert f"(default {Instrument().altitude_m:g})" in text
    assert f"--grid-m M fractal grid spacing [m] (default {SurfaceSpec().grid_m:g})" in text
    assert "(default: 8.17 strong, 2.04 weak)" in text and "--heading-deg DEG" in text


def test_warnings_are_printed_without_explain(tmp_path, capsys):
    out = tmp_path / "w.h5"
    assert main(["simulate", "--surface", "flat", "--shots", "50", "--signal-photons", "300",
                 "--paths-per-shot", "128", "--out", str(out), "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "warning: " in err and "too few paths, photons share paths" in err
    assert main(["simulate", "--surface", "fractal", "--size-m", "64", "--grid-m", "2",
                 "--shots", "50", "--max-depth", "1", "--out", str(out), "--no-progress"]) == 0
    assert "coarser than half the footprint sigma" in capsys.readouterr().err


def test_outputs_follow_the_umask(tmp_path, capsys):
    """New and replaced .h5 files get 0666 less the umask (mkstemp alone gave 0600)."""
    import os
    old = os.umask(0o022)
    try:
        out, seg = tmp_path / "p.h5", tmp_path / "s.h5"
        assert main(["simulate", "--surface", "flat", "--shots", "400", "--out", str(out),
                     "--no-progress"]) == 0
        assert (out.stat().st_mode & 0o777) == 0o644
        out.chmod(0o644)
        assert main(["simulate", "--surface", "flat", "--shots", "400", "--out", str(out),
                     "--no-progress"]) == 0
        assert (out.stat().st_mode & 0o777) == 0o644
        assert main(["segments", str(out), "--out", str(seg)]) == 0
        assert (seg.stat().st_mode & 0o777) == 0o644
        os.umask(0o027)
        assert main(["simulate", "--surface", "flat", "--shots", "400", "--out",
                     str(tmp_path / "q.h5"), "--no-progress"]) == 0
        assert ((tmp_path / "q.h5").stat().st_mode & 0o777) == 0o640
    finally:
        os.umask(old)
    capsys.readouterr()


def test_terrain_refuses_what_memory_cannot_hold(tmp_path, capsys, monkeypatch):
    from lidar_mitsuba import machine as resources
    monkeypatch.setattr(resources, "available_memory_bytes", lambda: 2 * 2 ** 30)    # 2 GB
    for args, option in ((["--size-m", "8192", "--out", str(tmp_path / "x.ply")], "--grid-m"),
                         (["--size-m", "8", "--grid-m", "1e-3", "--out", str(tmp_path / "x.npy")],
                          "--grid-m"), (["--seed", "-1", "--out", str(tmp_path / "x.npy")],
                                        "--seed")):
        assert call(["terrain", *args]) == 2
        err = capsys.readouterr().err
        assert f"error: {option}" in err and len(err.strip().splitlines()) == 1
        if "8192" in args:
            assert "GB of memory" in err
    assert list(tmp_path.iterdir()) == []


def test_xml_scene_with_parameters_and_track_from_the_cli(tmp_path, capsys):
    out = tmp_path / "b.h5"
    assert main(["simulate", "--scene", str(SCENES / "building.xml"), "-D", "roof_m=25",
                 "--heading-deg", "90", "--offset-m", "80", "--shots", "100", "--ideal-detector",
                 "--out", str(out), "--no-progress"]) == 0
    capsys.readouterr()
    with h5py.File(out) as f:
        x = f["truth/gt1l/shots/x_m"][()]
        h = f["gt1l/heights/h_ph"][()]
        cfg = json.loads(f.attrs["config"])
    np.testing.assert_allclose(x, -80.0, atol=1e-9)                # across the roof, along y
    assert abs(np.median(h) - 25.0) < 0.1 and cfg["track"]["heading_deg"] == 90.0
