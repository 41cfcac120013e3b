"""Command-line interface ``lidar-mitsuba`` (simulate, stats, segments, terrain, make-dem, bench,
reproduce, validate, sweep, campaign, make-raster, atl08, export-las). ``simulate`` and its
options are :mod:`.simulate`, ``campaign`` and ``make-raster`` :mod:`.campaign`, ``atl08`` and
``export-las`` :mod:`.export`; the shared argparse pieces :mod:`.args`.

Bad input is reported as one line naming the option, with exit code 2 and no output file.
The options of ``simulate`` and ``terrain`` are generated from the API (:mod:`.options`):
an option per field of :class:`~lidar_mitsuba.instrument.Instrument`,
:class:`~lidar_mitsuba.ground.surface.SurfaceSpec` and :class:`~lidar_mitsuba.track.Track` and per
keyword of :func:`~lidar_mitsuba.run.simulate`, with their defaults and descriptions.
"""
from __future__ import annotations

import argparse
import inspect
import json
import os
import pathlib
import sys
import time

from . import campaign as cli_campaign, export as cli_export, options as opts, \
    simulate as cli_simulate
from .args import (PROG, Parser, UsageError, connect_scheduler, finite, nonnegative_int,
                   out_dir, out_path, positive_int, rates_line, read_input, spec_error,
                   variant_list, version_text)
from ..constants import ParameterError


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog=PROG, description="Physically based simulation of a spaceborne "
               "photon-counting lidar (ICESat-2/ATLAS-like) with Mitsuba 3.")
    p.add_argument("--version", action="version", version=version_text())
    sub = p.add_subparsers(dest="command", parser_class=Parser, metavar="COMMAND")
    cli_simulate.add_parser(sub)
    _add_file_parsers(sub)
    _add_study_parsers(sub)
    _add_sweep_parser(sub)
    cli_campaign.add_parsers(sub)
    cli_export.add_parsers(sub)
    _add_terrain_parsers(sub)
    return p


def _add_file_parsers(sub) -> None:
    """``stats`` and ``segments``: what a simulated ATL03 file says."""
    st = sub.add_parser("stats", help="elevation bias and precision of a simulated file",
                        description="Bias and precision (mean and std of h - z_ref) of the "
                        "signal photons: overall, per window and per channel.")
    st.add_argument("file", metavar="FILE.h5")
    st.add_argument("--window", type=positive_int, default=1000, metavar="SHOTS",
                    help="shots per window (1000)")
    st.add_argument("--json", action="store_true", help="print JSON instead of a table")

    sg = sub.add_parser("segments", help="ATL06-style surface segments with first-photon-bias "
                        "correction", description="Fit 40 m segments every 20 m (ATL06 land-ice "
                        "style: iterative window, 3-sigma editing, line fit, background, "
                        "first-photon-bias correction) to a simulated ATL03-like file.")
    sg.add_argument("file", metavar="FILE.h5")
    sg.add_argument("--json", action="store_true", help="print a JSON summary instead of a table")
    sg.add_argument("--out", metavar="SEGMENTS.h5",
                    help="write the table as land_ice_segments/h_li, ... (HDF5)")


