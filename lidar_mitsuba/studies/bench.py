"""Benchmarks: ``lidar-mitsuba bench --out DIR [--quick]``.

Speed is measured here, never in tests. Every figure is the median of several repetitions
after a warm-up (kernel caches, numba), and ratios are taken within one run, since these
machines are noisy; the detector also reports its best repetition, because on these VMs the
cost of faulting in freshly allocated memory varies two- to threefold between identical runs.
Also runs the stability sweeps of :mod:`.breaking_points` (``stability.png``) and the
accuracy-against-time study and the simplification table of :mod:`.accuracy`
(``accuracy_vs_time.png``), and the mitransient peer comparison of :mod:`.peer`
(``peer.png``; skipped with a note when mitransient is not installed). Writes ``DIR/bench.json`` and ``DIR/throughput.png`` and returns a summary.
"""
from __future__ import annotations

import json
import os
import pathlib
import platform
import statistics
import subprocess
import sys
import time

import numpy as np

from ..detector import pmt
from ..trace import lazy
from ..trace.lazy import dr, mi

scn = lazy.module("lidar_mitsuba.trace.scene")
from ..ground import terrain
from ..constants import C_M_PER_NS
from ..instrument import Instrument
from ..detector.records import Returns
from ..run import simulate
from ..ground.surface import SurfaceSpec, heightfield_to_trimesh
from ..trace.variant import set_variant
from . import accuracy, breaking_points, peer


def _times(fn, *, repeats: int) -> list[float]:
    fn()                                            # warm-up: compile, caches
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return times


def _median_time(fn, *, repeats: int) -> float:
    return statistics.median(_times(fn, repeats=repeats))


def _synthetic_returns(rng, n_shots: int, k: int = 64) -> Returns:
    t0 = 2 * 496e3 / C_M_PER_NS
    return Returns.at_times(t0 + 0.4247 * rng.standard_normal(n_shots * k), paths_per_shot=k)


def bench_detector(*, quick: bool, smoke: bool = False) -> list[dict]:
    """Detector stage throughput [photon events/s] on synthetic returns (no rendering).
    ``smoke``: 5000 shots, one repetition after the warm-up.

    Events counted: the signal photons reaching the detector (Poisson arrivals, before fill
    factor and PDE, each drawn and thinned) plus the noise events generated (background after
    thinning, dark counts) — every photon the stage handles.
    """
    rng = np.random.default_rng(1)
    n_shots = 5_000 if smoke else 20_000 if quick else 200_000
    # paths per shot as a user should set them: about twice the photons per shot or more
    # (fewer paths than photons trigger the slower resampling fallback)
    returns = {k: _synthetic_returns(rng, n_shots, k=k) for k in (64, 256)}
    t0 = 2 * 496e3 / C_M_PER_NS
    gate = np.full(n_shots, t0)
    cases = [
        ("strong, no noise", 64, Instrument(beam="strong")),
        ("strong, 10 MHz background", 64, Instrument(beam="strong", background_mhz=10.0)),
        ("saturated, 100 photons/shot", 256, Instrument(beam="strong", signal_photons=100.0)),
        ("heavy background, 300 MHz", 64, Instrument(beam="strong", background_mhz=300.0,
                                                     range_gate_m=100.0)),
        ("paralyzable, 300 MHz", 64, Instrument(beam="strong", background_mhz=300.0,
                                                range_gate_m=100.0, paralyzable=True)),
        # ATLAS's receiver response (detector/impulse.py: per-photon delays, afterpulses and
        # a second dead-time pass): its cost against the row above it
        ("strong, 10 MHz, ATLAS response", 64, Instrument(beam="strong", background_mhz=10.0,
                                                          pulse_shape="atlas")),
    ]
    rows = []
    for name, k, inst in cases:
        ret = returns[k]
        out = {}

        def run():
            out["det"] = pmt.detect(ret, inst, np.random.default_rng(2), gate_center_ns=gate)

        times = _times(run, repeats=1 if smoke else 3 if quick else 7)
        sec, best = statistics.median(times), min(times)
        det = out["det"]
        bg, dc = inst.noise_per_shot
        events = (det.arrivals_per_shot.sum()
                  + n_shots * (bg * inst.fill_factor * inst.pde + dc * inst.channels))
        rows.append({"case": name, "shots": n_shots, "paths_per_shot": k, "events": float(events),
                     "detected": len(det), "seconds": sec, "best_seconds": best,
                     "events_per_s": events / sec, "best_events_per_s": events / best,
                     "returns_per_s": len(ret) / sec})
    return rows


