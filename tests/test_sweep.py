"""Sweeps on Dask: a 2-worker LocalCluster gives exactly the serial table, an interrupted sweep
resumes without rerunning finished tasks, failures are recorded with their message, bad specs
are refused with one line naming the key, and the chart draws the table's numbers."""
import os
import pathlib

import numpy as np
import pandas as pd
import pytest

from lidar_mitsuba import sweep
from lidar_mitsuba.cli import main
from cli_checks import bad_call
from lidar_mitsuba.sweep import plot as sweep_plot

SCENES = pathlib.Path(__file__).resolve().parents[1] / "scenes"

# 5 entries x 2 background rates x 2 replicates = 20 tasks of 200 shots: 12 run, 4 have an
# invalid value (refused before running), 4 fail on the worker (the track misses the scene)
SPEC = {
    "sweep": {"name": "test", "replicates": 2, "seed": 7},
    "fixed": {"beam": "weak", "shots": 200},
    "grid": {"background_mhz": [0.0, 3.0]},
    "list": [{"surface": "flat"},
             {"surface": "fractal", "size_m": 128.0, "p": 1.7},
             {"surface": "fractal", "size_m": 128.0, "rho_d": 0.99},
             {"scene": str(SCENES / "slope.xml"), "params": {"slope_deg": 4}},
             {"scene": str(SCENES / "flat.xml"), "start_xy_m": [5000.0, 0.0]}],
}
N_TASKS = 20


def same_numbers(a, b):
    """Tables equal in everything but when and where the tasks ran."""
    cols = [c for c in a.columns if c not in sweep.RUN_DEPENDENT]
    pd.testing.assert_frame_equal(a[cols], b[cols], check_exact=True)


@pytest.fixture(scope="module")
def serial():
    return sweep.run(SPEC, workers=0)


@pytest.fixture(scope="module")
def distributed():
    return sweep.run(SPEC, workers=2)


def test_two_workers_give_the_serial_table(serial, distributed):
    assert len(serial) == N_TASKS and list(serial["task_index"]) == list(range(N_TASKS))
    same_numbers(serial, distributed)
    pids = {int(w.split(":")[1]) for w in distributed["worker"] if not w.startswith("(")}
    assert pids and os.getpid() not in pids               # ran in the worker processes
    ok = serial[serial["status"] == "ok"]
    assert len(ok) == 12 and (ok["n_photons"] > 0).all()
    assert np.isfinite(ok[["bias_m", "bias_se_m", "std_m", "std_se_m", "robust_std_m",
                           "robust_std_se_m", "photons_per_shot"]].to_numpy()).all()
    assert (ok["atl06_n_segments"] > 0).all() and (ok["config_json"] != "").all()


def test_failures_are_recorded_with_their_message(serial):
    failed = serial[serial["status"] == "failed"]
    assert len(failed) == 8
    invalid = failed[failed["rho_d"] == 0.99]
    assert len(invalid) == 4 and set(invalid["error"]) == {
        "rho_d: rho_d + rho_s must be <= 1 (got 0.99 + 0.05)"}
    missed = failed[failed["start_xy_m"] == "[5000.0, 0.0]"]
    assert len(missed) == 4
    assert all(e.startswith("shots: the track leaves the scene's bounding box")
               for e in missed["error"])
    assert np.isnan(failed["bias_m"]).all() and (failed["n_photons"] == 0).all()


def test_seeds_depend_on_the_task_not_the_order():
    tasks = sweep.expand(SPEC)
    flipped = dict(SPEC, grid={"background_mhz": [3.0, 0.0]}, list=SPEC["list"][::-1])
    key = lambda ts: sorted((t.task_id, t.seed, t.terrain_seed) for t in ts)   # noqa: E731
    assert key(tasks) == key(sweep.expand(flipped))
    assert len({t.seed for t in tasks}) == N_TASKS                 # photons: one per task
    # replicate r is one terrain at every point; replicates differ
    assert {t.replicate: t.terrain_seed for t in tasks} == {
        t.replicate: t.terrain_seed for t in tasks[:2]}
    assert tasks[0].terrain_seed != tasks[1].terrain_seed
    other = sweep.expand(dict(SPEC, sweep=dict(SPEC["sweep"], seed=8)))
    assert not {t.seed for t in other} & {t.seed for t in tasks}


