"""`reproduce --quick`: every figure and a finite report; the same numbers from the same command;
`--profile` recovers p; the detector re-runs equal `simulate`; bad input is refused cleanly."""
import json
import math

import numpy as np
import pytest

from lidar_mitsuba import terrain
from lidar_mitsuba.studies import reproduce
from lidar_mitsuba.cli import main
from lidar_mitsuba.instrument import Instrument
from lidar_mitsuba.simulate import simulate
from lidar_mitsuba.surface import SurfaceSpec

PROFILE_P = 1.7


def call(argv):
    try:
        return main(argv)
    except SystemExit as e:
        return e.code


def _write_profile(path):
    """One along-track row of a p = 1.7 fractal (1024 points at 1 m) as distance, height."""
    hf = terrain.fractal(p=PROFILE_P, seed=11)
    x = 250.0 + np.arange(hf.nx, dtype=float)
    np.save(path, np.column_stack([x, hf.z_m[300]]))


@pytest.fixture(scope="module")
def quick_runs(tmp_path_factory):
    """The same quick command twice (with a --profile), and what it printed."""
    base = tmp_path_factory.mktemp("reproduce")
    prof = base / "profile.npy"
    _write_profile(prof)
    outs = []
    for k in range(2):
        out = base / f"run{k}"
        assert call(["reproduce", "--quick", "--out", str(out), "--profile", str(prof)]) == 0
        outs.append(out)
    return outs


def _numbers(obj, path=""):
    """(path, value) of every number in a JSON document."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _numbers(v, f"{path}/{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _numbers(v, f"{path}[{i}]")
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool) or obj is None:
        yield path, obj


def _without_timings(doc):
    doc = json.loads(json.dumps(doc))
    doc.pop("timings_s")
    for f in doc["figures"].values():
        f.pop("time_s")
    return doc


def test_quick_writes_every_figure_and_a_finite_report(quick_runs):
    out = quick_runs[0]
    for name in reproduce.PNG.values():
        png = out / name
        assert png.stat().st_size > 10_000, name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(list(out.glob("*.png"))) == 11
    assert not list(out.glob(".*"))                      # no temporary files left
    doc = json.loads((out / "report.json").read_text())
    numbers = list(_numbers(doc))
    assert len(numbers) > 500
    bad = [p for p, v in numbers if v is None or not math.isfinite(v)]
    assert not bad, bad[:10]
    md = (out / "report.md").read_text()
    for fig, title in reproduce.TITLES.items():
        assert f"## {title}" in md and f"({reproduce.PNG[fig]})" in md
        rows = doc["figures"][fig]["rows"]
        assert rows and all(r["agreement"] and r["ours"] and r["paper"] for r in rows)
    # the headline sits beside the paper's numbers
    assert "up to 2 cm" in md and "| 10 cm |" in md
    for beam in ("weak", "strong"):
        h = doc["headline"][beam]
        assert 0 < h["std_p2_m"] < h["std_p_first_m"] < 0.5
        assert -0.05 < h["bias_min_m"] <= h["bias_max_m"] < 0.05
    assert doc["timings_s"]["total"] > 0
    assert doc["data"]["fig3"]["atm_data_available"] is False


def _errorbars(ax):
    """{label: (x, y)} of the error-bar series of an axis (their data lines)."""
    return {c.get_label(): c.lines[0].get_xydata().T for c in ax.containers
            if hasattr(c, "lines")}


def test_figures_plot_the_computed_numbers(quick_runs):
    """Each figure draws the numbers of its own computation (redrawn here from report.json):
    Fig. 7's histograms and means, Fig. 9's bias and precision per slope, Fig. 12's
    per-beam curves against p, Fig. 13's curves against albedo; with axes naming them."""
    data = json.loads((quick_runs[0] / "report.json").read_text())["data"]
    d = data["fig7"]
    ax = reproduce.plot_fig7(d).axes[0]
    e = 100 * np.array(d["edges_m"])
    steps = [ln for ln in ax.lines if ln.get_drawstyle() == "steps-post"]
    means = [ln for ln in ax.lines if ln.get_linestyle() == ":"]
    assert len(steps) == len(d["detectors"]) == len(means) == 4
    for ln, mean, r in zip(steps, means, d["detectors"].values()):
        np.testing.assert_allclose(ln.get_xdata(), e[:-1])
        np.testing.assert_allclose(ln.get_ydata(), np.array(r["hist_per_shot"]) / (e[1] - e[0]))
        assert mean.get_xdata()[0] == pytest.approx(100 * r["bias_m"])
    assert "elevation" in ax.get_xlabel() and "[cm]" in ax.get_xlabel()

    d = data["fig8_9"]
    top, bottom = reproduce.plot_fig9(d).axes
    slopes = [r["slope_deg"] for r in d["runs"]]
    (xb, yb), (xi, yi) = list(_errorbars(top).values())[:2]
    np.testing.assert_allclose(xb, slopes)
    np.testing.assert_allclose(yb, [100 * r["bias_m"] for r in d["runs"]])
    np.testing.assert_allclose(yi, [100 * r["ideal"]["bias_m"] for r in d["runs"]])
    xs, ys = list(_errorbars(bottom).values())[0]
    np.testing.assert_allclose(ys, [100 * r["std_m"] for r in d["runs"]])
    assert bottom.get_xlabel() == "slope [deg]" and "[cm]" in bottom.get_ylabel()

    d = data["fig10_12"]
    axes = reproduce.plot_fig12(d).axes
    for k, (beam, q) in enumerate((("weak", "bias"), ("strong", "bias"), ("weak", "std"),
                                   ("strong", "std"))):
        ax = axes[k]
        series = _errorbars(ax)
        x, y = series["terrain seed 0 (±2 Monte Carlo SE)"]
        np.testing.assert_allclose(x, np.array(d["p"]) - 0.004)
        np.testing.assert_allclose(y, 100 * np.array(d["summary"][beam][q]["primary"]))
        x, y = [v for lab, v in series.items() if lab.startswith("mean of")][0]
        np.testing.assert_allclose(y, 100 * np.array(d["summary"][beam][q]["mean"]))
    assert axes[2].get_xlabel() == "p"

    d = data["fig13"]
    ax, bx, cx = reproduce.plot_fig13(d).axes
    w = d["summary"]["ward1992"]
    for axis, q in ((ax, "bias"), (bx, "std")):
        x, y = list(_errorbars(axis).values())[0]
        np.testing.assert_allclose(x, np.array(d["rho_d"]) - 0.004)
        np.testing.assert_allclose(y, 100 * np.array(w[q]["mean"]))
        assert "albedo" in axis.get_xlabel()
    lobes = _errorbars(cx)
    assert len(lobes) == 3
    for (x, y), norm in zip(lobes.values(), ("ward1992", "duer", "balanced")):
        np.testing.assert_allclose(y, 100 * np.array(d["summary"][norm]["bias"]["primary"]))