def device_name() -> str:
    """What the active variant runs on: the GPU's name for CUDA variants (from nvidia-smi when
    it is there), else the CPU model and its core count."""
    if _on_gpu():
        try:
            out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"],
                                 capture_output=True, text=True, timeout=20, check=True)
            return out.stdout.strip().splitlines()[0] + " (CUDA)"
        except (OSError, subprocess.SubprocessError, IndexError):
            return "CUDA GPU"
    model = platform.processor() or "CPU"
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model}, {os.cpu_count()} cores"


def _on_gpu() -> bool:
    return mi.variant().startswith("cuda")


def bench_integrator(*, quick: bool, smoke: bool = False) -> dict:
    """Photon paths/s of the path-length integrator against raw ``scene.ray_intersect`` on the
    same rays and mesh (the 1024 m fractal tile at 1 m, about 2 million triangles), cast in the
    same launches of ``max_lanes`` rays; and where a trace's host time goes: building and
    launching kernels, waiting for the device, compacting and copying returns to numpy.
    On a GPU the track is 1 M shots x 128 paths (the size of an orbit's chunk stream).

    Each repetition times the single- and two-bounce traces and the casts one after the other,
    and a ratio is the median of the repetitions' own ratios, so a machine whose speed drifts
    during the run (this VM's does, by tens of per cent within a minute) biases none of them.
    ``smoke`` (the tests' size): the quick run's mesh and launches, one repetition after the
    warm-up.
    """
    size = 256.0 if quick else 1024.0
    hf = terrain.fractal(p=1.8, size_m=size, grid_m=1.0, relief_m=10.0, seed=0)
    t = time.perf_counter()
    tm = heightfield_to_trimesh(hf, margin_m=13.5)
    scene = scn.scene_from_mesh(tm.vertices, tm.faces)
    build_s = time.perf_counter() - t
    n_shots, k = (2000, 128) if quick else ((2 ** 20, 128) if _on_gpu() else (20000, 256))
    xs = (np.arange(n_shots) * 0.7) % (size - 30) + 15
    ys = np.full(n_shots, size / 2)
    reps = 1 if smoke else 3 if quick else 5
    doc = {"triangles": int(len(tm.faces)), "mesh_build_s": build_s, "paths": n_shots * k,
           "shots": n_shots, "paths_per_shot": k}
    integs = {depth: mi.load_dict(Instrument().integrator_dict(max_depth=depth))
              for depth in (1, 2)}
    splits = {1: [], 2: []}

    def tracer(depth):
        def trace():
            pending = integs[depth].launch(scene, shot_x_m=xs, shot_y_m=ys, paths_per_shot=k,
                                           seed=1)
            pending.result()
            splits[depth].append(pending.timings_s)
        return trace

    rng = np.random.default_rng(3)
    per = max(1, integs[1].max_lanes // k)          # the single-bounce trace's launches
    batches = []
    top = float(tm.vertices[:, 2].max()) + 1.0
    for a in range(0, n_shots, per):
        m = (min(n_shots, a + per) - a) * k
        ox = (np.repeat(xs[a:a + per], k) + 2.5 * rng.standard_normal(m)).astype(np.float32)
        oy = (np.repeat(ys[a:a + per], k) + 2.5 * rng.standard_normal(m)).astype(np.float32)
        batches.append((mi.Float(ox), mi.Float(oy)))

    def cast():
        for ox, oy in batches:
            si = scene.ray_intersect(mi.Ray3f(mi.Point3f(ox, oy, top), mi.Vector3f(0, 0, -1)))
            si.p.z.numpy()            # the same device -> host copy the integrator makes

    runs = {"trace1": tracer(1), "trace2": tracer(2), "cast": cast}
    times = {name: [] for name in runs}
    for fn in runs.values():
        fn()                                        # warm-up: compile, caches
    for _ in range(reps):
        for name, fn in runs.items():
            t = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t)
    cast_s = statistics.median(times["cast"])
    for depth in (1, 2):
        trace_s = statistics.median(times[f"trace{depth}"])
        host = {key: statistics.median(d[key] for d in splits[depth][1:])
                for key in splits[depth][0]}
        row = {"trace_s": trace_s, "paths_per_s": n_shots * k / trace_s, **host,
               "host_share": (host["launch_s"] + host["fetch_s"]) / trace_s,
               "ratio_to_ceiling": statistics.median(
                   c / tr for c, tr in zip(times["cast"], times[f"trace{depth}"]))}
        if depth == 1:
            doc.update(row)
        else:
            doc["two_bounces"] = row
    doc.update(raycast_s=cast_s, rays_per_s=n_shots * k / cast_s)
    return doc