def test_interrupted_sweep_resumes_without_rerunning(tmp_path, serial):
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        sweep.run(SPEC, workers=0, out=out, _stop_after=9)
    first = {f.name: (f.stat().st_mtime_ns, f.read_bytes()) for f in (out / "rows").iterdir()}
    assert len(first) == 9
    assert len(pd.read_parquet(out / "results.parquet")) == 9      # the table so far
    (out / "rows" / ".0123456789abcdef.parquet.999.tmp").write_bytes(b"torn")  # a killed write
    df = sweep.run(SPEC, workers=0, out=out)
    assert (df.attrs["ran"], df.attrs["skipped"]) == (N_TASKS - 9, 9)
    for name, (mtime, data) in first.items():                     # finished tasks untouched
        f = out / "rows" / name
        assert f.stat().st_mtime_ns == mtime and f.read_bytes() == data
    same_numbers(df, serial)
    same_numbers(pd.read_parquet(out / "results.parquet"), serial)
    # a finished sweep runs nothing; a lost row runs again; failed tasks run again on request
    assert sweep.run(SPEC, workers=0, out=out).attrs["ran"] == 0
    (out / "rows" / f"{df['task_id'][0]}.parquet").unlink()
    assert sweep.run(SPEC, workers=0, out=out).attrs["ran"] == 1
    again = sweep.run(SPEC, workers=0, out=out, retry_failed=True)
    assert again.attrs["ran"] == 8
    same_numbers(again, serial)
    # another spec in the same folder: its own tasks only
    more = dict(SPEC, fixed=dict(SPEC["fixed"], shots=150), list=SPEC["list"][:1])
    assert len(sweep.run(more, workers=0, out=out)) == 4
    same_numbers(sweep.load(out, SPEC), serial)


def test_cli_runs_resumes_and_plots(tmp_path, capsys):
    spec = tmp_path / "s.toml"
    spec.write_text('[sweep]\nformat = "csv"\n[fixed]\nsurface = "flat"\nshots = 100\n'
                    '[grid]\nbackground_mhz = [0.0, 2.0]\nbeam = ["weak", "strong"]\n')
    out = tmp_path / "out"
    argv = ["sweep", str(spec), "--out", str(out), "--workers", "0", "--no-progress"]
    assert main(argv + ["--plot", "beam"]) == 0
    text = capsys.readouterr().out
    assert "s: 4 tasks, 4 run now, 0 already done, 0 failed" in text
    table = pd.read_csv(out / "results.csv")
    assert list(table["beam"]) == ["weak", "strong"] * 2 and (table["status"] == "ok").all()
    assert (out / "sweep_beam.png").stat().st_size > 0 and len(list(out.glob("rows/*.csv"))) == 4
    assert main(argv) == 0
    assert "0 run now, 4 already done" in capsys.readouterr().out


BAD_SPECS = [
    ("[grid]\np = 1.8\n", "[grid] p"),
    ("[grid]\nroughness = [1.5, 2.0]\n", "[grid] roughness"),
    ("[grid]\np = []\n", "[grid] p"),
    ("[grid]\np = [1.5, 1.5]\n", "[grid] p"),
    ("[fixed]\np = 1.8\n[grid]\np = [1.5, 2.0]\n", "[grid] p"),
    ("[fixed]\nsurface = { kind = \"flat\" }\n", "[fixed] surface"),
    ("[fixed]\npde = 1.5\n", "[fixed] pde"),
    ("[grid]\npde = [1.5, 2.0]\n", "[grid] pde"),
    ("[fixed]\nshots = 0\n", "[fixed] shots"),
    ("[fixed]\nparams = { slope_deg = 4 }\n", "[fixed] params.slope_deg"),
    ("[fixed]\nrelief = 4\n", "[fixed] relief: unknown parameter (did you mean relief_m?"),
    ("[[list]]\np = 1.5\n[[list]]\np = 1.5\n", "[[list]]"),
    ("[sweep]\nreplicates = 0\n[fixed]\nshots = 10\n", "[sweep] replicates"),
    ("[sweep]\nseed = -1\n[fixed]\nshots = 10\n", "[sweep] seed"),
    ("[sweep]\nformat = \"xlsx\"\n[fixed]\nshots = 10\n", "[sweep] format"),
    ("[sweep]\nworkers = 2\n", "[sweep] workers"),
    ("[sweep]\nreplicates = 2\n[fixed]\nseed = 1\nterrain_seed = 2\n", "[sweep] replicates"),
    ("[fixed]\np = 1979-05-27\n", "[fixed] p"),
    ("[grids]\np = [1.5]\n", "[grids]"),
    ("[grid\np = [1.5]\n", "not valid TOML"),
    ("", "no parameters"),
]


@pytest.mark.parametrize("text,key", BAD_SPECS, ids=[k for _, k in BAD_SPECS])
def test_bad_spec_is_one_line_naming_the_key(tmp_path, capsys, text, key):
    spec = tmp_path / "bad.toml"
    spec.write_text(text)
    out = tmp_path / "out"
    err = bad_call(["sweep", str(spec), "--out", str(out), "--workers", "0"], capsys)
    assert f"error: {spec}" in err and key in err, err
    assert not out.exists()