def _add_study_parsers(sub) -> None:
    """``bench``, ``reproduce`` and ``validate``: the studies with their reports."""
    b = sub.add_parser("bench", help="throughput benchmarks (charts and bench.json)",
                       description="Benchmarks: detector events/s, integrator vs the ray-cast "
                       "ceiling, end-to-end shots/s, accuracy against time, stability sweeps, "
                       "the cost of each model simplification, and the mitransient peer "
                       "comparison (pip install 'lidar_mitsuba[bench]'). Medians of repeats; "
                       "ratios within one run.")
    b.add_argument("--out", required=True, metavar="DIR", help="folder for bench.json and PNGs")
    b.add_argument("--quick", action="store_true", help="small sizes (a first look)")
    b.add_argument("--smoke", action="store_true",
                   help="smaller than --quick: every row, chart and field, its numbers "
                   "meaningless (what the tests run; implies --quick)")
    b.add_argument("--variant", type=variant_list, metavar="NAME[,NAME]",
                   help="Mitsuba variant(s) to measure, e.g. llvm_ad_mono,cuda_ad_mono: each "
                   "in its own process, charted side by side (default: the active one)")
    b.add_argument("--throughput-only", action="store_true",
                   help="only the throughput benchmarks (no studies)")

    rp = sub.add_parser("reproduce", help="regenerate the paper's results (Figs. 3-13) and "
                        "compare them with the paper",
                        description="Rerun the paper's results section at its own sample counts "
                        "(200,000 flat-plate shots, 50,000 per slope, 1000 per fractal track) and "
                        "write the 11 figures, report.md and report.json: each figure's quantities, "
                        "our values with Monte Carlo errors, the paper's values or trends, and "
                        "whether they agree.")
    rp.add_argument("--out", required=True, metavar="DIR",
                    help="folder for the PNGs, report.md and report.json (created if missing; its "
                    "parent must exist)")
    rp.add_argument("--quick", action="store_true",
                    help="fewer shots and configurations, same code (what the tests run)")
    rp.add_argument("--workers", type=positive_int, metavar="N",
                    help="compute the figures as tasks on a Dask LocalCluster of N processes "
                    "(same numbers; default: one after another in this process)")
    rp.add_argument("--profile", metavar="FILE",
                    help="along-track profile to fit p on (Fig. 3): .npy of shape (n, 2) or a "
                    "two-column text file, distance [m] and height [m]")

    va = sub.add_parser("validate", help="compare the simulator with real ATLAS data and "
                        "published validation", description="Simulate the twin of a real "
                        "ATL03 subset (weak beam, night, sea ice; shipped in lidar_mitsuba/data) "
                        "with ATLAS as flown and compare photon rates, background and spread; "
                        "run ATLAS over interior snow and compare ATL06 bias and precision with "
                        "the published ground validation. Writes report.md, report.json and "
                        "figures.")
    va.add_argument("--out", required=True, metavar="DIR",
                    help="folder for report.md, report.json and the PNGs (created if missing)")
    va.add_argument("--quick", action="store_true",
                    help="fewer interior shots (what the tests run)")
    va.add_argument("--real", nargs="*", metavar="FILE_OR_DIR",
                    help="instead, the realism matrix: every beam of these real ATL03, ATL06, "
                    "ATL07 or ATL08 files (a folder: its *.h5; none: the files the package "
                    "ships) against the model's background, signal, strong:weak, spread, tails "
                    "and saturation, with verdicts; writes realism.md, realism.json and "
                    "realism_background.png")
    va.add_argument("--cloud", metavar="TAU,BASE_M,TOP_M",
                    help="with --real: a cloud layer (optical depth, base and top above the "
                    "surface [m], liquid water) given to the cloudy segments: their background "
                    "(its backscatter, the air below dimmed) and signal (dimmed by exp(-2 tau)) "
                    "are then predicted with it instead of the cloud each beam's own "
                    "reflectance and msw_flag imply")
    va.add_argument("--signal-shots", type=nonnegative_int, default=200, metavar="N",
                    help="with --real: shots simulated per beam for its signal through dead "
                    "time (200; 0: the lidar equation alone, no rendering; > 0 also simulates each "
                    "ATL03 + ATL08 forest pair's twin over all its shots, studies.forest_twin, "
                    "and judges the pair's rows against it)")


def _add_terrain_parsers(sub) -> None:
    """``terrain`` and ``make-dem``: synthetic surfaces to simulate over."""
    from ..ground import terrain
    t = sub.add_parser("terrain", help="fractal terrain by Fourier synthesis (.npy or .ply)",
                       description="Synthesise a periodic 1/f^p fractal heightfield (paper eqs. 2-4).")
    opts.add_options(t, terrain.fractal, metavars={"p": "P"})
    t.add_argument("--out", required=True, metavar="FILE.npy",
                   help=".npy (heights [m], shape (N, N)) or .ply (mesh for XML scenes)")
    md = sub.add_parser("make-dem", help="write the synthetic ice-sheet test DEM (GeoTIFF)",
                        description="Write a GeoTIFF DEM like a slice of the Greenland ice "
                        "sheet in EPSG:3413 (for simulate --dem): ~2000 m, 0.5 % slope, "
                        "kilometre-scale undulations, a 1 km nodata square in its south-west "
                        "corner.")
    md.add_argument("--out", required=True, metavar="FILE.tif", help="GeoTIFF to write")
    md.add_argument("--lat", type=float, default=70.0, help="centre latitude [deg] (70)")
    md.add_argument("--lon", type=float, default=-45.0, help="centre longitude [deg] (-45)")
    md.add_argument("--width-m", type=float, default=12000.0, help="east-west extent (12000)")
    md.add_argument("--length-m", type=float, default=12000.0, help="north-south extent (12000)")
    md.add_argument("--posting-m", type=float, default=20.0, help="pixel size (20)")
    md.add_argument("--seed", type=nonnegative_int, default=0, help="undulations' seed (0)")
    md.add_argument("--no-hole", action="store_true", help="no nodata square")