def bench_canopy(*, quick: bool) -> dict:
    """One stand as bare ground, the gap layer, the turbid medium (1 and 3 vertices) and,
    in the full run, explicit leaves: photon paths/s, the time against bare ground, the
    ground's share and the canopy's height profile (:mod:`.canopy_representations`)."""
    from . import canopy_representations
    return canopy_representations.run(quick=quick)


#: end-to-end cases: beam, max_depth, paths per shot ("auto", the default, or the fixed 128
#: it replaced, measured in the same run for the ratio)
END_TO_END_CASES = (("strong", "auto", "auto"), ("weak", "auto", "auto"), ("strong", 1, "auto"),
                    ("strong", "auto", 128), ("strong", 1, 128))


def bench_end_to_end(*, quick: bool, smoke: bool = False) -> list[dict]:
    """Shots/s of ``simulate`` over the p = 1.8 fractal: both beams with the default
    ``max_depth="auto"`` (two bounces on this terrain) and the strong beam with one bounce,
    all with the default ``paths_per_shot="auto"``; and the strong beam's two cases again
    with the fixed 128 paths per shot that ``auto`` replaced (``paths`` says which), with
    their bias and precision beside the speed. ``shots_per_s`` counts the whole call (scene
    build, bounce pilot and path scout included); ``loop_shots_per_s`` the trace-and-detect
    chunk loop alone, what a long track runs at. On a GPU each run is 1 M shots; ``smoke``
    (the tests' size): 500 shots."""
    rows = []
    shots = 500 if smoke else 2000 if quick else (2 ** 20 if _on_gpu() else 20000)
    for beam, max_depth, paths in END_TO_END_CASES:
        out = {}

        def run():
            out["res"] = simulate(instrument=Instrument(beam=beam), shots=shots, seed=1,
                                  surface=SurfaceSpec(kind="fractal", p=1.8), progress=False,
                                  max_depth=max_depth, paths_per_shot=paths)

        sec = _median_time(run, repeats=1 if quick else 3)
        st = out["res"].timings_s
        o = out["res"].report().overall
        rows.append({"beam": beam, "max_depth": max_depth, "paths": paths,
                     "traced_depth": out["res"].config["max_depth"], "shots": shots,
                     "paths_per_shot": out["res"].config["paths_per_shot"],
                     "seconds": sec, "shots_per_s": shots / sec, "stage_seconds": st,
                     "loop_shots_per_s": shots / max(st["trace_s"] + st["detect_s"], 1e-9),
                     "bias_m": o.bias_m, "bias_se_m": o.bias_se_m, "std_m": o.std_m,
                     "std_se_m": o.std_se_m})
    return rows


def paths_speedup(end_to_end: list[dict]) -> list[dict]:
    """For each case measured with both ``paths_per_shot="auto"`` and the fixed 128: the
    speed-ups of ``auto`` (whole call and chunk loop, same run) and its bias and precision
    minus the fixed count's [m] (two runs of different paths, so they differ by Monte Carlo
    noise: compare with the standard errors)."""
    by = {(r["beam"], str(r["max_depth"]), str(r["paths"])): r for r in end_to_end}
    out = []
    for (beam, depth, paths), fixed in by.items():
        auto = by.get((beam, depth, "auto"))
        if paths == "auto" or auto is None:
            continue
        out.append({"beam": beam, "max_depth": fixed["max_depth"],
                    "auto_paths_per_shot": auto["paths_per_shot"],
                    "fixed_paths_per_shot": fixed["paths_per_shot"],
                    "whole_call": auto["shots_per_s"] / fixed["shots_per_s"],
                    "loop": auto["loop_shots_per_s"] / fixed["loop_shots_per_s"],
                    "d_bias_m": auto["bias_m"] - fixed["bias_m"],
                    "d_bias_se_m": float(np.hypot(auto["bias_se_m"], fixed["bias_se_m"])),
                    "d_std_m": auto["std_m"] - fixed["std_m"],
                    "d_std_se_m": float(np.hypot(auto["std_se_m"], fixed["std_se_m"]))})
    return out


