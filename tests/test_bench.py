"""`bench --quick --smoke` (the quick run with its costliest repetitions cut: bench.run's
docstring) runs and writes finite numbers and its charts (speed is not asserted here);
each chart shows the numbers of bench.json: the Figures the run drew (captured as the chart
functions return them) are read back, data and labels, and compared exactly with the
JSON-loaded document (floats survive JSON exactly)."""
import contextlib
import io
import json
import math
import os

import numpy as np
import pytest

from lidar_mitsuba.cli import main
from lidar_mitsuba.studies import accuracy, bench, breaking_points, peer


@pytest.fixture(scope="module")
def bench_run(tmp_path_factory, snow_study_file):
    """One quick bench at the smoke size through the CLI; the chart functions are wrapped to
    keep the Figures they return (same functions, same arguments: what the PNGs show). Its
    snow study is left for notebook 02 (conftest's ``snow_study_file``), written whole
    before it is named (a worker may be reading the folder)."""
    out = tmp_path_factory.mktemp("bench") / "b"
    figs = {}
    mp = pytest.MonkeyPatch()
    for key, module, name in (("throughput", bench, "_chart"),
                              ("stability", breaking_points, "chart"),
                              ("accuracy", accuracy, "chart"), ("peer", peer, "chart")):
        def wrapper(*args, _fn=getattr(module, name), _key=key, **kw):
            figs[_key] = _fn(*args, **kw)
            return figs[_key]
        mp.setattr(module, name, wrapper)
    printed = io.StringIO()
    try:
        with contextlib.redirect_stdout(printed):
            code = main(["bench", "--out", str(out), "--quick", "--smoke"])
    finally:
        mp.undo()
    assert code == 0
    doc = json.loads((out / "bench.json").read_text())
    part = snow_study_file.with_name(f"{snow_study_file.name}.{os.getpid()}.part")
    part.write_text(json.dumps(doc["snow"]))
    os.replace(part, snow_study_file)
    return {"out": out, "doc": doc, "figs": figs, "printed": printed.getvalue()}


def lines_by_label(ax):
    return {ln.get_label(): ln for ln in ax.get_lines() if not ln.get_label().startswith("_")}


def xy(line):
    return np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float)


