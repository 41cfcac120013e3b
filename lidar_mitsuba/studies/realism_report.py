"""The realism matrix's figure and report (:mod:`lidar_mitsuba.studies.realism`):
``realism_background.png`` (background against solar elevation, -10 to +35 deg: the model's
curves for strong and weak beams with every real beam over them) and ``realism.md``."""
from __future__ import annotations

import pathlib

import numpy as np

ELEVATION_RANGE_DEG = (-10.0, 35.0)


def plot(doc: dict, path) -> None:
    """Background [Hz, log] against solar elevation [deg]: the model's curves (clear snow,
    sea level, the leak as the matrix counts it:
    :func:`~lidar_mitsuba.studies.realism_curve.background_curve`) and each real beam's
    median (filled: clear segments, open: cloudy ones; beams with the sun below -10 deg drawn
    at -10 with a left arrow), our prediction for it as a cross."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    c = doc["curve"]
    colour = {"strong": "tab:red", "weak": "tab:blue"}
    fig, ax = plt.subplots(figsize=(9, 5.5))
    for kind in ("strong", "weak"):
        ax.plot(c["elevation_deg"], c[kind], color=colour[kind], lw=2,
                label=f"model, {kind} beam (clear snow, sea level; leak as the matrix "
                      "counts it, on photons drawn without dead time)")
    lo, hi = ELEVATION_RANGE_DEG
    for r in doc["rows"]:
        m, p = r["measured"], r["predicted"]
        el = p.get("solar_elevation_deg", m["solar_elevation_deg"])   # geometric, as the curve
        if el is None:
            continue
        x = float(np.clip(el, lo, hi))
        col = colour[r["strength"]]
        for key, fill in (("background_clear_hz", col), ("background_cloudy_hz", "none")):
            v = m[key]
            if v is not None and v > 0:
                ax.plot(x, v, "<" if el < lo else "o", ms=7, mfc=fill, mec=col, alpha=0.8)
        ax.plot(x, p["background_hz"], "x", color=col, ms=6, alpha=0.8)
        if p.get("background_cloudy_hz"):                   # with the file's own cloud
            ax.plot(x, p["background_cloudy_hz"], "+", color=col, ms=8, alpha=0.8)
    ax.plot([], [], "o", color="gray", label="real beam, clear segments (median)")
    ax.plot([], [], "o", mfc="none", mec="gray", label="real beam, cloudy segments")
    ax.plot([], [], "x", color="gray", label="our prediction for that beam (clear sky)")
    ax.plot([], [], "+", color="gray", label="our prediction with the cloud its file implies")
    ax.plot([], [], "<", color="gray", label="sun below -10 deg (drawn at -10)")
    ax.set_yscale("log")
    ax.set_xlim(lo - 1, hi + 1)
    ax.set_xlabel("solar elevation [deg]")
    ax.set_ylabel("background rate, detected [Hz]")
    ax.set_title("ATLAS background against solar elevation: model and real files")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="lower right", framealpha=0.9)
    fig.tight_layout()
    fig.savefig(pathlib.Path(path), dpi=110)
    plt.close(fig)


def _k(v) -> str:
    return "-" if v is None else f"{v / 1e3:.3g}"


def _f(v, spec=".2f") -> str:
    return "-" if v is None else format(v, spec)


def _sun(m: dict, p: dict) -> str:
    """The file's solar elevation [deg], or where it has none the model's (geometric, from
    the file's time and place), marked so."""
    if m["solar_elevation_deg"] is not None or p.get("solar_elevation_deg") is None:
        return _f(m["solar_elevation_deg"], ".1f")
    return f"{p['solar_elevation_deg']:.1f} (model)"


def report_md(doc: dict) -> str:
    """``realism.md``: the files and what each lacks, the matrix, the pairs' strong:weak
    ratios, ATL03's shape and saturation."""
    lines = ["# Realism matrix: the model against real ICESat-2 files", "",
             f"`lidar-mitsuba validate --real`: {len(doc['files'])} files, "
             f"{len(doc['rows'])} beams, {doc['seconds']:.0f} s; signal "
             + (f"from {doc['signal_shots']} simulated shots per beam (through dead time)"
                if doc["signal_shots"] else "from the lidar equation (no dead time)") + ".",
             "Nothing is fitted to a file. Background: measured median on clear / cloudy "
             "segments against the model (clear sky; with the cloud the file implies or the "
             "one given, for the cloudy segments); signal: photons per shot.", "",
             "Verdicts: **agrees** (background within 0.5-2x and signal within 0.7-1.4x of "
             "the measured; a beam all cloudy, with the cloud its file implies or the one "
             "given); **disagrees** (outside, for every cloud the file's inputs allow, or for "
             "one they pin down); **cloud uncertain** (a beam all cloudy whose file's inputs "
             "disagree on the cloud by more than those ranges can tell apart: its "
             "reflectances' optical depths, or, where ATL09 found several layers, how the "
             "depth splits between the band and above it; the measured value lies inside "
             "what they bracket, and the reason names the datasets, their depths and the "
             "bracket); **cloud missing** (all cloudy, no reflectance and no cloud given); "
             "**surface missing**, **not simulated**, **not measured**.", "",
             "## Files", ""]
    lines += [f"- {f['missing']}" + (f" (release {f['release']})" if f['release'] else "")
              for f in doc["files"]]
    lines += ["", "## Beams", "",
              "| file | beam | sun [deg] | clear | background clear / cloudy [kHz] | "
              "predicted [kHz] (dark, sun, air, leak) | with the cloud [kHz] (cloud) | ratio | "
              "signal measured | predicted | ratio | energy [uJ] | surface | verdict | reason |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        m, p = r["measured"], r["predicted"]
        t = p["background_terms_hz"]
        parts = ", ".join(_k(t[x]) for x in ("dark", "solar", "air", "leak"))
        cl = p.get("background_cloudy_terms_hz")
        cloudy = "-" if cl is None else (f"{_k(cl['total'])} (tau "
                                         f"{r['cloud']['optical_depth']:g}, "
                                         f"{r['cloud']['base_m']:g}-{r['cloud']['top_m']:g} m: "
                                         f"{_k(cl['cloud'])})")
        ratio = r["background_ratio"] if r["background_ratio"] is not None else \
            r.get("background_cloudy_ratio")
        lines.append(
            f"| {r['file']} | {r['beam']} ({r['strength']}) | {_sun(m, p)} "
            f"| {m['clear_fraction']:.2f}{'' if m['cloud_flags'] else ' (no flag)'} | "
            f"{_k(m['background_clear_hz'])} / {_k(m['background_cloudy_hz'])} | "
            f"{_k(p['background_hz'])} ({parts}) | {cloudy} | {_f(ratio)} | "
            f"{_f(m.get('signal_forest', m['signal_clear']))} | {_f(p['signal_per_shot'])} | "
            f"{_f(r['signal_ratio'])} | "
            f"{p['pulse_energy_uj']:.1f} ({'file' if p['energy_source'] == 'tx_pulse_energy' else 'history'}) "
            f"| {p['surface']} | **{r['verdict']}** | {r['reason']} |")
    lines += ["", "## Strong:weak", "", "| file | pair | sun [deg] | background measured, "
              "clear / cloudy | predicted, clear / with the cloud | signal measured | predicted |",
              "|---|---|---|---|---|---|---|"]
    for q in doc["pairs"]:
        lines.append(f"| {q['file']} | {q['pair']} | {_f(q['solar_elevation_deg'], '.1f')} | "
                     f"{_f(q['background_measured'])} / {_f(q['background_cloudy_measured'])} | "
                     f"{_f(q['background_predicted'])} / "
                     f"{_f(q.get('background_cloudy_predicted'))} | "
                     f"{_f(q['signal_measured'])} | {_f(q['signal_predicted'])} |")
    shape = [r for r in doc["rows"] if "spread_robust_m" in r["measured"]]
    if shape:
        lines += ["", "## ATL03: spread, tails, saturation", "",
                  "Spread: robust sd of the surface photons about each 20 m segment's median; "
                  f"tails: the fractions beyond -/+{100 * 0.2:.0f} cm, +- their binomial "
                  "standard errors; verdict by issue 41's rule (spread within 30 %, each tail "
                  "within a factor 2) on the predicted surface named.", "",
                  "| file | beam | spread measured / predicted [cm] | tails below / above, "
                  "measured | predicted | surface | shape verdict | full / near saturated, "
                  "measured | predicted |", "|---|---|---|---|---|---|---|---|---|"]
        for r in shape:
            lines.append(_shape_line(r))
    n = {}
    for r in doc["rows"]:
        n[r["verdict"]] = n.get(r["verdict"], 0) + 1
    lines += ["", ", ".join(f"{v} {k}" for k, v in sorted(n.items())) + ".", "",
              "![background against solar elevation](realism_background.png)", ""]
    return "\n".join(lines)


def _tails(d: dict) -> str:
    if d.get("tail_below") is None:
        return "-"
    return " / ".join(f"{d[f'tail_{k}']:.3f}" + (f" +- {d[f'tail_{k}_se']:.3f}"
                                                   if f"tail_{k}_se" in d else "")
                      for k in ("below", "above"))


def _shape_line(r: dict) -> str:
    """One ATL03 row of the shape table: measured and predicted spread and tails, the
    surface they were predicted over, issue 41's verdict with its ratios."""
    m, p = r["measured"], r["predicted"]
    sv = r.get("shape")
    verdict = "-" if sv is None else f"**{sv['verdict']}**: {sv['reason']}"
    return (f"| {r['file']} | {r['beam']} | {_f(100 * m['spread_robust_m'], '.1f')} / "
            f"{_f(100 * p['spread_robust_m'], '.1f') if 'spread_robust_m' in p else '-'} | "
            f"{_tails(m)} | {_tails(p)} | {p['surface']} ({p.get('shots', 0)} shots) | "
            f"{verdict} | {_f(m['full_sat_fract'], '.3f')} / {_f(m['near_sat_fract'], '.3f')} | "
            f"{_f(p.get('full_sat_fract'), '.3f')} / {_f(p.get('near_sat_fract'), '.3f')} |")