def _chart(doc: dict, path: pathlib.Path):
    """Throughput bars (detector cases; integrator and the end-to-end loops against the
    ray-cast ceiling, the loops as the casts they make per second), and, when
    the bench measured several variants, their rates side by side; saved to ``path``.
    Returns the (closed) matplotlib Figure."""
    from ..plotting import plt
    det = doc["detector"]
    variants = doc.get("by_variant", {})
    fig, axes = plt.subplots(1, 3 if len(variants) > 1 else 2,
                             figsize=(17.5 if len(variants) > 1 else 12, 3.8), dpi=110)
    ax = axes[0]
    ax.barh([r["case"] for r in det], [r["events_per_s"] / 1e6 for r in det], color="tab:blue")
    ax.axvline(20, color="k", ls="--", lw=1, label="target 20 M/s")
    ax.set_xlabel("detector stage [million photon events / s]\n"
                  "(the no-noise cases are bound by reading the traced returns)")
    ax.legend(fontsize=8)
    ax.invert_yaxis()
    ax = axes[1]
    integ = doc["integrator"]
    labels = ["ray_intersect (ceiling)", "pathlength integrator"]
    vals = [integ["rays_per_s"] / 1e6, integ["paths_per_s"] / 1e6]
    colors = ["0.6", "tab:orange"]
    for r in doc.get("end_to_end", []):       # the chunk loop, in the casts it makes per second
        if "loop_of_cast_bound" in r:
            labels.append(f"loop, {r['beam']}, {r['traced_depth']} "
                          f"bounce{'s' if r['traced_depth'] > 1 else ''}, "
                          f"{r['paths_per_shot']} paths (casts)")
            vals.append(r["loop_of_cast_bound"] * integ["rays_per_s"] / 1e6)
            colors.append("tab:green")
    ax.barh(labels, vals, color=colors)
    ax.set_xlabel(f"M rays or paths / s ({integ['triangles'] / 1e6:.1f} M triangles; "
                  f"ratio {integ['ratio_to_ceiling']:.2f})\n"
                  "loops: shots/s x paths x bounces (corridor)")
    ax.invert_yaxis()
    if len(variants) > 1:
        ax = axes[2]
        names, rates = variant_rates(variants)
        height = 0.8 / len(variants)
        for j, (variant, vals) in enumerate(rates.items()):
            ax.barh(np.arange(len(names)) + j * height, vals, height=height,
                    label=f"{variant}: {variants[variant]['device']}")
        ax.set_yticks(np.arange(len(names)) + 0.4 - height / 2, names)
        ax.set_xscale("log")
        ax.set_xlabel("million per second (log scale)")
        ax.legend(fontsize=7, loc="lower right")
        ax.invert_yaxis()
    fig.suptitle(f"lidar_mitsuba throughput on {doc.get('device', os.cpu_count())} "
                 f"({mi.variant() if 'variant' not in doc else doc['variant']})")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return fig


def variant_rates(variants: dict) -> tuple[list[str], dict[str, list[float]]]:
    """The rates the side-by-side panel shows, in millions per second: ray casts, integrator
    paths (one and two bounces), end-to-end shots (strong beam, one bounce and auto)."""
    names = ["ray_intersect [M rays/s]", "integrator, 1 bounce [M paths/s]",
             "integrator, 2 bounces [M paths/s]", "end to end, 1 bounce [M shots/s]",
             "end to end, auto [M shots/s]"]
    rates = {}
    for variant, d in variants.items():
        integ = d["integrator"]
        e2e = {(r["beam"], str(r["max_depth"])): r for r in d["end_to_end"]
               if r.get("paths", "auto") == "auto"}
        rates[variant] = [integ["rays_per_s"] / 1e6, integ["paths_per_s"] / 1e6,
                          integ["two_bounces"]["paths_per_s"] / 1e6,
                          e2e[("strong", "1")]["loop_shots_per_s"] / 1e6,
                          e2e[("strong", "auto")]["loop_shots_per_s"] / 1e6]
    return names, rates


