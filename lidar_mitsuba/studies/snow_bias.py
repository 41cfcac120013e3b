"""Snow as a volume: the elevation bias it causes and what it costs (``bench``; notebook
``02-snow-volume``).

Three measurements on a flat snowpack (semi-infinite, density as given), each run through
the whole chain (detector with dead time, ATL06 segments with first-photon-bias correction):

* ``bias``: per grain radius, density and beam, the mean elevation error of the raw signal
  photons, of ATL06's uncorrected ``h_mean`` and of ``h_li`` (fpb-corrected), against the
  surface, with Monte Carlo standard errors;
* ``cost``: traced shots per second with the snow volume against the surface alone (Ward
  snow BRDF), same shots and paths;
* ``events``: the accuracy-versus-time trade-off of the interactions traced per photon
  (``max_events``): bias and time per setting at one grain size;
* ``similarity``: the same snow traced with a smaller asymmetry g and the same reduced
  scattering (:meth:`~lidar_mitsuba.snow.SnowVolume.similar`): its speed and its error.
"""
from __future__ import annotations

import time

import numpy as np

from .. import atl06, snow
from ..instrument import Instrument
from ..simulate import simulate
from ..surface import SurfaceSpec


def _one(*, beam: str, grain_um: float | None, density: float, shots: int, seed: int,
         max_events: int | None = None, paths_per_shot: int = 64,
         similarity_g: float | None = None) -> dict:
    vol = (None if grain_um is None else
           snow.snow_from_grains(grain_radius_um=grain_um, density_kg_m3=density,
                                 max_events=max_events))
    if similarity_g is not None:
        vol = vol.similar(similarity_g)
    t0 = time.perf_counter()
    res = simulate(instrument=Instrument(beam=beam), surface=SurfaceSpec(kind="flat"),
                   snow=vol, shots=shots, seed=seed, paths_per_shot=paths_per_shot,
                   progress=False)
    seconds = time.perf_counter() - t0
    rep = res.report().overall
    seg = atl06.segments_from_result(res)
    good = seg.atl06_quality_summary == 0
    def stat(x):
        x = x[good & np.isfinite(x)]
        return (float(np.mean(x)), float(np.std(x) / np.sqrt(max(x.size, 1)))) if x.size else (
            float("nan"), float("nan"))
    h_li, h_li_se = stat(seg.h_li - seg.h_ref_m)
    h_mean, h_mean_se = stat(seg.h_mean - seg.h_ref_m)
    return {"beam": beam, "grain_um": grain_um, "density": density, "shots": shots,
            "max_events": None if vol is None else vol.events_cap,
            "similarity_g": similarity_g, "seconds": seconds,
            "raw_bias_m": rep.bias_m, "raw_bias_se_m": rep.bias_se_m,
            "precision_m": rep.std_m, "h_mean_bias_m": h_mean, "h_mean_bias_se_m": h_mean_se,
            "h_li_bias_m": h_li, "h_li_bias_se_m": h_li_se, "segments": int(good.sum())}


