"""Snow as a volume: the elevation bias it causes and what it costs (``bench``; notebook
``02-snow-volume``).

Three measurements on a flat snowpack (semi-infinite, density as given), each run through
the whole chain (detector with dead time, ATL06 segments with first-photon-bias correction):

* ``bias``: per grain radius, density and beam, with the kernel, the mean elevation error of
  the raw signal photons, of ATL06's uncorrected ``h_mean`` and of ``h_li`` (fpb-corrected),
  against the surface, with Monte Carlo standard errors;
* ``walk`` and ``cost``: the full walk at each grain size (the reference) and the shots per
  second of the walk, the kernel (:mod:`lidar_mitsuba.ground.snow.kernel`) and the surface alone
  (Ward snow BRDF), each with its own automatic paths per shot; ``kernel_vs_surface``: the
  kernel's time against the bare surface, paired runs, median ratio;
* ``events``: the accuracy-versus-time trade-off of the interactions traced per photon
  (``max_events``): bias and time per setting at one grain size;
* ``similarity``: the same snow traced with a smaller asymmetry g and the same reduced
  scattering (:meth:`~lidar_mitsuba.ground.snow.SnowVolume.similar`): its speed and its error.
"""
from __future__ import annotations

import time

import numpy as np

from ..products import atl06
from ..ground import snow
from ..ground.snow import kernel as snow_kernel
from ..instrument import Instrument
from ..run import simulate
from ..ground.surface import SurfaceSpec


def _one(*, beam: str, grain_um: float | None, density: float, shots: int, seed: int,
         max_events: int | None = None, paths_per_shot: int | str = 64,
         similarity_g: float | None = None, model: str = "walk") -> dict:
    vol = (None if grain_um is None else
           snow.snow_from_grains(grain_radius_um=grain_um, density_kg_m3=density,
                                 max_events=max_events))
    if similarity_g is not None:
        vol = vol.similar(similarity_g)
    t0 = time.perf_counter()
    res = simulate(instrument=Instrument(beam=beam), surface=SurfaceSpec(kind="flat"),
                   snow=vol, shots=shots, seed=seed, paths_per_shot=paths_per_shot,
                   progress=False, **({} if vol is None else {"snow_model": model}))
    seconds = time.perf_counter() - t0
    rep = res.report().overall
    seg = atl06.segments_from_result(res)
    good = seg.atl06_quality_summary == 0
    def stat(x):
        # segments are 40 m long every 20 m: neighbours share half their photons, so the
        # mean's standard error counts the independent (every other) segments
        x = x[good & np.isfinite(x)]
        return (float(np.mean(x)), float(np.std(x) / np.sqrt(max(x.size / 2, 1)))) if x.size else (
            float("nan"), float("nan"))
    h_li, h_li_se = stat(seg.h_li - seg.h_ref_m)
    h_mean, h_mean_se = stat(seg.h_mean - seg.h_ref_m)
    return {"beam": beam, "grain_um": grain_um, "density": density, "shots": shots,
            "model": None if vol is None else model,
            "max_events": None if vol is None else vol.events_cap,
            "similarity_g": similarity_g, "seconds": seconds,
            "paths_per_shot": int(res.config["paths_per_shot"]),
            "table_s": float(res.timings_s.get("kernel_table_s", 0.0)),
            "signal_per_shot": float(np.mean(res.detections.mean_photons_per_shot)),
            "raw_bias_m": rep.bias_m, "raw_bias_se_m": rep.bias_se_m,
            "precision_m": rep.std_m, "h_mean_bias_m": h_mean, "h_mean_bias_se_m": h_mean_se,
            "h_li_bias_m": h_li, "h_li_bias_se_m": h_li_se, "segments": int(good.sum())}