def test_same_command_same_numbers(quick_runs):
    a, b = (json.loads((o / "report.json").read_text()) for o in quick_runs)
    assert _without_timings(a) == _without_timings(b)


def test_profile_recovers_p(quick_runs):
    doc = json.loads((quick_runs[0] / "report.json").read_text())
    up = doc["data"]["fig3"]["user_profile"]
    assert up["n_points"] == 1024 and not up["resampled"] and up["spacing_m"] == 1.0
    # fit_p's own standard error (plus its documented single-profile bias, <= 0.015)
    assert abs(up["p"] - PROFILE_P) < 3 * up["p_se"] + 0.015, up
    row = doc["figures"]["fig3"]["rows"][-1]
    assert row["quantity"] == "p fitted from profile.npy" and row["agreement"] == "within the paper's range"


def test_fit_profile_resamples_text_profiles(tmp_path):
    """A jittered, comma-separated text profile with comments is sorted, resampled to its median
    spacing and still gives p within fit_p's error."""
    hf = terrain.fractal(p=1.9, seed=5)
    rng = np.random.default_rng(2)
    x = 10.0 + 1.5 * np.arange(600) + rng.uniform(-0.2, 0.2, 600)
    z = hf.profile(y_m=100.0, x_m=x)
    path = tmp_path / "p.csv"
    order = rng.permutation(600)
    path.write_text("# distance_m, height_m\n" + "\n".join(f"{a:.4f},{b:.5f}" for a, b in
                                                            zip(x[order], z[order])))
    d, h = reproduce.load_profile(path)
    assert np.all(np.diff(d) > 0) and d.size == 600
    fit = reproduce.fit_profile(d, h)
    assert fit["resampled"] and abs(fit["spacing_m"] - 1.5) < 0.05
    assert abs(fit["p"] - 1.9) < 3 * fit["p_se"] + 0.05