def run(*, quick: bool = False) -> dict:
    grains = (50, 200, 1000) if quick else (50, 100, 200, 500, 1000)
    densities = (350,) if quick else (250, 400)
    shots = 400 if quick else 2000
    bias = [_one(beam=b, grain_um=g, density=rho, shots=shots, seed=7)
            for rho in densities for b in ("strong", "weak") for g in grains]
    surface = _one(beam="strong", grain_um=None, density=0, shots=shots, seed=7)
    # end to end (simulate's wall time): a volume walk runs partly while its trace is
    # launched (the stages compact on the way), so the trace-wait time alone undercounts it
    cost = [{"grain_um": None, "shots_per_s": shots / surface["seconds"], **surface}]
    cost += [{"shots_per_s": r["shots"] / r["seconds"], **r} for r in bias
             if r["beam"] == "strong" and r["density"] == densities[0]]
    counts = (100, 1000, 10000) if quick else (300, 1000, 3000, 10000, 30000, 100000)
    events = [_one(beam="strong", grain_um=200, density=350, shots=shots, seed=11,
                   max_events=n) for n in counts]
    similarity = [_one(beam="strong", grain_um=200, density=350, shots=shots, seed=11,
                       similarity_g=gs) for gs in (0.0, 0.5)]
    return {"bias": bias, "cost": cost, "events": events, "similarity": similarity,
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
        for key, color in (("raw", "C0"), ("h_mean", "C1"), ("h_li", "C2")):
            y = 100 * np.array([r[f"{key}_bias_m"] for r in rows])
            e = 100 * np.array([r[f"{key}_bias_se_m"] for r in rows])
            ax[0].errorbar(g, y, e, marker=marker, color=color, capsize=2,
                           ls="-" if beam == "strong" else "--",
                           label=f"{key}, {beam}, {rho:g} kg/m³")
    ax[0].set(xscale="log", xlabel="optical grain radius [µm]", ylabel="elevation bias [cm]",
              title="snow volume: elevation bias (±1 SE)")
    ax[0].axhline(0, color="k", lw=0.5)
    ax[0].legend(fontsize=6, ncol=2)
    c = doc["cost"]
    ax[1].bar([("Ward surface" if r["grain_um"] is None else f"{r['grain_um']:g} µm")
               for r in c],
              [r["shots_per_s"] for r in c], color=["C7"] + ["C0"] * (len(c) - 1))
    ax[1].set(yscale="log", ylabel="shots/s, end to end",
              title="cost: snow volume (default cap) vs surface only")
    ax[1].tick_params(axis="x", rotation=30)
    ev = doc["events"]
    ref = ev[-1]
    for r in doc.get("similarity", []):
        e = 100 * abs(r["h_li_bias_m"] - ref["h_li_bias_m"])
        ax[2].plot(r["seconds"], max(e, 1e-3), "v", color="C3")
        ax[2].annotate(f"similar g={r['similarity_g']:g}", (r["seconds"], max(e, 1e-3)),
                       fontsize=7)
    err = [100 * abs(r["h_li_bias_m"] - ref["h_li_bias_m"]) for r in ev[:-1]]
    raw = [100 * abs(r["raw_bias_m"] - ref["raw_bias_m"]) for r in ev[:-1]]
    t = [r["seconds"] for r in ev[:-1]]
    ax[2].plot(t, err, "o-", label="|h_li - h_li(max)|")
    ax[2].plot(t, raw, "s--", label="|raw - raw(max)|")
    for r, x, y in zip(ev[:-1], t, err):
        ax[2].annotate(f"{r['max_events']}", (x, y), fontsize=7)
    ax[2].set(xscale="log", yscale="log", xlabel="run time [s]", ylabel="error [cm]",
              title=f"accuracy vs time: interactions per photon (ref {ref['max_events']})")
    ax[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def pareto_rows(doc: dict) -> dict:
    """The ``events`` rows as a panel of the accuracy-versus-time (Pareto) chart: error of
    ATL06 ``h_li`` against the run with the most interactions per photon, and run time."""
    ev = doc["events"]
    ref = ev[-1]
    rows = [{"knob": "snow_max_events", "value": r["max_events"], "seconds": r["seconds"],
             "error_m": abs(r["h_li_bias_m"] - ref["h_li_bias_m"])} for r in ev]
    rows += [{"knob": "snow_similarity_g", "value": r["similarity_g"], "seconds": r["seconds"],
              "error_m": abs(r["h_li_bias_m"] - ref["h_li_bias_m"])}
             for r in doc.get("similarity", [])]
    return {"reference": {"source": f"h_li with max_events {ref['max_events']} "
                                    f"({ref['grain_um']:g} um snow)"}, "rows": rows}


def format_summary(doc: dict) -> list[str]:
    s = doc["surface_only"]
    lines = [f"snow: surface only {s['shots'] / s['seconds']:.0f} shots/s end to end"]
    for r in doc["cost"][1:]:
        lines.append(f"snow {r['grain_um']:g} um: {r['shots_per_s']:.0f} shots/s "
                     f"({r['shots_per_s'] / (s['shots'] / s['seconds']):.3f} of surface only); "
                     f"raw bias {100 * r['raw_bias_m']:+.1f} cm, h_li {100 * r['h_li_bias_m']:+.1f}"
                     f" ± {100 * r['h_li_bias_se_m']:.1f} cm")
    for r in doc["events"]:
        lines.append(f"snow 200 um, max_events {r['max_events']}: h_li "
                     f"{100 * r['h_li_bias_m']:+.2f} cm, raw {100 * r['raw_bias_m']:+.2f} cm, "
                     f"run {r['seconds']:.2f} s")
    for r in doc.get("similarity", []):
        lines.append(f"snow 200 um, similar with g {r['similarity_g']:g} (same sigma_s (1-g), "
                     f"{r['max_events']} interactions, 10 m of path): h_li "
                     f"{100 * r['h_li_bias_m']:+.2f} ± {100 * r['h_li_bias_se_m']:.2f} cm, "
                     f"run {r['seconds']:.2f} s")
    return lines