def _kernel_vs_surface(*, grain_um: float, density: float, shots: int, reps: int) -> dict:
    """The kernel's end-to-end time against the same plane without snow, same shots, in
    turn ``reps`` times (the table already built): the median of the paired ratios."""
    pairs = []
    for k in range(reps):
        s = _one(beam="strong", grain_um=None, density=0, shots=shots, seed=100 + k,
                 paths_per_shot="auto")
        kr = _one(beam="strong", grain_um=grain_um, density=density, shots=shots,
                  seed=100 + k, paths_per_shot="auto", model="kernel")
        pairs.append((s["seconds"], kr["seconds"]))
    t = np.array(pairs)
    return {"grain_um": grain_um, "shots": shots, "reps": reps,
            "surface_s_median": float(np.median(t[:, 0])),
            "kernel_s_median": float(np.median(t[:, 1])),
            "kernel_over_surface": float(np.median(t[:, 1] / t[:, 0]))}


def run(*, quick: bool = False, smoke: bool = False) -> dict:
    """The snow study: the kernel's biases over grain size, density and beam; the walk at
    each grain size (the reference, strong beam, first density) and what each model costs;
    the kernel's time against the bare surface; the walk's accuracy knobs. Quick: two grain
    sizes, and kernel tables of 2^14 walk photons a node (a smoke run: building the full
    tables was two thirds of its time). ``smoke`` (the tests' size; implies ``quick``): the
    quick run with :data:`SMOKE_WALK_ROW_SHOTS` shots in the walk rows and
    :data:`SMOKE_WALK_SHOTS` in the ``max_events`` and similarity knobs (the walk's runs were
    two thirds of a quick run's time) and tables of :data:`SMOKE_TABLE_PHOTONS` walk photons
    a node; the kernel's bias rows keep the quick run's shots."""
    photons = SMOKE_TABLE_PHOTONS if smoke else 1 << 14 if quick else None
    with snow_kernel.photons_per_node(photons):
        return _run(quick=quick or smoke, smoke=smoke)


#: the walk's shots in a smoke run (quick: 400): 200 shots are 140 m of track, about five
#: 40 m ATL06 segments for the ``max_events`` and similarity rows' h_li
SMOKE_WALK_SHOTS = 200

#: the shots of a smoke run's walk rows (``walk``, ``cost``): they trace the automatic paths
#: per shot, 1024 a shot (the top of the ladder; the knob rows: 64), 11.4 CPU-s at 200 um for
#: 200 shots (session 23, the 2-core VM), two thirds of a smoke run's time. 100 shots, 70 m
#: of track, leave two 40 m ATL06 segments for their h_li: a smoke run's rows show that the
#: walk runs and what it costs a shot, not its bias (the quick run's 400 shots do)
SMOKE_WALK_ROW_SHOTS = 100

#: walk photons a node of a smoke run's kernel tables (quick: 2^14): a table of 2^12 builds in
#: a third of the time (200 um: 2.5 against 8.1 s of CPU, session 21). The photon count is
#: part of a table's key, so a smoke table never stands in for a larger one. Its nadir mean
#: extra path has a standard error of 2.5 cm at 200 um (2^14: 1.3 cm), ~1.2 cm in height:
#: the smoke rows' 200 and 1000 um biases (~9 cm apart) stay far apart
SMOKE_TABLE_PHOTONS = 1 << 12