def _cmd_stats(a) -> int:
    from ..products import atl03
    from ..products.retrieval import elevation_report, format_report
    d = read_input(a.file, atl03.read)
    sig = d["is_signal"]
    dh = d["h_m"] - d["z_ref_m"][d["shot"]]
    rep = elevation_report(dh_m=dh[sig], shot=d["shot"][sig], channel=d["channel"][sig],
                           n_shots=d["n_shots"], n_channels=d["n_channels"], window_shots=a.window)
    from ..products.classify import classification_rates
    rates = classification_rates(d["signal_conf"], sig)
    if a.json:
        doc = rep.to_dict()
        doc.update(beam=d["beam"], file=str(a.file), classification=rates)
        print(json.dumps(finite(doc), indent=1))
    else:
        print(format_report(rep, title=f"{a.file} ({d['beam']})"))
        if rates["n_noise"]:
            print(rates_line(rates))
    return 0


def _cmd_segments(a) -> int:
    out = out_path(a.out, (".h5", ".hdf5")) if a.out else None
    from ..products import atl06
    table = read_input(a.file, atl06.segments_from_atl03)
    summary = atl06.summarize(table)
    if out is not None:
        atl06.write(table, out)
    if a.json:
        print(json.dumps(finite(summary), indent=1))
    else:
        def cm(key, sign="+"):
            v = summary.get(key)
            return "n/a" if v is None else f"{100 * v:{sign}.2f} cm"
        print(f"{a.file}: {summary['n_segments']} segments, {summary['n_good']} good, "
              f"{summary['n_flagged']} flagged")
        print(f"  h_li - h_ref    mean {cm('h_li_minus_ref_mean_m')} "
              f"(± {cm('h_li_minus_ref_se_m', '')}), std {cm('h_li_minus_ref_std_m', '')}")
        print(f"  uncorrected     mean {cm('h_mean_minus_ref_mean_m')}")
        print(f"  mean first-photon-bias correction {cm('mean_fpb_corr_m')}, "
              f"mean h_li_sigma {cm('mean_h_li_sigma', '')}")
        bg = summary.get("mean_bckgrd")
        if bg is not None:
            print(f"  background estimate {bg:.3f} MHz")
    if out is not None:   # stdout stays pure JSON with --json
        print(f"wrote {out}", file=sys.stderr if a.json else sys.stdout)
    return 0


def _cmd_bench(a) -> int:
    out = out_dir(a.out)
    from ..studies import bench
    doc = bench.run(out_dir=out, quick=a.quick, smoke=a.smoke, variants=a.variant,
                    throughput_only=a.throughput_only)
    print(bench.format_summary(doc))
    print(f"wrote {out / 'bench.json'} and the charts {', '.join(doc['charts'])} in {out}")
    return 0


def _cmd_make_dem(a) -> int:
    out = out_path(a.out, (".tif", ".tiff"))
    from ..ground.dem import synthetic_ice_sheet
    if not abs(a.lat) < 85:                     # (NaN fails it too)
        raise UsageError("--lat", f"must be within 85 degrees of the equator (got {a.lat:g})")
    if not -180 <= a.lon <= 360:
        raise UsageError("--lon", f"must be in [-180, 360] (got {a.lon:g})")
    for flag, v, lo, hi in (("--width-m", a.width_m, 200, 2e6), ("--length-m", a.length_m, 200, 2e6),
                            ("--posting-m", a.posting_m, 0.5, 1000)):
        if not lo <= v <= hi:
            raise UsageError(flag, f"must be in [{lo:g}, {hi:g}] (got {v:g})")
    if a.width_m / a.posting_m * a.length_m / a.posting_m > 1e8:
        raise UsageError("--posting-m", "more than 1e8 pixels: use a coarser posting")
    import tempfile
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:    # no partial file on failure
        t = pathlib.Path(tmp) / out.name
        synthetic_ice_sheet(t, lat_deg=a.lat, lon_deg=a.lon, width_m=a.width_m,
                            length_m=a.length_m, posting_m=a.posting_m, seed=a.seed,
                            hole=not a.no_hole)
        os.replace(t, out)
    print(f"wrote {out}")
    return 0


