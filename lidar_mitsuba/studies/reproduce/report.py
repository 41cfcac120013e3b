"""The report: every figure's agreement rows, the headline numbers, ``report.md`` and
``report.json``, and :func:`run`, which computes and draws every figure in turn."""
from __future__ import annotations

import json
import os
import pathlib
import platform
import time
from dataclasses import asdict

import numpy as np

from .common import PAPER, PNG, SEEDS, TITLES, _cm, _seq, counts_for
from .terrain_figs import (fig3_spectra, fig4_surfaces, fig5_rms, load_profile, plot_fig3,
                           plot_fig4, plot_fig5, rows_fig3, rows_fig4, rows_fig5)
from .brdf_fig import fig6_brdf, plot_fig6, rows_fig6
from .plates import (fig7_flat, fig8_9_slopes, plot_fig7, plot_fig8, plot_fig9, rows_fig7,
                     rows_fig8, rows_fig9)
from .complex_surfaces import (_beam_summary, fig10_12_complex, plot_fig10, plot_fig11, plot_fig12,
                               rows_fig10, rows_fig11, rows_fig12)
from .albedo import fig13_albedo, plot_fig13, rows_fig13
from ...trace.lazy import mi
from .. import json_safe

ROWS = {"fig3": rows_fig3, "fig4": rows_fig4, "fig5": rows_fig5, "fig6": rows_fig6,
        "fig7": rows_fig7, "fig8": rows_fig8, "fig9": rows_fig9, "fig10": rows_fig10,
        "fig11": rows_fig11, "fig12": rows_fig12, "fig13": rows_fig13}


def _data_key(fig: str) -> str:
    return {"fig8": "fig8_9", "fig9": "fig8_9", "fig10": "fig10_12", "fig11": "fig10_12",
            "fig12": "fig10_12"}.get(fig, fig)


def agreement_rows(results: dict) -> dict[str, list[dict]]:
    """The comparison rows of every figure whose data is in ``results`` (keys as in :func:`run`:
    fig3 ... fig7, fig8_9, fig10_12, fig13)."""
    return {fig: fn(results[_data_key(fig)]) for fig, fn in ROWS.items() if _data_key(fig) in results}


def headline(results: dict) -> dict:
    """Complex-surface bias and precision beside the paper's 'up to 2 cm' and '10 cm'."""
    d = results["fig10_12"]
    sm, S = d["summary"], d["terrain_seeds"]
    out = {"terrain_seeds": S, "shots": d["shots"], "p": d["p"]}
    for beam in ("weak", "strong"):
        b, bse = _beam_summary(sm[beam], "bias", S)
        s, sse = _beam_summary(sm[beam], "std", S)
        out[beam] = {"bias_min_m": float(b.min()), "bias_max_m": float(b.max()),
                     "bias_max_se_m": float(np.nan_to_num(bse)[int(b.argmax())]),
                     "std_min_m": float(s.min()), "std_max_m": float(s.max()),
                     "std_p2_m": float(s[-1]), "std_p2_se_m": float(np.nan_to_num(sse[-1])),
                     "std_p_first_m": float(s[0])}
    return out


