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
import time

import drjit as dr
import mitsuba as mi
import numpy as np

from .. import pmt, scene as scn, terrain
from ..constants import C_M_PER_NS
from ..instrument import Instrument
from ..photons import Returns
from ..simulate import simulate
from ..surface import SurfaceSpec, heightfield_to_trimesh
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


def bench_detector(*, quick: bool) -> list[dict]:
    """Detector stage throughput [photon events/s] on synthetic returns (no rendering).

    Events counted: the signal photons reaching the detector (Poisson arrivals, before fill
    factor and PDE, each drawn and thinned) plus the noise events generated (background after
    thinning, dark counts) — every photon the stage handles.
    """
    rng = np.random.default_rng(1)
    n_shots = 20_000 if quick else 200_000
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
    ]
    rows = []
    for name, k, inst in cases:
        ret = returns[k]
        out = {}

        def run():
            out["det"] = pmt.detect(ret, inst, np.random.default_rng(2), gate_center_ns=gate)

        times = _times(run, repeats=3 if quick else 7)
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


def bench_integrator(*, quick: bool) -> dict:
    """Photon paths/s of the path-length integrator against raw ``scene.ray_intersect`` on the
    same rays and mesh: the 1024 m fractal tile at 1 m (about 2 million triangles)."""
    size = 256.0 if quick else 1024.0
    hf = terrain.fractal(p=1.8, size_m=size, grid_m=1.0, relief_m=10.0, seed=0)
    t = time.perf_counter()
    tm = heightfield_to_trimesh(hf, margin_m=13.5)
    scene = scn.scene_from_mesh(tm.vertices, tm.faces)
    build_s = time.perf_counter() - t
    integ = mi.load_dict(Instrument().integrator_dict())
    n_shots, k = (2000, 128) if quick else (20000, 256)
    xs = (np.arange(n_shots) * 0.7) % (size - 30) + 15
    ys = np.full(n_shots, size / 2)

    def trace():
        integ.trace(scene, shot_x_m=xs, shot_y_m=ys, paths_per_shot=k, seed=1)

    rng = np.random.default_rng(3)
    n = n_shots * k
    ox = (np.repeat(xs, k) + 2.5 * rng.standard_normal(n)).astype(np.float32)
    oy = (np.repeat(ys, k) + 2.5 * rng.standard_normal(n)).astype(np.float32)
    top = float(tm.vertices[:, 2].max()) + 1.0
    rays = mi.Ray3f(mi.Point3f(mi.Float(ox), mi.Float(oy), top), mi.Vector3f(0, 0, -1))

    def cast():
        si = scene.ray_intersect(rays)
        z = si.p.z.numpy()            # the same device -> host copy the integrator makes
        return z

    reps = 3 if quick else 5
    trace_s = _median_time(trace, repeats=reps)
    cast_s = _median_time(cast, repeats=reps)
    return {"triangles": int(len(tm.faces)), "mesh_build_s": build_s, "paths": n,
            "trace_s": trace_s, "raycast_s": cast_s, "paths_per_s": n / trace_s,
            "rays_per_s": n / cast_s, "ratio_to_ceiling": cast_s / trace_s}


def bench_end_to_end(*, quick: bool) -> list[dict]:
    """Shots/s of ``simulate`` (scene build included) over the p = 1.8 fractal, both beams."""
    rows = []
    shots = 2000 if quick else 20000
    for beam in ("strong", "weak"):
        out = {}

        def run():
            out["res"] = simulate(instrument=Instrument(beam=beam), shots=shots, seed=1,
                                  surface=SurfaceSpec(kind="fractal", p=1.8), progress=False)

        sec = _median_time(run, repeats=1 if quick else 3)
        rows.append({"beam": beam, "shots": shots, "seconds": sec, "shots_per_s": shots / sec,
                     "stage_seconds": out["res"].timings_s})
    return rows