def _cmd_terrain(a) -> int:
    out = out_path(a.out, (".npy", ".ply"))
    import numpy as np

    from ..ground import terrain
    from ..ground.surface import export_ply, heightfield_to_trimesh
    kw = inspect.signature(terrain.fractal).bind(
        **opts.given(a, ("p", "size_m", "grid_m", "relief_m", "seed")))
    kw.apply_defaults()
    hf = terrain.fractal(**kw.arguments)
    tmp = out.with_name(f".{out.name}.tmp{out.suffix}")
    try:
        if out.suffix.lower() == ".npy":
            with open(tmp, "wb") as fh:
                np.save(fh, hf.z_m)
        else:
            export_ply(heightfield_to_trimesh(hf), tmp)
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()
    print(f"wrote {out} ({hf.z_m.shape[0]}x{hf.z_m.shape[1]} grid, {hf.grid_m} m, "
          f"relief {hf.relief_m:.3f} m, p {kw.arguments['p']:g}, seed {kw.arguments['seed']})")
    return 0


def _cmd_validate(a) -> int:
    out = out_dir(a.out)
    if a.real is not None:
        from ..studies import realism
        doc = realism.run(a.real, out, signal_shots=a.signal_shots, progress=print,
                          cloud=_cloud(a.cloud))
        print(f"wrote {out / 'realism.md'}, {out / 'realism.json'} and "
              f"{out / 'realism_background.png'}")
        from ..studies import atl08_real          # ATL03 + NASA's ATL08 pairs among them
        if atl08_real.run(a.real, out, progress=print):
            print(f"wrote {out / 'atl08_real.md'} and {out / 'atl08_real.json'}")
        if doc["forest_twin"]:                    # the forest pairs' twins the matrix ran
            from ..studies import forest_twin
            forest_twin.write(doc["forest_twin"], out)
            print(f"wrote {out / 'forest_twin.md'} and {out / 'forest_twin.json'}")
        return 0
    for flag, given in (("--signal-shots", a.signal_shots != 200), ("--cloud", a.cloud)):
        if given:
            raise UsageError(flag, "only applies with --real")
    from ..studies import validate
    doc = validate.run(out, quick=a.quick)
    print(validate.format_summary(doc))
    print(f"wrote {out / 'report.md'}, {out / 'report.json'} and {len(validate.PNG)} figures")
    return 0


def _cloud(text: str | None):
    """``--cloud TAU,BASE_M,TOP_M`` as a liquid-water
    :class:`~lidar_mitsuba.atmosphere.cloud_layer.Cloud`, the clouds of runs (None)."""
    if text is None:
        return None
    from ..atmosphere.cloud_layer import Cloud
    try:
        tau, base, top = (float(v) for v in text.split(","))
    except ValueError:
        raise UsageError("--cloud", f"{text!r}: give TAU,BASE_M,TOP_M, e.g. 1.0,500,1500") \
            from None
    try:
        return Cloud.water(tau, base, top)
    except ParameterError as e:
        raise UsageError("--cloud", e.message) from None


def _cmd_reproduce(a) -> int:
    started = time.perf_counter()
    out = out_dir(a.out)
    from ..studies import reproduce
    profile = None
    if a.profile is not None:
        try:
            profile = reproduce.load_profile(a.profile)
        except ValueError as e:
            raise UsageError("--profile", str(e)) from None
    doc = reproduce.run(out, quick=a.quick, profile=profile,
                        profile_name=pathlib.Path(a.profile).name if a.profile else None,
                        log=lambda msg: print(msg, flush=True), started=started,
                        workers=a.workers)
    print(reproduce.format_summary(doc))
    print(f"wrote {out / 'report.md'}, {out / 'report.json'} and {len(reproduce.PNG)} figures")
    return 0