def _write_text(path: pathlib.Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def markdown_table(rows: list[dict]) -> list[str]:
    """Markdown lines of a comparison table (quantity, ours, paper, agreement) and its notes."""
    out = ["| quantity | ours (± Monte Carlo SE) | paper | agreement |", "|---|---|---|---|"]
    for r in rows:
        cells = [r["quantity"], r["ours"], r["paper"], f"**{r['agreement']}**"]
        out.append("| " + " | ".join(str(c).replace("|", "/") for c in cells) + " |")
    notes = [f"- *{r['quantity']}*: {r['why']}." for r in rows if r.get("why")]
    return out + ([""] + notes if notes else [])


def _terrain_note(doc: dict) -> str:
    """How much one track's numbers move between terrain realisations vs its photon noise."""
    sm = doc["data"]["fig10_12"]["summary"]["strong"]
    S, ps = doc["headline"]["terrain_seeds"], doc["headline"]["p"]
    if S < 2:
        return ("One realisation per configuration: the terrain-to-terrain scatter of a single "
                "track is not estimated (run the full mode).")
    out = []
    for q, name in (("std", "precision"), ("bias", "bias")):
        sd, mc = np.array(sm[q]["terrain_sd"]), np.array(sm[q]["primary_se"])
        ratio = sd / mc
        what = (f"the terrain realisation dominates the {name} of a single track"
                if np.all(ratio > 2) else
                f"for the {name} the scatter between realisations (which includes the photon "
                f"noise) is comparable to one track's photon noise")
        out.append(what + " (strong beam: " + "; ".join(
            f"p = {p:.1f}: {_cm(a, None, 2)} between realisations vs {_cm(b, None, 2)} Monte Carlo"
            for p, a, b in zip((ps[0], ps[-1]), (sd[0], sd[-1]), (mc[0], mc[-1]))) + ")")
    text = "; ".join(out)
    return text[0].upper() + text[1:] + "."


def format_markdown(doc: dict) -> str:
    """report.md from the report document (``report.json``'s content)."""
    c, h, t = doc["counts"], doc["headline"], doc["timings_s"]
    S = h["terrain_seeds"]
    L = ["# Reproducing Zhang & Kerekes, results section (Figs. 3–13)", "",
         f"Mode **{doc['mode']}**: {c['flat_shots']:,} shots on the flat plate (paper 200,000), "
         f"{c['slope_shots']:,} per slope (paper 50,000), {c['complex_shots']:,} per fractal track "
         f"(paper 1000), {c['terrain_seeds']} fractal realisations per configuration (paper: one), "
         f"{c['paths_per_shot']} traced paths per shot. Wall time {t['total']:.1f} s on "
         f"{doc['environment']['cpus']} CPU cores ({doc['environment']['variant']}; a command-line "
         "run adds about 2 s of Python start-up and package import).", "",
         "Errors are Monte Carlo standard errors: bias SE = std/√n, std SE = std/√(2(n−1)), n the "
         f"detected photons. On fractal surfaces a single {c['complex_shots']}-shot track is one terrain realisation: "
         f"where {S} realisations are averaged the error is the standard error of their mean "
         "(terrain and photon noise together); values for the primary track (terrain seed 0) carry "
         "the photon noise alone. " + _terrain_note(doc),
         "", f"## Headline: complex surfaces (10 m relief, p = {_seq(h['p'])})", "",
         "| | ours | paper | agreement |", "|---|---|---|---|"]
    rows12 = {r["quantity"]: r for r in doc["figures"]["fig12"]["rows"]}
    for beam in ("weak", "strong"):
        hb = h[beam]
        rb = next(r for q, r in rows12.items() if q.startswith(f"bias, {beam}"))
        L.append(f"| elevation bias, {beam} beam | {100 * hb['bias_min_m']:.2f} … {100 * hb['bias_max_m']:.2f} cm "
                 f"(max ± {100 * hb['bias_max_se_m']:.2f}) | up to 2 cm | **{rb['agreement']}** |")
    for beam in ("weak", "strong"):
        hb = h[beam]
        rs = next(r for q, r in rows12.items() if q.startswith(f"standard deviation, {beam}"))
        L.append(f"| precision (std), {beam} beam | {100 * hb['std_p2_m']:.1f} ± {100 * hb['std_p2_se_m']:.1f} cm "
                 f"at p = {h['p'][-1]:.1f}; {100 * hb['std_p_first_m']:.1f} cm at p = {h['p'][0]:.1f} "
                 f"| 10 cm | **{rs['agreement']}** |")
    L += ["", ("Values are the mean of %d fractal realisations, %d shots each." % (S, h["shots"]))
          if S > 1 else "Values are from one %d-shot track per p." % h["shots"], "",
          "## Agreement at a glance", "", "| figure | quantity | agreement |", "|---|---|---|"]
    for fig, f in doc["figures"].items():
        for r in f["rows"]:
            L.append(f"| {fig[3:]} | {r['quantity']} | {r['agreement']} |")
    for fig, f in doc["figures"].items():
        L += ["", f"## {TITLES[fig]}", "", f"![{fig}]({f['png']})", "", f"Paper: {PAPER[fig]}.", ""]
        L += markdown_table(f["rows"])
        if f.get("cli"):
            L += ["", f"Primary run from the command line: `{f['cli']}`"]
        L.append(f"\nTime: {f['time_s']:.1f} s.")
    L += ["", "## Time by figure", "", "| step | wall time [s] |", "|---|---|"]
    for k, v in t.items():
        L.append(f"| {k} | {v:.1f} |")
    L += ["", "Figures 8–9 and 10–12 share their simulations; their compute time is counted "
          "once under the first figure of each group.", ""]
    return "\n".join(L)


def run(out_dir, *, quick: bool = False, profile=None, profile_name: str | None = None,
        log=None, started: float | None = None, workers: int | None = None) -> dict:
    """Regenerate every figure into ``out_dir`` (created if missing; its parent must exist) and
    write ``report.md`` and ``report.json``.

    Args:
        quick: :data:`QUICK` counts instead of the paper's (:data:`FULL`).
        profile: a path (see :func:`load_profile`) or a (distance_m, height_m) pair: an
            along-track profile whose p is fitted too (Fig. 3).
        profile_name: how the report names the profile (default: the file name).
        log: callable receiving one progress line per figure.
        started: ``time.perf_counter()`` at the start of the caller's set-up, to include it in
            the reported wall time.
        workers: compute the figure groups as tasks on a Dask ``LocalCluster`` of this many
            processes (:func:`lidar_mitsuba.sweep.compute_all`); ``None``: one after another
            here. The numbers are the same either way (every computation seeds itself).

    Returns the report document (what ``report.json`` holds).
    """
    t_all = time.perf_counter() if started is None else started
    counts = counts_for(quick)
    prof, prof_name = _profile(profile, profile_name)
    out = pathlib.Path(out_dir)
    out.mkdir(exist_ok=True)
    log = log or (lambda msg: None)
    timings: dict[str, float] = {}
    setup = time.perf_counter() - t_all
    if started is not None:
        timings["set-up"] = setup
    results, fig_time = _compute_and_draw(_computations(counts, prof, prof_name), out,
                                          timings=timings, workers=workers, log=log)
    t0 = time.perf_counter()
    doc = _document(results, counts=counts, quick=quick, fig_time=fig_time, timings=timings)
    timings["report"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_all
    doc = json_safe(doc, skip=lambda key: key.startswith("_"))
    _write_text(out / "report.json", json.dumps(doc, indent=1) + "\n")
    _write_text(out / "report.md", format_markdown(doc))
    timings["total"] = time.perf_counter() - t_all
    return doc


#: the figures each computation draws: group key -> [(figure, draw(data, png path))]
_PLOTS = {"fig3": [("fig3", plot_fig3)], "fig4": [("fig4", plot_fig4)],
          "fig5": [("fig5", plot_fig5)], "fig6": [("fig6", lambda d, p: plot_fig6(p))],
          "fig7": [("fig7", plot_fig7)],
          "fig8_9": [("fig8", plot_fig8), ("fig9", plot_fig9)],
          "fig10_12": [("fig10", plot_fig10), ("fig11", plot_fig11), ("fig12", plot_fig12)],
          "fig13": [("fig13", plot_fig13)]}


def _profile(profile, profile_name: str | None):
    """:func:`run`'s ``profile`` as ``((distance_m, height_m) arrays, name)``, or (None, None)."""
    if profile is None:
        return None, None
    if isinstance(profile, (str, os.PathLike)):
        return load_profile(profile), profile_name or pathlib.Path(profile).name
    return ((np.asarray(profile[0], float), np.asarray(profile[1], float)),
            profile_name or "user profile")


def _computations(counts, prof, prof_name) -> dict:
    """Every figure group's computation (key -> callable returning its data), at ``counts``."""
    return {
        "fig3": lambda: fig3_spectra(profile=prof, profile_name=prof_name),
        "fig4": fig4_surfaces,
        "fig5": lambda: fig5_rms(terrain_seeds=max(counts.terrain_seeds, 3)),
        "fig6": fig6_brdf,
        "fig7": lambda: fig7_flat(shots=counts.flat_shots, paths_per_shot=counts.paths_per_shot),
        "fig8_9": lambda: fig8_9_slopes(shots=counts.slope_shots, slopes_deg=counts.slopes_deg,
                                        paths_per_shot=counts.paths_per_shot),
        "fig10_12": lambda: fig10_12_complex(shots=counts.complex_shots,
                                             terrain_seeds=counts.terrain_seeds,
                                             p_values=counts.p_values,
                                             paths_per_shot=counts.paths_per_shot),
        "fig13": lambda: fig13_albedo(shots=counts.complex_shots,
                                      terrain_seeds=counts.terrain_seeds,
                                      resolve_shots=counts.resolve_shots, albedos=counts.albedos,
                                      paths_per_shot=counts.paths_per_shot),
    }


def _compute_and_draw(computes: dict, out: pathlib.Path, *, timings: dict,
                      workers: int | None, log) -> tuple[dict, dict[str, float]]:
    """Run every computation (here, or as tasks on ``workers`` Dask workers) and draw its
    figures into ``out``. Returns ``(results by group, seconds by figure)`` (a group's
    compute time counted under its first figure); each group's seconds go into ``timings``."""
    results: dict = {}
    fig_time: dict[str, float] = {}
    if workers:      # every figure's computation seeds itself: the same numbers anywhere
        from ...sweep import compute_all
        log(f"computing the {len(computes)} figure groups on {workers} Dask workers")
        computed = compute_all(computes, workers=workers, log=log)
    for key, compute in computes.items():
        t0 = time.perf_counter()
        if workers:
            results[key], compute_s = computed[key]
        else:
            results[key] = compute()
            compute_s = time.perf_counter() - t0
        t1 = time.perf_counter()
        for fig, draw in _PLOTS[key]:
            t2 = time.perf_counter()
            draw(results[key], out / PNG[fig])
            fig_time[fig] = time.perf_counter() - t2
        fig_time[_PLOTS[key][0][0]] += compute_s
        spent = compute_s + time.perf_counter() - t1
        timings[key.replace("_", "–").replace("fig", "Fig. ")] = spent
        log(f"{key}: {spent:.1f} s")
    return results, fig_time


def _document(results: dict, *, counts, quick: bool, fig_time: dict, timings: dict) -> dict:
    """The report document (``report.json``'s content before
    :func:`~lidar_mitsuba.studies.json_safe`): mode,
    counts, seeds, headline, every figure's rows and command line, the data, the
    environment and ``timings`` (the dict itself, still filled by the caller)."""
    cloud = results["fig10_12"].get("_cloud")
    if cloud is not None:
        results["fig10_12"]["cloud_stats"] = cloud["stats"]
        results["fig10_12"]["cloud_p"] = cloud["p"]
    rows = agreement_rows(results)
    clis = {"fig7": results["fig7"]["cli"], "fig9": results["fig8_9"]["runs"][-1]["cli"],
            "fig10": cloud["cli"] if cloud else None, "fig12": results["fig10_12"]["cli_primary"],
            "fig13": results["fig13"]["cli_primary"]}
    return {
        "mode": "quick" if quick else "full (paper counts)", "counts": asdict(counts),
        "seeds": dict(SEEDS), "headline": headline(results),
        "figures": {fig: {"title": TITLES[fig], "png": PNG[fig], "paper": PAPER[fig],
                          "rows": rows[fig], "time_s": fig_time[fig],
                          **({"cli": clis[fig]} if clis.get(fig) else {})}
                    for fig in ROWS},
        "data": {k: v for k, v in results.items()},
        "environment": {"variant": mi.variant(), "cpus": os.cpu_count(),
                        "python": platform.python_version(), "machine": platform.machine()},
        "timings_s": timings,
    }


def format_summary(doc: dict) -> str:
    """A few lines for the terminal: the headline, the verdict counts and the wall time."""
    h = doc["headline"]
    lines = [f"reproduce ({doc['mode']}): {doc['timings_s']['total']:.1f} s"]
    for beam in ("weak", "strong"):
        hb = h[beam]
        lines.append(f"  {beam:<6} beam: bias {100 * hb['bias_min_m']:.2f} … {100 * hb['bias_max_m']:.2f} cm "
                     f"(paper: up to 2 cm); std {100 * hb['std_p2_m']:.1f} cm at p = {h['p'][-1]:.1f}, "
                     f"{100 * hb['std_p_first_m']:.1f} cm at p = {h['p'][0]:.1f} (paper: 10 cm)")
    tally: dict[str, int] = {}
    for f in doc["figures"].values():
        for r in f["rows"]:
            key = r["agreement"].split(":")[0]
            tally[key] = tally.get(key, 0) + 1
    lines.append("  verdicts: " + ", ".join(f"{v} {k}" for k, v in sorted(tally.items(), key=lambda kv: -kv[1])))
    return "\n".join(lines)