def test_flat_plate_tracks_equal_simulate():
    """Fig. 7's one-trace, many-detector path gives exactly simulate()'s photons per detector."""
    insts = {"ideal": Instrument(beam="weak", ideal_detector=True),
             "one": Instrument(beam="weak", channels=1)}
    tracks = reproduce.flat_plate_tracks(insts, shots=2500, seed=4, chunk_shots=1000)
    for name, inst in insts.items():
        res = simulate(instrument=inst, surface=SurfaceSpec(kind="flat"), shots=2500, seed=4,
                       chunk_shots=1000, progress=False)
        t = reproduce.track_of(res)
        assert t.dh_m.size > 1000
        np.testing.assert_array_equal(t.shot, tracks[name].shot)
        np.testing.assert_array_equal(t.channel, tracks[name].channel)
        # same photons; simulate() meshes only the track's corridor, so float32 hit points
        # round differently (nanometres)
        np.testing.assert_allclose(t.dh_m, tracks[name].dh_m, rtol=0, atol=1e-6)


def test_redetect_equals_simulate():
    """Another detector on kept returns = simulate() with that detector and the same seed."""
    surface = SurfaceSpec(kind="fractal", p=1.6)
    res = simulate(instrument=Instrument(beam="strong"), surface=surface, shots=400, seed=8,
                   chunk_shots=150, keep_returns=True, progress=False)
    weak = Instrument(beam="weak")
    t = reproduce.redetect(res, weak, seed=8, chunk_shots=150)
    ref = reproduce.track_of(simulate(instrument=weak, surface=surface, shots=400, seed=8,
                                      chunk_shots=150, progress=False))
    np.testing.assert_array_equal(t.shot, ref.shot)
    np.testing.assert_array_equal(t.channel, ref.channel)
    np.testing.assert_allclose(t.dh_m, ref.dh_m, rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="geometry"):
        reproduce.redetect(res, weak.replace(footprint_diameter_m=12.0), seed=8)


def _bad_profiles(tmp_path):
    three = tmp_path / "three.txt"
    three.write_text("\n".join("1 2 3" for _ in range(40)))
    short = tmp_path / "short.npy"
    np.save(short, np.zeros((5, 2)))
    dup = tmp_path / "dup.npy"
    np.save(dup, np.column_stack([np.zeros(64), np.arange(64.0)]))
    return {"missing": str(tmp_path / "missing.npy"), "three columns": str(three),
            "too short": str(short), "repeated distances": str(dup)}


@pytest.mark.parametrize("case", ["missing", "three columns", "too short", "repeated distances"])
def test_bad_profile(tmp_path, capsys, case):
    src = tmp_path / "src"
    src.mkdir()
    profile = _bad_profiles(src)[case]
    out = tmp_path / "out"
    code = call(["reproduce", "--quick", "--out", str(out), "--profile", profile])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "--profile" in err and "Traceback" not in err, err
    assert not out.exists()


def test_bad_out(tmp_path, capsys):
    before = sorted(tmp_path.iterdir())
    code = call(["reproduce", "--quick", "--out", str(tmp_path / "nodir" / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "--out" in err
    assert sorted(tmp_path.iterdir()) == before
    f = tmp_path / "file.txt"
    f.write_text("x")
    code = call(["reproduce", "--quick", "--out", str(f)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "--out" in err
    assert f.read_text() == "x"


def test_workers_give_the_same_report(quick_runs, tmp_path):
    """`reproduce --workers 2` computes the figure groups on a Dask LocalCluster: the report's
    numbers are those of the serial run, to the bit."""
    out = tmp_path / "par"
    prof = quick_runs[0].parent / "profile.npy"
    assert call(["reproduce", "--quick", "--workers", "2", "--out", str(out),
                 "--profile", str(prof)]) == 0
    a, b = (json.loads((o / "report.json").read_text()) for o in (quick_runs[0], out))
    assert _without_timings(a) == _without_timings(b)