def _add_sweep_parser(sub) -> None:
    sw = sub.add_parser("sweep", help="parameter sweeps on Dask: a table of bias, precision, "
                        "... per task, resumable", description="Run a grid (or list) of "
                        "parameters and replicates as independent tasks on Dask (a LocalCluster "
                        "here, or any running scheduler), one row of statistics per task, "
                        "appended to DIR as tasks finish; rerunning resumes. The spec format is "
                        "in docs/guide/sweeps.md and in `lidar_mitsuba.sweep`.")
    sw.add_argument("spec", metavar="SPEC.toml", help="the sweep: [sweep], [fixed], [grid], "
                    "[[list]]")
    sw.add_argument("--out", required=True, metavar="DIR", help="folder for rows/, "
                    "results.parquet (or .csv) and charts (created if missing; reusing it "
                    "skips the tasks already done)")
    sw.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler, e.g. "
                    "tcp://host:8786 (default: a LocalCluster on this machine)")
    sw.add_argument("--workers", type=nonnegative_int, metavar="N", help="worker processes "
                    "of the LocalCluster (default: the cores; 0: no Dask, tasks run here one "
                    "after another)")
    sw.add_argument("--threads", type=positive_int, metavar="N", help="Dr.Jit and numba "
                    "threads per task (default: cores / workers on the LocalCluster, the "
                    "workers' own setting with --scheduler)")
    sw.add_argument("--plot", action="append", metavar="PARAM", help="draw bias and precision "
                    "against the swept parameter PARAM to DIR/sweep_PARAM.png (repeatable)")
    sw.add_argument("--retry-failed", action="store_true", help="run the tasks recorded as "
                    "failed again")
    sw.add_argument("--no-progress", action="store_true", help="no progress bar")


def _cmd_sweep(a) -> int:
    """Checks everything (spec, options, scheduler) before anything is written."""
    from .. import sweep
    from ..sweep import plot as sweep_plot
    if not pathlib.Path(a.spec).is_file():
        raise UsageError("SPEC", f"{a.spec!r} not found")

    try:
        spec = sweep.load_spec(a.spec)
    except sweep.SpecError as e:
        raise spec_error(a.spec, e) from None
    out = out_dir(a.out)
    if a.scheduler is not None and a.workers is not None:
        raise UsageError("--workers", "does not apply to --scheduler (its workers are started "
                         "there)")
    for param in a.plot or []:
        if param not in spec.swept:
            raise UsageError("--plot", f"{param!r} is not a swept parameter of {a.spec} "
                             f"(swept: {', '.join(spec.swept) or 'none'})")
    client = connect_scheduler(a.scheduler) if a.scheduler is not None else None
    try:
        df = sweep.run(spec, client, out=out, workers=a.workers, threads=a.threads,
                       retry_failed=a.retry_failed, progress=not a.no_progress,
                       log=lambda msg: print(msg, flush=True))
    except sweep.SpecError as e:
        raise spec_error(a.spec, e) from None
    except KeyboardInterrupt:
        sys.stderr.write(f"{PROG} sweep: the finished tasks are in {out / 'rows'}; run the same "
                         "command again to resume\n")
        raise
    finally:
        if client is not None:
            client.close()
    n, failed = df.attrs["tasks"], df[df["status"] == "failed"]
    print(f"{spec.name}: {n} tasks, {df.attrs['ran']} run now, {df.attrs['skipped']} already "
          f"done, {len(failed)} failed; wrote {df.attrs['results']}")
    for _, row in failed.head(5).iterrows():
        what = ", ".join(f"{k} = {row[k]}" for k in spec.swept) or f"task {row['task_index']}"
        sys.stderr.write(f"{PROG} sweep: warning: task {row['task_id']} ({what}, replicate "
                         f"{row['replicate']}) failed: {row['error']}\n")
    if len(failed) > 5:
        sys.stderr.write(f"{PROG} sweep: warning: {len(failed) - 5} more failed tasks (status "
                         "'failed' in the table)\n")
    for param in a.plot or []:
        path = out / f"sweep_{param}.png"
        sweep_plot.plot(df, param, path=path, title=f"{spec.name}: {n} tasks")
        print(f"wrote {path}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:             # no command: say what there is
        parser.print_help()
        return 0
    prog = f"{PROG} {args.command}"
    try:
        try:
            return {"simulate": cli_simulate.run, "stats": _cmd_stats, "segments": _cmd_segments,
                    "bench": _cmd_bench, "terrain": _cmd_terrain, "make-dem": _cmd_make_dem,
                    "reproduce": _cmd_reproduce, "sweep": _cmd_sweep,
                    "campaign": cli_campaign.cmd_campaign,
                    "make-raster": cli_campaign.cmd_make_raster,
                    "validate": _cmd_validate, "atl08": cli_export.cmd_atl08,
                    "export-las": cli_export.cmd_export_las}[args.command](args)
        except ParameterError as e:
            raise UsageError(opts.option_name(e.name), e.message) from None
    except UsageError as e:
        sys.stderr.write(f"{prog}: error: {e}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write(f"{prog}: interrupted\n")
        return 130