def _chart(doc: dict, path: pathlib.Path):
    """Throughput bars (detector cases; integrator against its ray-cast ceiling), saved to
    ``path``. Returns the (closed) matplotlib Figure."""
    from ..plotting import plt
    det = doc["detector"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), dpi=110)
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
    ax.barh(labels, vals, color=["0.6", "tab:orange"])
    ax.set_xlabel(f"million paths / s, {integ['triangles'] / 1e6:.1f} M triangles "
                  f"(ratio {integ['ratio_to_ceiling']:.2f})")
    ax.invert_yaxis()
    fig.suptitle(f"lidar_mitsuba throughput on {os.cpu_count()} CPU cores ({mi.variant()})")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return fig


def run(*, out_dir: str | os.PathLike, quick: bool = False) -> dict:
    """Run every benchmark; write ``bench.json`` and ``throughput.png`` into ``out_dir``."""
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    doc = {"quick": quick, "variant": mi.variant(), "cpu_count": os.cpu_count(),
           "machine": platform.platform(), "drjit": dr.__version__, "mitsuba": mi.__version__,
           "detector": bench_detector(quick=quick), "integrator": bench_integrator(quick=quick),
           "end_to_end": bench_end_to_end(quick=quick)}
    doc["stability"] = breaking_points.run_all(quick=quick)
    doc["accuracy_vs_time"] = accuracy.run(quick=quick)
    doc["simplifications"] = accuracy.simplifications(quick=quick)
    doc["peer"] = peer.run(quick=quick)
    (out / "bench.json").write_text(json.dumps(doc, indent=1, default=float))
    _chart(doc, out / "throughput.png")
    breaking_points.chart(doc["stability"], out / "stability.png")
    accuracy.chart(doc["accuracy_vs_time"], out / "accuracy_vs_time.png")
    peer.chart(doc["peer"], out / "peer.png")
    return doc


def format_summary(doc: dict) -> str:
    lines = [f"{'detector case':<30}{'M events/s':>11}{'(best)':>8}{'events':>10}"
             f"{'M returns/s':>12}{'median s':>10}"]
    for r in doc["detector"]:
        lines.append(f"{r['case']:<30}{r['events_per_s'] / 1e6:>11.1f}"
                     f"{r['best_events_per_s'] / 1e6:>8.1f}{r['events']:>10.3g}"
                     f"{r['returns_per_s'] / 1e6:>12.1f}{r['seconds']:>10.3f}")
    lines.append("(few photons per shot: the stage is bound by the traced returns it reads, "
                 "not by events)")
    i = doc["integrator"]
    lines.append(f"integrator: {i['paths_per_s'] / 1e6:.1f} M paths/s vs ray_intersect "
                 f"{i['rays_per_s'] / 1e6:.1f} M rays/s on {i['triangles'] / 1e6:.2f} M triangles: "
                 f"ratio {i['ratio_to_ceiling']:.2f}")
    for r in doc["end_to_end"]:
        lines.append(f"end to end, {r['beam']} beam: {r['shots_per_s']:.0f} shots/s "
                     f"({r['shots']} shots in {r['seconds']:.2f} s)")
    for name, d in doc.get("accuracy_vs_time", {}).items():
        front = ", ".join(f"{r['knob']}={r['value']:g}: {100 * r['error_m']:.2f} cm in "
                          f"{r['seconds']:.2f} s" for r in accuracy.pareto_front(d["rows"]))
        lines.append(f"accuracy vs time, {name} (Pareto front): {front}")
    if "simplifications" in doc:
        lines.append(accuracy.format_simplifications(doc["simplifications"]))
    if "peer" in doc:
        lines.append(peer.format_summary(doc["peer"]))
    for name, rows in doc.get("stability", {}).items():
        bad = [f"{r['value']:g}: {r['status']}" for r in rows
               if not str(r.get("status", "ok")).startswith("ok")]
        lines.append(f"stability {name}: {len(rows) - len(bad)} ok"
                     + (f"; {'; '.join(bad)}" if bad else ""))
    return "\n".join(lines)