def cast_bound(end_to_end: list[dict], rays_per_s: float) -> None:
    """Put into each end-to-end row the rate its ray casts alone would allow
    (``cast_bound_shots_per_s``: ``rays_per_s`` over one cast per path per traced bounce,
    ``rays_per_s`` measured in the same run on nadir rays) and the chunk loop's fraction of
    it (``loop_of_cast_bound``): what is left for sampling, BSDFs, fetching and detecting,
    whatever the machine's speed that minute. A second bounce's rays start on the surface
    in random directions and cost more than nadir rays, so for two bounces it is a bound
    the loop cannot reach."""
    for r in end_to_end:
        bound = rays_per_s / (r["paths_per_shot"] * r["traced_depth"])
        r["cast_bound_shots_per_s"] = bound
        r["loop_of_cast_bound"] = r["loop_shots_per_s"] / bound


def throughput(*, quick: bool, smoke: bool = False) -> dict:
    """The throughput part of the bench in the active variant: detector, integrator, end to
    end, with the variant and the device they ran on."""
    doc = {"variant": mi.variant(), "device": device_name(), "cpu_count": os.cpu_count(),
           "detector": bench_detector(quick=quick, smoke=smoke),
           "integrator": bench_integrator(quick=quick, smoke=smoke),
           "end_to_end": bench_end_to_end(quick=quick, smoke=smoke)}
    cast_bound(doc["end_to_end"], doc["integrator"]["rays_per_s"])
    doc["paths_speedup"] = paths_speedup(doc["end_to_end"])
    return doc


def _throughput_in_child(variant: str, out: pathlib.Path, quick: bool,
                         smoke: bool = False) -> dict:
    """Run the throughput bench of ``variant`` in a process of its own (one variant per
    process) and read its bench.json."""
    sub = out / variant
    cmd = [sys.executable, "-m", "lidar_mitsuba_cli", "bench", "--variant", variant,
           "--throughput-only", "--out", str(sub)] + (["--quick"] if quick else []) + (
               ["--smoke"] if smoke else [])
    subprocess.run(cmd, check=True)
    return json.loads((sub / "bench.json").read_text())


def run(*, out_dir: str | os.PathLike, quick: bool = False, smoke: bool = False,
        variants: list[str] | None = None, throughput_only: bool = False) -> dict:
    """Run every benchmark; write ``bench.json`` and ``throughput.png`` (and, unless
    ``throughput_only``, the study charts) into ``out_dir``.

    ``smoke`` (the tests' size; implies ``quick``): the quick run with its costliest parts
    cut where no row, chart or field depends on them: the detector's cases on 5000 shots
    once, the integrator's traces once, 500 shots end to end, the stability sweeps on fewer
    shots (:func:`.breaking_points.run_all`), each accuracy setting once and
    a smaller reference (the water and fog settings once too: :func:`.media_accuracy.run`),
    two seeds for the simplifications, one for the peer comparison (:func:`.peer.run`), fewer
    shots in the snow walk and snow kernel tables of 2^12 walk photons a node
    (:func:`.snow_bias.run`, :func:`.snow_optics.run`). Its numbers only show that the bench
    runs.

    ``variants``: Mitsuba variants to measure (default: the active one). With several, each
    variant's throughput runs in a process of its own (``out_dir/<variant>/``), the studies
    run in the first, and ``bench.json["by_variant"]`` and the chart hold them side by side.
    """
    quick = quick or smoke
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    variants = list(variants or [mi.variant()])
    if len(variants) == 1:
        set_variant(variants[0])
        doc = throughput(quick=quick, smoke=smoke)
    else:
        by = {v: _throughput_in_child(v, out, quick, smoke) for v in variants}
        set_variant(variants[0])
        doc = dict(by[variants[0]])
        doc["by_variant"] = {v: {k: d[k] for k in ("device", "cpu_count", "detector",
                                                   "integrator", "end_to_end")}
                             for v, d in by.items()}
    doc.update(quick=quick, smoke=smoke, machine=platform.platform(), drjit=dr.__version__,
               mitsuba=mi.__version__)
    if not throughput_only:
        doc["stability"] = breaking_points.run_all(quick=quick, smoke=smoke)
        doc["accuracy_vs_time"] = accuracy.run(quick=quick, smoke=smoke)
        doc["simplifications"] = accuracy.simplifications(quick=quick, smoke=smoke)
        doc["peer"] = peer.run(quick=quick, smoke=smoke)
        from . import snow_bias, track_length
        doc["track_length"] = track_length.run(out=out, quick=quick)
        doc["snow"] = snow_bias.run(quick=quick, smoke=smoke)
        doc["accuracy_vs_time"]["snow volume, 200 um"] = snow_bias.pareto_rows(doc["snow"])
        from . import media_accuracy, snow_optics
        doc["snow_optics"] = snow_optics.run(quick=quick, smoke=smoke)
        doc["media"] = media_accuracy.run(quick=quick, smoke=smoke)
        doc["accuracy_vs_time"].update(doc["media"])
        from . import cloud_cost
        doc["cloud"] = cloud_cost.run(quick=quick)
        from . import sky_table
        doc["sky"] = sky_table.bench(quick=quick)
        doc["canopy"] = bench_canopy(quick=quick)
        from . import forest_cost             # a forest in a DEM granule against a bare one
        doc["forest"] = forest_cost.run(quick=quick)
    charts = {"throughput.png": lambda p: _chart(doc, p)}
    if not throughput_only:
        charts.update({
            "stability.png": lambda p: breaking_points.chart(doc["stability"], p),
            "accuracy_vs_time.png": lambda p: accuracy.chart(doc["accuracy_vs_time"], p)})
        if "rows" in doc["peer"]:             # mitransient installed: the comparison ran
            charts["peer.png"] = lambda p: peer.chart(doc["peer"], p)
        charts.update({
            "track_length.png": lambda p: track_length.chart(doc["track_length"], p),
            "snow.png": lambda p: snow_bias.chart(doc["snow"], p)})
        from . import canopy_representations
        charts["canopy.png"] = lambda p: canopy_representations.chart(doc["canopy"], p)
    for name, draw in charts.items():
        draw(out / name)
    doc["charts"] = list(charts)         # the files written, for the caller to name
    (out / "bench.json").write_text(json.dumps(doc, indent=1, default=float))
    return doc