@pytest.mark.parametrize("args,option", [
    (["--plot", "p"], "--plot"), (["--plot", "shots"], "--plot"),
    (["--scheduler", "tcp://127.0.0.1:1", "--workers", "2"], "--workers"),
    (["--workers", "-1"], "--workers"), (["--threads", "0"], "--threads"),
    (["--out", "{spec}"], "--out"), (["--out", "{tmp}/missing/out"], "--out")])
def test_bad_sweep_options(tmp_path, capsys, args, option):
    spec = tmp_path / "s.toml"
    spec.write_text("[fixed]\nshots = 10\n[grid]\nbackground_mhz = [0.0, 1.0]\n")
    args = [a.replace("{spec}", str(spec)).replace("{tmp}", str(tmp_path)) for a in args]
    err = bad_call(["sweep", str(spec), "--out", str(tmp_path / "out"), *args], capsys)
    assert f"error: {option}" in err
    assert not (tmp_path / "out").exists()
    err = bad_call(["sweep", str(tmp_path / "none.toml"), "--out", str(tmp_path / "o")], capsys)
    assert "error: SPEC" in err


def errorbars(ax):
    """``[(x, y, yerr), ...]`` of each errorbar line of an Axes."""
    out = []
    for c in ax.containers:
        xy = c.lines[0].get_xydata()
        segs = c.lines[2][0].get_segments()
        out.append([(x, y, (s[1][1] - s[0][1]) / 2) for (x, y), s in zip(xy, segs)])
    return out


def test_plot_draws_the_means_and_standard_errors():
    rows = []
    for bg in (0.0, 5.0):
        for p in (2.0, 1.5):
            for r in range(3):
                rows.append({"p": p, "background_mhz": bg, "replicate": r, "seed": r,
                             "status": "ok", "bias_m": 0.01 * p + 0.001 * r * r + bg,
                             "bias_se_m": 0.5, "std_m": p + 0.01 * r, "std_se_m": 0.5})
    rows.append(dict(rows[0], status="failed", bias_m=np.nan, std_m=np.nan))
    rows.append({"p": 1.8, "background_mhz": 0.0, "replicate": 0, "seed": 9, "status": "ok",
                 "bias_m": 0.02, "bias_se_m": 0.003, "std_m": 0.2, "std_se_m": 0.004})
    df = pd.DataFrame(rows)
    fig = sweep_plot.plot(df, "p")
    bias, precision = (errorbars(ax) for ax in fig.axes)
    assert [ax.get_legend_handles_labels()[1] for ax in fig.axes][1] == [
        "background_mhz = 0.0", "background_mhz = 5.0"]
    sd = np.std([0.0, 0.001, 0.004], ddof=1) / np.sqrt(3)        # over the 3 replicates
    np.testing.assert_allclose(bias[0], [(1.5, 100 * (0.015 + 0.005 / 3), 100 * sd),
                                         (1.8, 2.0, 0.3),          # one run: its own SE
                                         (2.0, 100 * (0.02 + 0.005 / 3), 100 * sd)])
    np.testing.assert_allclose(bias[1], [(1.5, 100 * (5.015 + 0.005 / 3), 100 * sd),
                                         (2.0, 100 * (5.02 + 0.005 / 3), 100 * sd)])
    np.testing.assert_allclose(precision[1], [(1.5, 151.0, 0.5773503), (2.0, 201.0, 0.5773503)])


def test_plot_of_a_real_sweep(serial, tmp_path):
    fig = sweep_plot.plot(serial, "background_mhz", path=tmp_path / "c.png")
    assert (tmp_path / "c.png").stat().st_size > 0
    pts = sweep_plot.points(serial, "background_mhz", "bias_m")
    drawn = errorbars(fig.axes[0])
    assert len(drawn) == len(pts) == 3          # flat, fractal p 1.7, the slope scene
    for line, expected in zip(drawn, pts.values()):
        np.testing.assert_allclose(line, [(x, 100 * y, 100 * e) for x, y, e, _ in expected])
    ok = serial[(serial["status"] == "ok") & (serial["surface"] == "flat")
                & (serial["background_mhz"] == 0.0)]
    assert list(pts.values())[0][0][1] == pytest.approx(ok["bias_m"].mean())


def test_atl06_from_the_result_equals_the_file_route(tmp_path):
    from lidar_mitsuba.products import atl03, atl06
    from lidar_mitsuba.instrument import Instrument
    from lidar_mitsuba.run import simulate
    from lidar_mitsuba.ground.surface import SurfaceSpec
    res = simulate(instrument=Instrument(beam="weak", background_mhz=2.0, paralyzable=True),
                   surface=SurfaceSpec(kind="slope", slope_deg=3.0), shots=300, seed=2,
                   progress=False)
    atl03.write(res, tmp_path / "r.h5")
    a, b = atl06.segments_from_result(res), atl06.segments_from_atl03(tmp_path / "r.h5")
    for k, v in a.to_dict(json_safe=False).items():
        np.testing.assert_array_equal(v, getattr(b, k), err_msg=k)