def test_bench_quick(bench_run):
    out, doc, printed = bench_run["out"], bench_run["doc"], bench_run["printed"]
    assert (out / "throughput.png").stat().st_size > 10_000
    assert (out / "stability.png").stat().st_size > 10_000
    assert (out / "accuracy_vs_time.png").stat().st_size > 10_000
    for name, d in doc["accuracy_vs_time"].items():
        errs = [r["error_m"] for r in d["rows"]]
        assert errs and all(math.isfinite(e) and e >= 0 for e in errs), name
    for name, rows in doc["stability"].items():     # every row: a result or a stated status
        assert rows and all("status" in r for r in rows), name
    for row in doc["detector"]:
        assert math.isfinite(row["events_per_s"]) and row["events_per_s"] > 0
    assert doc["integrator"]["triangles"] > 100_000
    assert 0 < doc["integrator"]["ratio_to_ceiling"] < 10
    assert all(r["shots_per_s"] > 0 for r in doc["end_to_end"])
    for r in doc["end_to_end"]:   # the rate the run's own casts allow, one per path and bounce
        assert r["cast_bound_shots_per_s"] == pytest.approx(
            doc["integrator"]["rays_per_s"] / (r["paths_per_shot"] * r["traced_depth"]))
        assert r["loop_of_cast_bound"] == pytest.approx(
            r["loop_shots_per_s"] / r["cast_bound_shots_per_s"])
    assert "of its ray casts' bound" in printed
    # paths_per_shot auto against the fixed 128 it replaced, both measured in this run
    e2e = {(r["beam"], str(r["max_depth"]), str(r["paths"])): r for r in doc["end_to_end"]}
    assert [(r["beam"], str(r["max_depth"])) for r in doc["paths_speedup"]] == [
        ("strong", "auto"), ("strong", "1")]
    for r in doc["paths_speedup"]:
        auto, fixed = (e2e[("strong", str(r["max_depth"]), p)] for p in ("auto", "128"))
        assert fixed["paths_per_shot"] == 128 and auto["paths_per_shot"] < 128
        assert r["whole_call"] == pytest.approx(auto["shots_per_s"] / fixed["shots_per_s"])
        assert r["loop"] == pytest.approx(auto["loop_shots_per_s"] / fixed["loop_shots_per_s"])
        assert r["d_bias_m"] == pytest.approx(auto["bias_m"] - fixed["bias_m"])
    assert "paths_per_shot auto (" in printed
    assert "M events/s" in printed and "simplifications of the default run" in printed
    simp = doc["simplifications"]
    assert simp["mc_std_m"] > 0 and len(simp["rows"]) == 4
    assert simp["auto_max_depth"] == [2]    # the default p = 1.8 snow needs the second bounce
    crop = simp["rows"][0]        # the corridor crop is exact: photon for photon the same
    assert crop["d_bias_m"] == 0.0 and crop["d_std_m"] == 0.0
    # the DEM track-length rows: one process each, tiles in proportion to the length
    tl, (granule,) = ([r for r in doc["track_length"] if "beams" not in r],
                      [r for r in doc["track_length"] if "beams" in r])
    assert [r["length_km"] for r in tl] == [1.0, 4.0]
    # a six-beam granule against casting its rays alone: the cast is the cheaper, and the
    # rays are every beam's shots x paths
    assert granule["beams"] == 6 and granule["rays"] >= 6 * granule["shots"]
    assert 0 < granule["cast_s"] < granule["seconds"] and granule["of_cast"] > 1
    # the cast's yardstick: the granule's own ray count, in one of its tiles per >= 1 M rays
    assert granule["cast_tiles"] == max(1, min(8, granule["rays"] // 1_000_000))
    assert granule["cast_lanes"] == granule["rays"] // granule["cast_tiles"]
    assert granule["cast_cv"] >= 0 and granule["cast_cpu_s"] > 0
    # a cold process's granule (interpreter, imports, renderer) costs more than a warm one's
    assert granule["end_to_end_s"] > granule["first_s"] > 0
    assert granule["end_to_end_over_warm"] == pytest.approx(
        granule["end_to_end_s"] / granule["seconds"])
    # and in CPU (both processes): the start and the first granule against the second
    assert granule["end_to_end_cpu_s"] > granule["cpu_s"] > 0
    assert "DEM granule, 6 beams x 4 km" in printed
    assert all(r["peak_rss_mb"] >= r["rss_before_mb"] > 0 and r["photons"] > 0 for r in tl)
    assert tl[1]["tiles"] > tl[0]["tiles"] and "DEM track 4 km" in printed
    # every tile is a new scene: the kernels launched must not grow with the tiles
    assert tl[1]["kernels"] == tl[0]["kernels"]
    assert (out / "track_length.png").stat().st_size > 10_000
    # snow: the volume costs time and biases elevations low, more for larger grains
    sn = doc["snow"]
    assert sn["cost"][0]["grain_um"] is None
    assert [r["model"] for r in sn["cost"][1:]] == ["walk", "kernel"] * 2
    assert all(r["shots_per_s"] < sn["cost"][0]["shots_per_s"] for r in sn["cost"][1:]
               if r["model"] == "walk")
    kv = sn["kernel_vs_surface"]
    assert kv["reps"] == 3 and kv["kernel_over_surface"] > 0
    assert "the time (median of 3 paired runs" in printed
    strong = [r for r in sn["bias"] if r["beam"] == "strong"]
    assert all(r["model"] == "kernel" for r in strong)
    assert strong[-1]["h_li_bias_m"] < strong[0]["h_li_bias_m"] < 0
    assert [r["max_events"] for r in sn["events"]] == [100, 1000, 10000, 30000]
    assert [r["similarity_g"] for r in sn["similarity"]] == [0.0, 0.5]
    assert "snow volume, 200 um" in doc["accuracy_vs_time"]
    # water and air: the pond's bottom within a few cm of n_g x depth with the default depth,
    # and one vertex in fog (attenuation only) further from the reference than eight
    pond = {r["value"]: r for r in doc["media"]["melt pond 2 m"]["rows"]}
    assert pond[8]["error_m"] < 0.05
    fog = {r["value"]: r for r in doc["media"]["fog, optical depth 0.5"]["rows"]}
    assert fog[1]["error_m"] > fog[8]["error_m"]
    assert "melt pond 2 m: fastest" in printed
    # snow optics (quick: two rows, small tables; docs/guide/snow.md's table is the full run)
    so = doc["snow_optics"]["rows"]
    assert [r["name"] for r in so] == ["default (natural snow)", "spheres (g 0.89, B 1.25)"]
    assert all(r["strong_bias_m"] < 0 and r["strong_segments"] > 50 for r in so)
    assert "| default (natural snow) |" in printed
    assert "of surface only" in printed
    assert (out / "snow.png").stat().st_size > 10_000
    assert "track_length.png, snow.png, canopy.png in" in printed       # the CLI names every chart
    if "rows" in doc["peer"]:     # mitransient installed (the test extra has it)
        assert (out / "peer.png").stat().st_size > 10_000
        assert all(math.isfinite(r["error"]) and r["seconds"] > 0 for r in doc["peer"]["rows"])
        assert "peer comparison (mitransient)" in printed
    c = doc["cloud"]          # a cloud in a granule: its cost against clear and rays alone
    assert c["beams"] == 6 and c["clear_s"] > 0 and c["cloud_s"] > 0 and c["table_s"] > 0
    assert c["cloud_of_cast"] > 1 and c["clear_of_cast"] > 1
    assert "cloud in a DEM granule" in printed
    sky = doc["sky"]          # the sky model: closed form, table lookup, one render, as ratios
    assert sky["render_over_closed_form"] > 10 and sky["closed_form_over_lookup"] > 1
    assert "sky, one nadir radiance" in printed
    fo = {r["representation"]: r for r in doc["forest"]}   # a turbid forest over the DEM
    assert set(fo) == {"bare", "turbid"} and fo["turbid"]["over_bare"] > 0
    assert fo["turbid"]["of_cast"] > 1 and fo["turbid"]["atl08_s"] > 0
    assert "forest in a DEM granule" in printed


def test_throughput_chart_shows_the_measured_rates(bench_run):
    """Left: one bar per detector case, its length the case's events/s in millions, named by
    the case; right: ray_intersect and the integrator in million paths/s, then each
    end-to-end loop as the casts it makes per second (its fraction of the cast bound times
    the ray-cast rate: shots/s x paths x bounces)."""
    doc, fig = bench_run["doc"], bench_run["figs"]["throughput"]
    ax, ax2 = fig.axes
    det = doc["detector"]
    np.testing.assert_array_equal([p.get_width() for p in ax.patches],
                                  [r["events_per_s"] / 1e6 for r in det])
    assert [t.get_text() for t in ax.get_yticklabels()] == [r["case"] for r in det]
    assert "million photon events / s" in ax.get_xlabel()
    (target,) = [ln for ln in ax.get_lines() if ln.get_label() == "target 20 M/s"]
    assert list(target.get_xdata()) == [20, 20]
    integ = doc["integrator"]
    loops = [r["loop_shots_per_s"] * r["paths_per_shot"] * r["traced_depth"] / 1e6
             for r in doc["end_to_end"]]
    np.testing.assert_allclose([p.get_width() for p in ax2.patches],
                               [integ["rays_per_s"] / 1e6, integ["paths_per_s"] / 1e6, *loops],
                               rtol=1e-12)
    labels = [t.get_text() for t in ax2.get_yticklabels()]
    assert labels[:2] == ["ray_intersect (ceiling)", "pathlength integrator"]
    assert labels[2:] == [f"loop, {r['beam']}, {r['traced_depth']} bounce"
                          f"{'s' if r['traced_depth'] > 1 else ''}, {r['paths_per_shot']} "
                          f"paths (casts)" for r in doc["end_to_end"]]
    assert "M rays or paths / s" in ax2.get_xlabel()
    assert f"{integ['triangles'] / 1e6:.1f} M triangles" in ax2.get_xlabel()
    assert f"ratio {integ['ratio_to_ceiling']:.2f}" in ax2.get_xlabel()
    assert "throughput" in fig.get_suptitle() and doc["variant"] in fig.get_suptitle()


def test_accuracy_chart_shows_every_setting_and_the_front(bench_run):
    """One panel per track: each knob's points are its rows' (seconds, 100 * error_m) [cm]
    (errors floored at 1e-5 m for the log axis), labelled with the knob's values; the black
    line is the Pareto front of the rows."""
    doc, fig = bench_run["doc"]["accuracy_vs_time"], bench_run["figs"]["accuracy"]
    assert len(fig.axes) == len(doc)
    for ax, (name, d) in zip(fig.axes, doc.items()):
        rows = d["rows"]
        assert ax.get_title().startswith(name) and d["reference"]["source"] in ax.get_title()
        assert ax.get_xlabel() == "wall time of the run [s]"
        assert ax.get_ylabel() == "error of (bias, precision) [cm]"
        assert ax.get_xscale() == ax.get_yscale() == "log"
        lines = lines_by_label(ax)
        knobs = list(dict.fromkeys(r["knob"] for r in rows))
        assert set(lines) == set(knobs) | {"Pareto front"}
        for knob in knobs:
            sel = [r for r in rows if r["knob"] == knob]
            x, y = xy(lines[knob])
            np.testing.assert_array_equal(x, [r["seconds"] for r in sel])
            np.testing.assert_array_equal(y, [100 * max(r["error_m"], 1e-5) for r in sel])
        x, y = xy(lines["Pareto front"])
        front = accuracy.pareto_front(rows)
        np.testing.assert_array_equal(x, [r["seconds"] for r in front])
        np.testing.assert_array_equal(y, [100 * max(r["error_m"], 1e-5) for r in front])
        assert sorted(t.get_text() for t in ax.texts) == sorted(
            f"{r['value']:g}" if isinstance(r["value"], (int, float)) else r["value"]
            for r in rows)


# the stability panels: sweep, y key, closed-form key, words the x and y labels must contain
STABILITY_PANELS = [
    ("slope_deg", "std_m", "expected_std_m", "slope", "precision"),
    ("ward_alpha", "mean_photons_per_shot", "expected_photons_per_shot", "Ward alpha",
     "photons/shot"),
    ("signal_photons", "bias_m", None, "signal photons", "bias"),
    ("dead_time_ns", "bias_m", None, "dead time [ns]", "bias"),
    ("p", "std_m", None, "fractal p", "precision"),
    ("grid_m", "std_m", None, "mesh spacing [m]", "precision"),
    ("altitude_m", "float32_error_m", "max_error_m", "altitude [m]", "path error [m]"),
    ("photons_per_launch", "paths_per_s", None, "photons per launch", "paths / s"),
]


def test_stability_chart_plots_the_sweeps(bench_run):
    """Each panel: the sweep's finite results against the swept value (and the closed form
    where there is one, dashed); every refused or degraded row is marked by a red line at
    its value."""
    doc, fig = bench_run["doc"]["stability"], bench_run["figs"]["stability"]
    assert set(doc) == {p[0] for p in STABILITY_PANELS}
    for ax, (name, key, exp_key, xword, yword) in zip(fig.axes, STABILITY_PANELS):
        rows = doc[name]
        assert xword in ax.get_xlabel() and yword in ax.get_ylabel(), (name, ax.get_xlabel())
        ok = [r for r in rows if r.get(key) is not None and np.isfinite(r[key])]
        assert ok, name
        lines = ax.get_lines()
        x, y = xy(lines[0])
        np.testing.assert_array_equal(x, [r["value"] for r in ok], err_msg=name)
        np.testing.assert_array_equal(y, [r[key] for r in ok], err_msg=name)
        if exp_key:
            x, y = xy(lines[1])
            assert lines[1].get_linestyle() == "--"
            np.testing.assert_array_equal(x, [r["value"] for r in ok], err_msg=name)
            np.testing.assert_array_equal(y, [r[exp_key] for r in ok], err_msg=name)
        bad = [r["value"] for r in rows if not str(r.get("status", "ok")).startswith("ok")]
        marks = [ln.get_xdata()[0] for ln in lines
                 if ln.get_color() == "tab:red" and len(ln.get_xdata()) == 2]
        assert sorted(marks) == sorted(bad), name
    # the sweeps with a refusal by design show it
    for name in ("slope_deg", "ward_alpha", "p", "grid_m"):
        assert any(str(r["status"]).startswith("refused") for r in doc[name]), name


def test_peer_chart_plots_both_tools(bench_run):
    doc = bench_run["doc"]["peer"]
    fig = bench_run["figs"]["peer"]
    if "rows" not in doc:
        assert fig is None
        pytest.skip(doc["skipped"])
    axes = fig.axes
    for ax, plate in zip(axes[:2], ("0 deg plate", "5 deg plate")):
        assert ax.get_title() == plate
        assert "wall time" in ax.get_xlabel() and "L2 error" in ax.get_ylabel()
        lines = lines_by_label(ax)
        tools = {r["tool"] for r in doc["rows"] if r["plate"] == plate}
        assert set(lines) == tools and len(tools) == 4
        for tool in tools:
            rr = sorted((r for r in doc["rows"] if r["plate"] == plate and r["tool"] == tool),
                        key=lambda r: r["paths"])
            x, y = xy(lines[tool])
            np.testing.assert_array_equal(x, [r["seconds"] for r in rr])
            np.testing.assert_array_equal(y, [max(r["error"], 1e-6) for r in rr])
    ax = axes[2]
    assert "range from the plate centre [m]" in ax.get_xlabel()
    assert ax.get_ylabel() == "fraction of the return"
    lines = lines_by_label(ax)
    assert set(lines) == set(doc["waveforms"])
    for name, wf in doc["waveforms"].items():
        fine = np.asarray(wf["fine"])
        n = fine.size // 20
        coarse = fine[:n * 20].reshape(n, 20).sum(1)      # 1 cm of OPL = 5 mm of range
        x, y = xy(lines[name])
        np.testing.assert_allclose(y, coarse / coarse.sum(), rtol=1e-12)
        assert y.sum() == pytest.approx(1.0)
        np.testing.assert_allclose(np.diff(x), wf["bin_m"] * 20 / 2, rtol=1e-6)


def test_two_variants_are_measured_apart_and_charted_side_by_side(tmp_path):
    """`bench --variant A,B --throughput-only`: each variant in a process of its own, both in
    bench.json["by_variant"], and a third panel whose bars are their rates (variant_rates).
    Here two CPU variants (mono and rgb); on a GPU machine, llvm_ad_mono,cuda_ad_mono."""
    out = tmp_path / "b"
    figs = {}
    mp = pytest.MonkeyPatch()
    mp.setattr(bench, "_chart", lambda *a, _fn=bench._chart, **kw: figs.setdefault("f", _fn(*a, **kw)))
    try:
        with contextlib.redirect_stdout(io.StringIO()) as printed:
            code = main(["bench", "--out", str(out), "--smoke", "--throughput-only",
                         "--variant", "llvm_ad_mono,llvm_ad_rgb"])
    finally:
        mp.undo()
    assert code == 0
    doc = json.loads((out / "bench.json").read_text())
    assert list(doc["by_variant"]) == ["llvm_ad_mono", "llvm_ad_rgb"]
    assert doc["variant"] == "llvm_ad_mono" and "stability" not in doc
    for variant, d in doc["by_variant"].items():
        child = json.loads((out / variant / "bench.json").read_text())
        assert child["variant"] == variant and child["integrator"] == d["integrator"]
        assert child["smoke"] and child["quick"]          # the sizes reach the child
        assert 0 <= d["integrator"]["host_share"] <= 1
        assert {r["traced_depth"] for r in d["end_to_end"]} == {1, 2}
    names, rates = bench.variant_rates(doc["by_variant"])
    ax = figs["f"].axes[2]
    widths = [p.get_width() for p in ax.patches]
    np.testing.assert_array_equal(widths, rates["llvm_ad_mono"] + rates["llvm_ad_rgb"])
    assert [t.get_text() for t in ax.get_yticklabels()] == names
    assert ax.get_xscale() == "log"
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert legend == [f"{v}: {d['device']}" for v, d in doc["by_variant"].items()]
    assert "-- llvm_ad_rgb on" in printed.getvalue()


def test_bench_refuses_an_unknown_variant(capsys):
    with pytest.raises(SystemExit) as e:
        main(["bench", "--out", "x", "--variant", "llvm_ad_mono,cuda_ad_nope"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) >= 1 and "--variant: cuda_ad_nope not available here" in err[-1]