def _format_rates(d: dict) -> list[str]:
    i, two = d["integrator"], d["integrator"]["two_bounces"]
    lines = [f"integrator: {i['paths_per_s'] / 1e6:.1f} M paths/s vs ray_intersect "
             f"{i['rays_per_s'] / 1e6:.1f} M rays/s on {i['triangles'] / 1e6:.2f} M triangles: "
             f"ratio {i['ratio_to_ceiling']:.2f}; host share of a trace {i['host_share']:.0%} "
             f"(launch {i['launch_s']:.3f} s, wait {i['wait_s']:.3f} s, "
             f"fetch {i['fetch_s']:.3f} s)",
             f"integrator, 2 bounces: {two['paths_per_s'] / 1e6:.1f} M paths/s, ratio "
             f"{two['ratio_to_ceiling']:.2f}, host share {two['host_share']:.0%}"]
    for r in d["end_to_end"]:
        lines.append(f"end to end, {r['beam']} beam, max_depth {r['max_depth']} "
                     f"({r['traced_depth']} traced), paths_per_shot {r.get('paths', 'auto')} "
                     f"({r['paths_per_shot']}): {r['shots_per_s']:.0f} shots/s "
                     f"({r['shots']} shots in {r['seconds']:.2f} s); chunk loop "
                     f"{r['loop_shots_per_s']:.0f} shots/s, "
                     f"{r['loop_of_cast_bound']:.2f} of its ray casts' bound "
                     f"({r['cast_bound_shots_per_s']:.0f})")
    for r in d.get("paths_speedup", []):
        lines.append(f"paths_per_shot auto ({r['auto_paths_per_shot']}) vs "
                     f"{r['fixed_paths_per_shot']}, {r['beam']} beam, max_depth "
                     f"{r['max_depth']}: {r['whole_call']:.2f}x whole call, {r['loop']:.2f}x "
                     f"chunk loop; bias {100 * r['d_bias_m']:+.2f} +- "
                     f"{100 * r['d_bias_se_m']:.2f} cm, std {100 * r['d_std_m']:+.2f} +- "
                     f"{100 * r['d_std_se_m']:.2f} cm")
    return lines


def _value(v) -> str:
    return f"{v:g}" if isinstance(v, (int, float)) else str(v)


