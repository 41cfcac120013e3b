"""Accuracy against time: every knob that trades one for the other, and the Pareto front.

For three tracks — a flat plate and a 5 degree plane (closed forms: ideal detector, unbiased,
spread sqrt((c sigma_t/2)^2 + (sigma_fp tan theta)^2)) and the p = 1.8 fractal (a high-sample
reference run) — each knob is varied alone from the default run: shots, paths traced per shot,
mesh spacing (one terrain, decimated), max_depth and the chunk size. The error of a setting is
the RMS over three seeds of ``sqrt(d_bias^2 + d_std^2)`` against the reference; its time is
the median wall time of ``simulate``. A user reads off the cheapest setting that reaches a given
accuracy; the Pareto front joins the settings no other setting beats on both.

The default run's ``max_depth`` is ``"auto"`` (1 on the plates; 2 on this fractal, where a
pilot shows that single bounce would move the answer). The reference of the fractal traces
three bounces, so the ``max_depth`` points measure what each depth leaves out: single bounce
misses multiple scattering between terrain facets (on p = 1.8 snow ~0.1 % of the return weight,
delayed by metres), which the standard deviation feels strongly.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..instrument import Instrument
from ..run import simulate
from ..ground.surface import SurfaceSpec
from ..ground.terrain import Heightfield, fractal

DEFAULT = {"shots": 8000, "paths_per_shot": 128, "grid_m": 1.0, "max_depth": "auto",
           "chunk_shots": 65536}
KNOBS = {"shots": (1000, 2000, 4000, 8000, 16000, 32000),
         "paths_per_shot": (8, 16, 32, 64, 128, 256),
         "grid_m": (0.5, 1.0, 2.0, 4.0, 8.0),
         "max_depth": (1, 2, 3),
         "chunk_shots": (1000, 4000, 65536)}
QUICK_KNOBS = {"shots": (250, 1000, 4000), "paths_per_shot": (16, 128),
               "grid_m": (1.0, 4.0), "max_depth": (1, 2), "chunk_shots": (500, 65536)}


def _tracks(quick: bool) -> dict:
    fine = fractal(p=1.8, size_m=256.0 if quick else 512.0, grid_m=0.5, relief_m=10.0, seed=0)
    return {
        "flat": {"kind": "plane", "slope_deg": 0.0},
        "slope 5 deg": {"kind": "plane", "slope_deg": 5.0},
        "fractal p=1.8": {"kind": "fractal", "fine": fine},
    }


def _surface(track: dict, grid_m: float):
    if track["kind"] == "plane":
        return SurfaceSpec(kind="slope" if track["slope_deg"] else "flat",
                           slope_deg=track["slope_deg"])
    k = max(1, int(round(grid_m / track["fine"].grid_m)))
    z = np.ascontiguousarray(track["fine"].z_m[::k, ::k])
    return Heightfield(z_m=z, grid_m=track["fine"].grid_m * k)


SEEDS = (1, 2, 3)


def _run(track: dict, *, shots, paths_per_shot, grid_m, max_depth, chunk_shots, seed, ideal):
    surface = _surface(track, grid_m)
    t0 = time.perf_counter()
    res = simulate(instrument=Instrument(beam="strong", ideal_detector=ideal),
                   surface=surface, shots=int(shots),
                   paths_per_shot=int(paths_per_shot), max_depth=max_depth,
                   chunk_shots=int(chunk_shots), seed=seed, progress=False, keep_returns=False)
    sec = time.perf_counter() - t0
    st = res.report().overall
    return st.bias_m, st.std_m, sec


def _setting(track, ref, *, ideal, smoke: bool = False, **cfg) -> dict:
    """Median time and RMS error over ``SEEDS`` (the Monte Carlo noise of one seed would
    hide the trends), after a warm-up run (kernel compilation is not part of the cost).
    ``smoke``: the first seed alone, no warm-up (every row and field, numbers meaningless)."""
    if not smoke:
        _run(track, seed=0, ideal=ideal, **cfg)
    runs = [_run(track, seed=s, ideal=ideal, **cfg) for s in (SEEDS[:1] if smoke else SEEDS)]
    errs = [math.hypot(b - ref["bias_m"], sd - ref["std_m"]) for b, sd, _ in runs]
    return {"seconds": float(np.median([r[2] for r in runs])),
            "bias_m": float(np.mean([r[0] for r in runs])),
            "std_m": float(np.mean([r[1] for r in runs])),
            "error_m": float(np.sqrt(np.mean(np.square(errs))))}


def run(*, quick: bool = False, smoke: bool = False) -> dict:
    """All tracks x knobs. Returns ``{track: {"reference": {...}, "rows": [...]}}``; each row:
    knob, value, seconds, bias_m, std_m, error_m (against the reference). ``smoke`` (the
    tests' size; implies ``quick``): each setting run once (:func:`_setting`) and the
    fractal's reference on 2000 shots (quick: 8000)."""
    quick = quick or smoke
    knobs = QUICK_KNOBS if quick else KNOBS
    default = dict(DEFAULT, shots=1000 if quick else DEFAULT["shots"])
    out = {}
    for name, track in _tracks(quick).items():
        ideal = track["kind"] == "plane"        # closed forms hold for the ideal detector
        if ideal:
            inst = Instrument(beam="strong")
            ref = {"bias_m": 0.0, "std_m": math.hypot(
                inst.ranging_sigma_m,
                inst.footprint_sigma_m * math.tan(math.radians(track["slope_deg"]))),
                "source": "closed form"}
        else:
            r_shots = 2000 if smoke else 8000 if quick else 40000
            b, s, sec = _run(track, shots=r_shots, paths_per_shot=256, grid_m=0.5, max_depth=3,
                             chunk_shots=65536, seed=999, ideal=False)
            ref = {"bias_m": b, "std_m": s, "seconds": sec,
                   "source": f"{r_shots} shots, 256 paths/shot, 0.5 m mesh, max_depth 3"}
        rows = []
        for knob, values in knobs.items():
            if track["kind"] == "plane" and knob == "grid_m":
                continue                        # a plane has no mesh spacing
            for v in values:
                cfg = dict(default, **{knob: v})
                rows.append({"knob": knob, "value": v,
                             **_setting(track, ref, ideal=ideal, smoke=smoke, **cfg)})
        out[name] = {"reference": ref, "rows": rows}
    return out


def pareto_front(rows: list[dict]) -> list[dict]:
    """Rows no other row beats on both time and error, by increasing time."""
    best = []
    for r in sorted(rows, key=lambda r: (r["seconds"], r["error_m"])):
        if not best or r["error_m"] < best[-1]["error_m"]:
            best.append(r)
    return best


def chart(results: dict, path):
    """Error against wall time per track, one marker per knob, the Pareto front drawn; saved
    to ``path``. Returns the (closed) matplotlib Figure."""
    from ..plotting import plt
    markers = {"shots": "o", "paths_per_shot": "s", "grid_m": "^", "max_depth": "D",
               "chunk_shots": "x", "snow_max_events": "v", "snow_similarity_g": "P",
               "snow_model": "*"}
    fig, axes = plt.subplots(1, len(results), figsize=(5.2 * len(results), 4.4), dpi=110)
    for ax, (name, doc) in zip(np.atleast_1d(axes), results.items()):
        rows = doc["rows"]
        for knob, m in markers.items():
            sel = [r for r in rows if r["knob"] == knob]
            if sel:
                ax.plot([r["seconds"] for r in sel], [100 * max(r["error_m"], 1e-5) for r in sel],
                        m, label=knob, alpha=0.8)
                for r in sel:
                    v = r["value"]
                    ax.annotate(f"{v:g}" if isinstance(v, (int, float)) else str(v),
                                (r["seconds"], 100 * max(r["error_m"], 1e-5)),
                                fontsize=6, xytext=(3, 2), textcoords="offset points")
        front = pareto_front(rows)
        ax.plot([r["seconds"] for r in front], [100 * max(r["error_m"], 1e-5) for r in front],
                "k-", lw=1, label="Pareto front")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time of the run [s]")
        ax.set_ylabel("error of (bias, precision) [cm]")
        ax.set_title(f"{name}\nreference: {doc['reference']['source']}", fontsize=9)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.suptitle("accuracy against time: each knob varied from the default run "
                 "(labels: the knob's value)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return fig


# --------------------------------------------------------------------------- simplifications
SIMPLIFICATIONS = {   # name: (the simplified run, the fuller run), as changes to the default run
    "corridor crop (vs the full tile)": ({}, {"crop_to_track": False}),
    "1 m mesh (vs 0.5 m)": ({}, {"grid_m": 0.5}),
    "auto bounces (vs max_depth 3)": ({}, {"max_depth": 3}),
    "single bounce, the paper's model (vs auto)": ({"max_depth": 1}, {}),
}


def simplifications(*, quick: bool = False, smoke: bool = False) -> dict:
    """Each simplification the simulator makes by default, against the full model, on the
    default run (the paper's: p = 1.8 fractal, weak beam, 1000 shots, real detector);
    and single bounce, which ``max_depth="auto"`` turns down on this terrain.

    Paired design: for each seed both runs see the same random numbers, so the mean paired
    difference (with its standard error over seeds) is the error the simplification adds,
    and the spread of the default run over seeds is its Monte Carlo error. Verdict "below"
    when ``|mean difference|`` + 2 SE is under the Monte Carlo error of bias and of precision,
    "above" when ``|mean difference|`` - 2 SE exceeds it, else "comparable". ``smoke`` (the
    tests' size; implies ``quick``): two seeds, the fewest a spread needs, and no warm-up.
    """
    # 48 seeds: the tail of twice-scattered photons makes the precision of one run noisy
    quick = quick or smoke
    seeds = range(1, 3 if smoke else 5 if quick else 49)
    shots = 500 if quick else 1000
    spec = SurfaceSpec()                            # the default surface, on a 0.5 m grid
    fine = fractal(p=spec.p, size_m=spec.size_m, grid_m=0.5, relief_m=spec.relief_m, seed=0)
    track = {"kind": "fractal", "fine": fine}
    runs = {}

    def one(seed, grid_m=1.0, max_depth="auto", crop_to_track=True):
        key = (seed, grid_m, max_depth, crop_to_track)
        if key not in runs:
            res = simulate(instrument=Instrument(beam="weak"), surface=_surface(track, grid_m),
                           shots=shots, seed=seed, max_depth=max_depth,
                           crop_to_track=crop_to_track, progress=False, keep_returns=False)
            st = res.report().overall
            runs[key] = (st.bias_m, st.std_m, res.config["max_depth"])
        return runs[key]

    if not smoke:
        one(0)                                      # warm-up (compilation)
    base = np.array([one(s)[:2] for s in seeds])    # (seeds, 2): bias, std [m]
    chosen = sorted({one(s)[2] for s in seeds})
    mc = base.std(axis=0, ddof=1)
    rows = []
    for name, (simple_cfg, full_cfg) in SIMPLIFICATIONS.items():
        d = np.array([np.subtract(one(s, **full_cfg)[:2], one(s, **simple_cfg)[:2])
                      for s in seeds])
        mean, se = d.mean(axis=0), d.std(axis=0, ddof=1) / math.sqrt(len(seeds))
        verdict = []
        for k in range(2):
            if abs(mean[k]) + 2 * se[k] < mc[k]:
                verdict.append("below")
            elif abs(mean[k]) - 2 * se[k] > mc[k]:
                verdict.append("above")
            else:
                verdict.append("comparable")
        rows.append({"simplification": name, "simplified": simple_cfg, "full_model": full_cfg,
                     "d_bias_m": float(mean[0]), "d_bias_se_m": float(se[0]),
                     "d_std_m": float(mean[1]), "d_std_se_m": float(se[1]),
                     "verdict_bias": verdict[0], "verdict_std": verdict[1]})
    return {"run": f"fractal p=1.8, 10 m relief on 1024 m (0.5 m terrain, decimated), weak "
                   f"beam, {shots} shots, "
                   f"{len(seeds)} seeds",
            "mc_bias_m": float(mc[0]), "mc_std_m": float(mc[1]), "auto_max_depth": chosen,
            "bias_m": float(base[:, 0].mean()), "std_m": float(base[:, 1].mean()), "rows": rows}


def format_simplifications(doc: dict) -> str:
    lines = [f"simplifications of the default run ({doc['run']}): Monte Carlo error of one run "
             f"{100 * doc['mc_bias_m']:.2f} cm (bias), {100 * doc['mc_std_m']:.2f} cm (precision); "
             f"auto chose max_depth {', '.join(map(str, doc['auto_max_depth']))}"]
    for r in doc["rows"]:
        lines.append(f"  {r['simplification']:<44} bias {100 * r['d_bias_m']:+.3f} "
                     f"+- {100 * r['d_bias_se_m']:.3f} cm ({r['verdict_bias']}), precision "
                     f"{100 * r['d_std_m']:+.3f} +- {100 * r['d_std_se_m']:.3f} cm "
                     f"({r['verdict_std']})")
    return "\n".join(lines)