def _run(*, quick: bool, smoke: bool = False) -> dict:
    grains = (200, 1000) if quick else (50, 100, 200, 500, 1000)   # (quick: no 50 um table)
    densities = (350,) if quick else (250, 400)
    shots = SMOKE_WALK_SHOTS if smoke else 400 if quick else 2000
    kshots = 4000 if quick else 20000
    # the walk first: its rows give the reference and the cost; the kernel's first run at
    # each snowpack builds (or reads) its table, timed apart in "table_s"
    walk = [_one(beam="strong", grain_um=g, density=densities[0], seed=7,
                 shots=SMOKE_WALK_ROW_SHOTS if smoke else shots, paths_per_shot="auto")
            for g in grains]
    bias = [_one(beam=b, grain_um=g, density=rho, shots=kshots, seed=7,
                 paths_per_shot="auto", model="kernel")
            for rho in densities for b in ("strong", "weak") for g in grains]
    surface = _one(beam="strong", grain_um=None, density=0, shots=kshots, seed=7,
                   paths_per_shot="auto")
    cost = [{"grain_um": None, "model": None, "shots_per_s": kshots / surface["seconds"],
             **surface}]
    for w in walk:
        k = next(r for r in bias if r["beam"] == "strong" and r["grain_um"] == w["grain_um"]
                 and r["density"] == densities[0])
        cost.append({**w, "shots_per_s": w["shots"] / w["seconds"]})
        cost.append({**k, "shots_per_s": k["shots"] / (k["seconds"] - k["table_s"])})
    ratio = _kernel_vs_surface(grain_um=200, density=densities[0], shots=kshots,
                               reps=3 if quick else 5)
    # the last, the reference, above the default cap at 200 um (sigma_s x 10 m = 28,600)
    counts = (100, 1000, 10000, 30000) if quick else (300, 1000, 3000, 10000, 30000, 100000)
    events = [_one(beam="strong", grain_um=200, density=350, shots=shots, seed=11,
                   max_events=n) for n in counts]
    similarity = [_one(beam="strong", grain_um=200, density=350, shots=shots, seed=11,
                       similarity_g=gs) for gs in (0.0, 0.5)]
    kernel200 = _one(beam="strong", grain_um=200, density=350, shots=shots, seed=11,
                     model="kernel")
    return {"bias": bias, "walk": walk, "cost": cost, "kernel_vs_surface": ratio,
            "events": events, "similarity": similarity, "kernel_200um": kernel200,
            "surface_only": surface}