def format_summary(doc: dict) -> str:
    lines = [f"{'detector case':<30}{'M events/s':>11}{'(best)':>8}{'events':>10}"
             f"{'M returns/s':>12}{'median s':>10}"]
    for r in doc["detector"]:
        lines.append(f"{r['case']:<30}{r['events_per_s'] / 1e6:>11.1f}"
                     f"{r['best_events_per_s'] / 1e6:>8.1f}{r['events']:>10.3g}"
                     f"{r['returns_per_s'] / 1e6:>12.1f}{r['seconds']:>10.3f}")
    lines.append("(few photons per shot: the stage is bound by the traced returns it reads, "
                 "not by events)")
    for variant, d in (doc.get("by_variant") or {doc["variant"]: doc}).items():
        lines.append(f"-- {variant} on {d['device']}")
        lines += _format_rates(d)
    for name, d in doc.get("accuracy_vs_time", {}).items():
        front = ", ".join(f"{r['knob']}={_value(r['value'])}: {100 * r['error_m']:.2f} cm in "
                          f"{r['seconds']:.2f} s" for r in accuracy.pareto_front(d["rows"]))
        lines.append(f"accuracy vs time, {name} (Pareto front): {front}")
    if "simplifications" in doc:
        lines.append(accuracy.format_simplifications(doc["simplifications"]))
    if "peer" in doc:
        lines.append(peer.format_summary(doc["peer"]))
    for r in doc.get("track_length", []):
        if "beams" in r:
            lines.append(f"DEM granule, {r['beams']} beams x {r['length_km']:g} km: "
                         f"{r['seconds']:.2f} s in a warm worker, {r['of_cast']:.1f}x its "
                         f"{r['rays'] / 1e6:.1f} M rays cast alone ({r['cast_s']:.2f} s at "
                         f"{r['cast_rays_per_s'] / 1e6:.0f} M rays/s into {r['cast_tiles']} of "
                         f"its tiles, {100 * r['cast_cv']:.0f} % cv); end to end (a cold "
                         f"process) {r['end_to_end_s']:.2f} s, "
                         f"{r['end_to_end_over_warm']:.2f}x warm "
                         f"({r['end_to_end_over_warm_cpu']:.2f}x in CPU); peak RSS "
                         f"{r['peak_rss_first_mb']:.0f} MB after one granule, "
                         f"{r['peak_rss_mb']:.0f} MB after two")
            continue
        kernels = f", {r['kernels']} kernels" if r.get("kernels") is not None else ""
        lines.append(f"DEM track {r['length_km']:g} km ({r['shots']} shots, {r['sections']} "
                     f"sections, {r['tiles']} tiles{kernels}): {r['shots_per_s']:.0f} shots/s, "
                     f"peak RSS {r['peak_rss_mb']:.0f} MB (before the run "
                     f"{r['rss_before_mb']:.0f}), "
                     f"files {r['files_mb']:.0f} MB")
    if "cloud" in doc:
        c = doc["cloud"]
        lines.append(f"cloud in a DEM granule ({c['beams']} beams x {c['length_km']:g} km, "
                     f"tau {c['cloud']['optical_depth']:g} at {c['cloud']['base_m']:g}-"
                     f"{c['cloud']['top_m']:g} m): {c['cloud_s']:.2f} s against "
                     f"{c['clear_s']:.2f} s clear ({c['cloud_over_clear']:.2f}x), "
                     f"{c['cloud_of_cast']:.0f}x its rays cast alone (clear "
                     f"{c['clear_of_cast']:.0f}x); the cloud's table once: {c['table_s']:.1f} s")
    if "snow" in doc:
        from . import snow_bias
        lines += snow_bias.format_summary(doc["snow"])
    if "snow_optics" in doc:
        from . import snow_optics
        lines.append("snow optics: ATLAS h_li bias over interior snow (polar night)")
        lines += snow_optics.format_table(doc["snow_optics"])
    if "media" in doc:
        from . import media_accuracy
        lines += media_accuracy.format_summary(doc["media"])
    if "sky" in doc:
        from . import sky_table
        lines.append(sky_table.format_bench(doc["sky"]))
    if "canopy" in doc:
        from . import canopy_representations
        lines += canopy_representations.format_rows(doc["canopy"])
    if "forest" in doc:
        from . import forest_cost
        lines += forest_cost.format_rows(doc["forest"])
    for name, rows in doc.get("stability", {}).items():
        bad = [f"{r['value']:g}: {r['status']}" for r in rows
               if not str(r.get("status", "ok")).startswith("ok")]
        lines.append(f"stability {name}: {len(rows) - len(bad)} ok"
                     + (f"; {'; '.join(bad)}" if bad else ""))
    return "\n".join(lines)