def chart(doc: dict, path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.3))
    for (beam, rho), marker in zip(sorted({(r["beam"], r["density"]) for r in doc["bias"]}),
                                   "osd^v<"):
        rows = [r for r in doc["bias"] if r["beam"] == beam and r["density"] == rho]
        g = np.array([r["grain_um"] for r in rows])
        for key, color in (("raw", "C0"), ("h_li", "C2")):
            y = 100 * np.array([r[f"{key}_bias_m"] for r in rows])
            e = 100 * np.array([r[f"{key}_bias_se_m"] for r in rows])
            ax[0].errorbar(g, y, e, marker=marker, color=color, capsize=2,
                           ls="-" if beam == "strong" else "--",
                           label=f"kernel {key}, {beam}, {rho:g} kg/m³")
    w = doc.get("walk", [])
    if w:
        ax[0].errorbar([r["grain_um"] for r in w], [100 * r["h_li_bias_m"] for r in w],
                       [100 * r["h_li_bias_se_m"] for r in w], fmt="k*", ms=9, capsize=2,
                       label=f"walk h_li, strong, {w[0]['density']:g} kg/m³")
    ax[0].set(xscale="log", xlabel="optical grain radius [µm]", ylabel="elevation bias [cm]",
              title="snow: elevation bias (±1 SE)")
    ax[0].axhline(0, color="k", lw=0.5)
    ax[0].legend(fontsize=6, ncol=2)
    c = doc["cost"]
    names = ["surface" if r["grain_um"] is None else f"{r['model']} {r['grain_um']:g} µm"
             for r in c]
    colors = ["C7" if r["grain_um"] is None else "C0" if r["model"] == "walk" else "C2"
              for r in c]
    ax[1].bar(names, [r["shots_per_s"] for r in c], color=colors)
    kv = doc["kernel_vs_surface"]
    ax[1].set(yscale="log", ylabel="shots/s, end to end",
              title=f"cost: walk (blue), kernel (green), surface (grey);\nkernel / surface "
                    f"time {kv['kernel_over_surface']:.2f} (median of {kv['reps']})")
    ax[1].title.set_fontsize(9)
    ax[1].tick_params(axis="x", rotation=60, labelsize=7)
    pr = pareto_rows(doc)
    for knob, m in (("snow_max_events", "o-"), ("snow_similarity_g", "v"),
                    ("snow_model", "*")):
        rows = [r for r in pr["rows"] if r["knob"] == knob]
        ax[2].plot([r["seconds"] for r in rows], [100 * max(r["error_m"], 1e-3) for r in rows],
                   m, ms=9 if knob == "snow_model" else 6, label=knob)
        for r in rows:
            ax[2].annotate(str(r["value"]), (r["seconds"], 100 * max(r["error_m"], 1e-3)),
                           fontsize=7)
    ax[2].set(xscale="log", yscale="log", xlabel="run time [s]", ylabel="|h_li - reference| [cm]",
              title=f"accuracy vs time; reference:\n{pr['reference']['source']}")
    ax[2].title.set_fontsize(9)
    ax[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def pareto_rows(doc: dict) -> dict:
    """The walk's knobs, the kernel and the bare surface as a panel of the accuracy-versus-time
    (Pareto) chart: the error of ATL06 ``h_li`` against the walk with the most interactions
    per photon (200 um snow, the same shots and seed), and each run's time (the kernel's
    without building its table, which a later run reads from the cache)."""
    ev = doc["events"]
    ref = ev[-1]
    rows = [{"knob": "snow_max_events", "value": r["max_events"], "seconds": r["seconds"],
             "error_m": abs(r["h_li_bias_m"] - ref["h_li_bias_m"])} for r in ev]
    rows += [{"knob": "snow_similarity_g", "value": r["similarity_g"], "seconds": r["seconds"],
              "error_m": abs(r["h_li_bias_m"] - ref["h_li_bias_m"])}
             for r in doc.get("similarity", [])]
    k = doc.get("kernel_200um")
    if k is not None:
        rows.append({"knob": "snow_model", "value": "kernel",
                     "seconds": k["seconds"] - k["table_s"],
                     "error_m": abs(k["h_li_bias_m"] - ref["h_li_bias_m"])})
        s = doc["surface_only"]
        rows.append({"knob": "snow_model", "value": "surface (no snow)",
                     "seconds": s["seconds"] * ref["shots"] / s["shots"],
                     "error_m": abs(s["h_li_bias_m"] - ref["h_li_bias_m"])})
    return {"reference": {"source": f"h_li, walk with max_events {ref['max_events']} "
                                    f"({ref['grain_um']:g} um snow, "
                                    f"SE {100 * ref['h_li_bias_se_m']:.1f} cm)"}, "rows": rows}


def format_summary(doc: dict) -> list[str]:
    s = doc["surface_only"]
    rate = s["shots"] / s["seconds"]
    lines = [f"snow: surface only {rate:.0f} shots/s end to end ({s['shots']} shots)"]
    for r in doc["cost"][1:]:
        extra = (f", its table {r['table_s']:.1f} s once" if r["model"] == "kernel" else "")
        lines.append(f"snow {r['grain_um']:g} um, {r['model']}: {r['shots_per_s']:.0f} shots/s "
                     f"({r['shots_per_s'] / rate:.3f} of surface only, {r['paths_per_shot']} "
                     f"paths/shot{extra}); h_li {100 * r['h_li_bias_m']:+.1f} "
                     f"± {100 * r['h_li_bias_se_m']:.1f} cm, raw {100 * r['raw_bias_m']:+.1f} cm")
    kv = doc["kernel_vs_surface"]
    lines.append(f"snow kernel (200 um) against the surface alone, {kv['shots']} shots: "
                 f"{kv['kernel_over_surface']:.2f}x the time (median of {kv['reps']} paired "
                 f"runs: {kv['kernel_s_median']:.3f} s vs {kv['surface_s_median']:.3f} s)")
    for r in doc["events"]:
        lines.append(f"snow 200 um walk, max_events {r['max_events']}: h_li "
                     f"{100 * r['h_li_bias_m']:+.2f} cm, raw {100 * r['raw_bias_m']:+.2f} cm, "
                     f"run {r['seconds']:.2f} s")
    for r in doc.get("similarity", []):
        lines.append(f"snow 200 um, similar with g {r['similarity_g']:g} (same sigma_s (1-g), "
                     f"{r['max_events']} interactions, 10 m of path): h_li "
                     f"{100 * r['h_li_bias_m']:+.2f} ± {100 * r['h_li_bias_se_m']:.2f} cm, "
                     f"run {r['seconds']:.2f} s")
    k = doc.get("kernel_200um")
    if k is not None:
        lines.append(f"snow 200 um, kernel (same shots): h_li {100 * k['h_li_bias_m']:+.2f} ± "
                     f"{100 * k['h_li_bias_se_m']:.2f} cm, run {k['seconds'] - k['table_s']:.2f}"
                     f" s")
    return lines
