"""Compare BRDF variants on the simulated returns: sweeps over surfaces, a table and figures.

One *row* is one :func:`~lidar_mitsuba.simulate.simulate` run (one BRDF on one surface) reduced
to photons per shot, elevation bias and precision of the signal photons, each with its Monte
Carlo standard error. Every variant on a surface is run with the same ``seed``, so the footprint
positions and pulse times of the traced photons are the same for all of them (common random
numbers): the *differences* between variants are less noisy than the per-row error bars.

>>> import lidar_mitsuba
>>> from lidar_mitsuba import compare
>>> rows = compare.sweep(variants=compare.BRDF_VARIANTS,
...                      surfaces=compare.slope_surfaces(slopes_deg=(0, 10, 20)),
...                      shots=2000, seed=1, beam="strong")          # doctest: +SKIP
>>> fig = compare.plot_sweep(rows, x="slope_deg")                    # doctest: +SKIP
"""
from __future__ import annotations

import functools
import math
import time
from collections.abc import Iterable, Mapping, Sequence

import matplotlib.pyplot as plt
import numpy as np

from ..instrument import Instrument
from ..simulate import SimulationResult, simulate
from ..surface import SurfaceSpec

_WARD = {"type": "ward", "rho_d": 0.9, "rho_s": 0.05, "alpha": 0.3}

#: BRDF variants compared, name -> Mitsuba BSDF dict (mono variants: one scalar per quantity).
#:
#: * the paper's Ward snow (rho_d 0.9, rho_s 0.05, alpha 0.3) with its three normalisations of
#:   the specular lobe (they agree exactly at normal incidence and differ off normal);
#: * a Lambertian 0.9 plate, the instrument's radiometric reference (return weight exactly 1
#:   on a flat plate at nadir);
#: * Mitsuba's ``roughplastic`` (diffuse 0.9 under a dielectric coating of IOR 1.49 with a
#:   rough interface, alpha 0.3), Beckmann and GGX. Its diffuse part is attenuated by the
#:   coating's Fresnel transmission and internal reflection, which Mitsuba integrates over the
#:   chosen microfacet distribution, so ``diffuse_reflectance`` 0.9 returns less than the 0.9
#:   Lambertian plate, and GGX (longer tails) less than Beckmann;
#: * Mitsuba's ``roughconductor`` (Beckmann, alpha 0.3) with ``material="none"`` (a Fresnel
#:   factor of exactly 1, spectrally flat, so nothing depends on how a mono variant reduces a
#:   metal's spectral IOR) scaled by ``specular_reflectance`` 0.9 to the snow's albedo. With no
#:   diffuse part its nadir return is the lobe peak, 1/(4 alpha^2) * 0.9 / 0.9 = 2.78 times the
#:   Lambertian plate's, and it falls off as the Beckmann distribution exp(-tan^2(theta)/alpha^2).
BRDF_VARIANTS: dict[str, dict] = {
    "Ward ward1992": {**_WARD, "normalization": "ward1992"},
    "Ward duer": {**_WARD, "normalization": "duer"},
    "Ward balanced": {**_WARD, "normalization": "balanced"},
    "Lambertian": {"type": "diffuse", "reflectance": 0.9},
    "roughplastic Beckmann": {"type": "roughplastic", "diffuse_reflectance": 0.9, "alpha": 0.3,
                              "distribution": "beckmann"},
    "roughplastic GGX": {"type": "roughplastic", "diffuse_reflectance": 0.9, "alpha": 0.3,
                         "distribution": "ggx"},
    "roughconductor": {"type": "roughconductor", "material": "none", "alpha": 0.3,
                       "distribution": "beckmann", "specular_reflectance": 0.9},
}

#: Plot style per variant name (colour, marker); unknown names get matplotlib's cycle.
STYLES: dict[str, tuple[str, str]] = {
    "Ward ward1992": ("#08519c", "o"),
    "Ward duer": ("#3182bd", "s"),
    "Ward balanced": ("#6baed6", "D"),
    "Lambertian": ("black", "x"),
    "roughplastic Beckmann": ("#e6550d", "^"),
    "roughplastic GGX": ("#fdae6b", "v"),
    "roughconductor": ("#a50f15", "*"),
}

#: Numeric fields of a row that :func:`sweep` fills (all floats; see :func:`row_of`).
ROW_FIELDS = ("photons_per_shot", "photons_per_shot_se", "return_weight", "bias_m", "bias_se_m",
              "std_m", "std_se_m")


def slope_surfaces(*, slopes_deg: Iterable[float] = (0, 5, 10, 15, 20, 25, 30),
                   azimuth_deg: float = 0.0) -> list[SurfaceSpec]:
    """Sloped planes, one per slope [deg] (0 is the flat plate), rising along ``azimuth_deg``."""
    return [SurfaceSpec(kind="slope", slope_deg=float(s), slope_azimuth_deg=float(azimuth_deg))
            for s in slopes_deg]


def fractal_surfaces(*, ps: Iterable[float] = (1.5, 1.6, 1.8, 2.0), relief_m: float = 10.0,
                     size_m: float = 1024.0, grid_m: float = 1.0,
                     terrain_seed: int = 0) -> list[SurfaceSpec]:
    """Fractal snow tiles, one per spectral exponent ``p``, all from the same white noise
    (``terrain_seed``), each scaled to ``relief_m`` max - min [m] over a ``size_m`` tile [m]."""
    return [SurfaceSpec(kind="fractal", p=float(p), relief_m=float(relief_m), size_m=float(size_m),
                        grid_m=float(grid_m), terrain_seed=int(terrain_seed)) for p in ps]


def _instrument(beam: str | Instrument, ideal_detector: bool | None) -> Instrument:
    inst = beam if isinstance(beam, Instrument) else Instrument(beam=beam)
    if ideal_detector is not None and inst.ideal_detector != ideal_detector:
        inst = inst.replace(ideal_detector=bool(ideal_detector))
    return inst


def row_of(res: SimulationResult) -> dict:
    """Photons per shot, bias and precision of one run's signal photons, with standard errors.

    Returns a dict of floats (NaN where undefined):
        photons_per_shot: detected signal photons / shots [photons/shot].
        photons_per_shot_se: its standard error, std(per-shot counts, ddof=1) / sqrt(shots).
        return_weight: footprint-averaged return weight, mean over shots of the Poisson mean
            arrivals / ``signal_photons`` (1 for the flat Lambertian 0.9 plate at nadir;
            before fill factor, PDE and dead time) [-].
        bias_m, bias_se_m: mean of h - z_ref [m] and its standard error std / sqrt(n) [m].
        std_m, std_se_m: precision, the standard deviation of h - z_ref [m], and its standard
            error from the photons' kurtosis (std / sqrt(2 (n - 1)) for normal residuals) [m].
    Also ``n_photons`` (int) and ``shots`` (int).
    """
    st = res.report().overall
    d = res.detections
    counts = np.bincount(d.shot[d.is_signal], minlength=res.n_shots)
    n = st.n_photons
    sp = float(res.instrument.signal_photons)
    return {
        "shots": int(res.n_shots), "n_photons": int(n),
        "photons_per_shot": float(st.photons_per_shot),
        "photons_per_shot_se": float(counts.std(ddof=1) / math.sqrt(res.n_shots))
        if res.n_shots > 1 else math.nan,
        "return_weight": float(np.mean(d.mean_photons_per_shot) / sp) if sp > 0 else math.nan,
        "bias_m": float(st.bias_m), "bias_se_m": float(st.bias_se_m),
        "std_m": float(st.std_m), "std_se_m": float(st.std_se_m),
    }


def sweep(*, variants: Mapping[str, dict], surfaces: Sequence[SurfaceSpec], shots: int,
          seed: int = 0, beam: str | Instrument = "strong", ideal_detector: bool | None = None,
          paths_per_shot: int = 128, max_depth: int | str = 1,
          progress: bool = False, workers: int | None = None) -> list[dict]:
    """Simulate every BRDF variant on every surface and summarise each run.

    Args:
        variants: name -> Mitsuba BSDF dict (e.g. :data:`BRDF_VARIANTS`), replacing the
            surface's Ward BSDF.
        surfaces: the surfaces (e.g. :func:`slope_surfaces`, :func:`fractal_surfaces`); their
            own Ward parameters are ignored.
        shots: laser shots per run (the track: ``shots`` x 0.7 m, folded into the tile).
        seed: photon and detector seed, the same for every run (common random numbers).
        beam: ``"strong"``, ``"weak"`` or an :class:`~lidar_mitsuba.instrument.Instrument`.
        ideal_detector: override the instrument's dead time (``True``: none); ``None`` keeps it.
        paths_per_shot: traced photon paths per shot.
        max_depth: surface interactions per path. Default 1: every BRDF under one model (the
            paper's single bounce), so that common random numbers pair the runs; 2 adds
            multiple scattering; ``"auto"`` lets each run choose (see
            :func:`~lidar_mitsuba.simulate.simulate`), which may differ between BRDFs.
        progress: print one line per run.
        workers: run the simulations as tasks on a Dask ``LocalCluster`` of this many
            processes (:func:`lidar_mitsuba.sweep.compute_all`); the rows are the same.

    Returns:
        ``len(surfaces) * len(variants)`` rows (surface-major), each a dict with ``variant``,
        ``bsdf`` (the BSDF's plugin type), ``beam``, ``ideal_detector``, ``dead_time_ns``
        [ns], ``kind``, ``slope_deg`` [deg], ``p`` (NaN off fractals), ``relief_m`` [m],
        ``size_m`` [m], ``terrain_seed``, ``seed``, ``max_depth`` (the one used),
        ``time_s`` [s] and the fields of
        :func:`row_of` (``shots``, ``n_photons``, ``photons_per_shot``,
        ``photons_per_shot_se``, ``return_weight``, ``bias_m``, ``bias_se_m``, ``std_m``,
        ``std_se_m``).
    """
    inst = _instrument(beam, ideal_detector)
    if not variants:
        raise ValueError("variants: give at least one BRDF")
    runs = {(i, name): functools.partial(
        simulate, instrument=inst, surface=surface, bsdf=dict(bsdf), shots=shots, seed=seed,
        paths_per_shot=paths_per_shot, max_depth=max_depth, progress=False)
        for i, surface in enumerate(surfaces) for name, bsdf in variants.items()}
    if workers:
        from ..sweep import compute_all
        done = compute_all({k: functools.partial(_row_of_run, fn) for k, fn in runs.items()},
                           workers=workers)
    rows = []
    for (i, name), fn in runs.items():
        surface, bsdf = surfaces[i], variants[name]
        (max_used, summary), seconds = done[(i, name)] if workers else _timed_row(fn)
        row = {"variant": name, "bsdf": str(bsdf.get("type", "")), "beam": inst.beam,
               "ideal_detector": inst.ideal_detector,
               "dead_time_ns": float(inst.effective_dead_time_ns), "kind": surface.kind,
               "slope_deg": float(surface.slope_deg) if surface.kind == "slope" else 0.0,
               "p": float(surface.p) if surface.kind == "fractal" else math.nan,
               "relief_m": float(surface.relief_m) if surface.kind == "fractal" else 0.0,
               "size_m": float(surface.size_m), "terrain_seed": int(surface.terrain_seed),
               "seed": int(seed), "max_depth": max_used, **summary, "time_s": seconds}
        rows.append(row)
        if progress:
            print(f"{_surface_label(row):<16}{name:<24}{row['photons_per_shot']:7.3f} ph/shot "
                  f"({row['time_s']:.2f} s)", flush=True)
    return rows


def _row_of_run(run) -> tuple[int, dict]:
    """(max_depth used, :func:`row_of`) of ``run()``: small enough to send back from a worker."""
    res = run()
    return int(res.config["max_depth"]), row_of(res)


def _timed_row(run):
    t0 = time.perf_counter()
    out = _row_of_run(run)
    return out, time.perf_counter() - t0


def _surface_label(row: dict) -> str:
    if row["kind"] == "fractal":
        return f"fractal p={row['p']:g}"
    if row["kind"] == "slope" and row["slope_deg"] != 0:
        return f"slope {row['slope_deg']:g}°"
    return "flat"


def select(rows: Iterable[dict], **where) -> list[dict]:
    """The rows whose fields equal ``where`` (e.g. ``variant="Lambertian", kind="fractal"``);
    ``kind="plane"`` matches both ``flat`` and ``slope``."""
    out = []
    for r in rows:
        ok = True
        for k, v in where.items():
            if k == "kind" and v == "plane":
                ok &= r["kind"] in ("flat", "slope")
            elif isinstance(v, float) and isinstance(r.get(k), float):
                ok &= math.isclose(r[k], v, rel_tol=0, abs_tol=1e-9)
            else:
                ok &= r.get(k) == v
        if ok:
            out.append(r)
    return out


def format_table(rows: Sequence[dict], *, title: str = "") -> str:
    """A plain-text table of sweep rows: photons/shot, bias and precision in cm, with errors."""
    head = (f"{'surface':<15}{'BRDF':<23}{'weight':>7}{'photons/shot':>15}"
            f"{'bias [cm]':>16}{'precision [cm]':>17}")
    out = [title] if title else []
    out.append(head)
    for r in rows:
        out.append(f"{_surface_label(r):<15}{r['variant']:<23}{r['return_weight']:>7.3f}"
                   f"{r['photons_per_shot']:>8.3f} ±{r['photons_per_shot_se']:>5.3f}"
                   f"{100 * r['bias_m']:>9.2f} ±{100 * r['bias_se_m']:>5.2f}"
                   f"{100 * r['std_m']:>10.2f} ±{100 * r['std_se_m']:>5.2f}")
    return "\n".join(out)


def _surface_key(row: dict) -> tuple:
    fractal = row["kind"] == "fractal"
    return ("fractal" if fractal else "plane", row["slope_deg"], row["p"] if fractal else None,
            row["relief_m"], row["size_m"] if fractal else None,
            row["terrain_seed"] if fractal else None, row["beam"], row["ideal_detector"],
            row["shots"], row["seed"])


def relative_to(rows: Sequence[dict], *, reference: str = "Lambertian") -> list[dict]:
    """Each row against the ``reference`` variant's row on the same surface, beam and detector.

    Returns one dict per row that has a reference (the reference's own rows included: ratio 1,
    difference 0), with the row's identifying fields (``variant``, ``beam``,
    ``ideal_detector``, ``kind``, ``slope_deg``, ``p``) and
        photons_ratio, photons_ratio_se: photons per shot / the reference's [-];
        weight_ratio: return weight / the reference's [-];
        bias_diff_m, bias_diff_se_m: bias - the reference's bias [m];
        std_ratio, std_ratio_se: precision / the reference's precision [-].
    Errors combine both rows' standard errors as if independent; the runs share their random
    numbers (same seed), which correlates them positively, so the errors are conservative.
    """
    refs = {_surface_key(r): r for r in rows if r["variant"] == reference}
    out = []
    for r in rows:
        b = refs.get(_surface_key(r))
        if b is None:
            continue
        same = r is b

        def ratio(key, err):
            v = r[key] / b[key]
            e = 0.0 if same else v * math.hypot(r[err] / r[key], b[err] / b[key])
            return v, e

        pr, pre = ratio("photons_per_shot", "photons_per_shot_se")
        sr, sre = ratio("std_m", "std_se_m")
        out.append({k: r[k] for k in ("variant", "beam", "ideal_detector", "kind", "slope_deg", "p")}
                   | {"photons_ratio": pr, "photons_ratio_se": pre,
                      "weight_ratio": r["return_weight"] / b["return_weight"],
                      "bias_diff_m": r["bias_m"] - b["bias_m"],
                      "bias_diff_se_m": 0.0 if same else math.hypot(r["bias_se_m"], b["bias_se_m"]),
                      "std_ratio": sr, "std_ratio_se": sre})
    return out


_PANELS = (
    # (row key, error key, scale, absolute label,
    #  relative key, its error, its scale, its label, shift subtracted before scaling)
    ("photons_per_shot", "photons_per_shot_se", 1.0, "photons per shot",
     "photons_ratio", "photons_ratio_se", 1.0, "photons per shot ÷ {ref}'s", 0.0),
    ("bias_m", "bias_se_m", 100.0, "elevation bias [cm]",
     "bias_diff_m", "bias_diff_se_m", 100.0, "bias − {ref}'s [cm]", 0.0),
    ("std_m", "std_se_m", 100.0, "precision (std) [cm]",
     "std_ratio", "std_ratio_se", 100.0, "precision ÷ {ref}'s − 1 [%]", 1.0),
)


def plot_sweep(rows: Sequence[dict], *, x: str, reference: str | None = "Lambertian",
               variants: Sequence[str] | None = None, instrument: Instrument | None = None,
               title: str = "", path=None):
    """Photons per shot, bias and precision against slope or p, one curve per BRDF variant.

    Top row: the values. Bottom row (when ``reference`` is among the rows): the same against
    the ``reference`` variant on the same surface (see :func:`relative_to`): photons per shot
    as a ratio, bias as a difference [cm], precision as a relative difference [%].

    Args:
        rows: output of :func:`sweep` for one beam and detector (rows of other surfaces than
            those of ``x`` are ignored).
        x: ``"slope_deg"`` (flat and sloped planes) or ``"p"`` (fractal tiles).
        reference: variant the bottom row compares with (``None``: no bottom row).
        variants: the variants to draw, in legend order (default: all, in row order).
        instrument: for ``x="slope_deg"``, draw the ideal-detector closed form of the precision,
            hypot(c sigma_t / 2, sigma_fp tan(slope)), as a dashed line (default: the rows'
            beam's instrument); that panel's y axis is logarithmic.
        title: figure title. path: PNG file to write (optional).

    Error bars are +-1 Monte Carlo standard error; points of the variants are spread a little
    along x so that their error bars do not hide one another.
    Returns the matplotlib Figure (2 x 3 panels, or 1 x 3 without a reference).
    """
    if x not in ("slope_deg", "p"):
        raise ValueError(f"x must be 'slope_deg' or 'p' (got {x!r})")
    sel = select(rows, kind="plane") if x == "slope_deg" else select(rows, kind="fractal")
    if not sel:
        raise ValueError(f"no rows to plot against {x}")
    names = list(dict.fromkeys(r["variant"] for r in sel)) if variants is None else list(variants)
    rel = relative_to(sel, reference=reference) if reference is not None else []
    nrows = 2 if rel else 1
    xs_all = sorted({r[x] for r in sel})
    span = (xs_all[-1] - xs_all[0]) if len(xs_all) > 1 else 1.0
    dodge = 0.01 * span
    fig, axes = plt.subplots(nrows, 3, figsize=(15, 4.3 * nrows + 0.4), dpi=110, squeeze=False,
                             sharex=True)
    for k, name in enumerate(names):
        colour, marker = STYLES.get(name, (None, "o"))
        off = (k - (len(names) - 1) / 2) * dodge
        for i, source in enumerate((sel, rel)[:nrows]):
            rs = sorted((r for r in source if r["variant"] == name), key=lambda r: r[x])
            if not rs:
                continue
            xv = np.array([r[x] for r in rs])
            for j, (ax, panel) in enumerate(zip(axes[i], _PANELS)):
                key, err, scale = panel[0:3] if i == 0 else panel[4:7]
                shift = panel[8] if i == 1 else 0.0
                y = scale * (np.array([r[key] for r in rs]) - shift)
                # no spread for the absolute precision: its error bars are tiny, and a spread
                # along x would read as a difference on the steep curve
                ax.errorbar(xv + (0.0 if (i, j) == (0, 2) else off), y, yerr=scale * np.array([r[err] for r in rs]), color=colour,
                            marker=marker, ms=5, lw=1.2, capsize=2.5, label=name)
    if x == "slope_deg":
        inst = instrument or Instrument(beam=sel[0]["beam"])
        s = np.linspace(xs_all[0], xs_all[-1], 200)
        closed = np.hypot(inst.ranging_sigma_m, inst.footprint_sigma_m * np.tan(np.radians(s)))
        axes[0][2].plot(s, 100 * closed, "--", color="grey", lw=1,
                        label="closed form, ideal detector")
        axes[0][2].set_yscale("log")
    xlabel = "surface slope [deg]" if x == "slope_deg" else "fractal spectral exponent p"
    for i in range(nrows):
        for ax, panel in zip(axes[i], _PANELS):
            ax.set_ylabel(panel[3] if i == 0 else panel[7].format(ref=reference))
            ax.grid(alpha=0.3)
            if i == nrows - 1:
                ax.set_xlabel(xlabel)
            if i == 1:
                ax.axhline(1.0 if panel[4] == "photons_ratio" else 0.0, color="grey", lw=0.8)
    axes[0][0].set_ylim(bottom=0)
    axes[0][1].axhline(0.0, color="grey", lw=0.8)
    axes[0][2].legend(fontsize=7.5, loc="best")
    meta = sel[0]
    det = ("ideal detector (no dead time)" if meta["ideal_detector"]
           else f"{meta['dead_time_ns']:g} ns dead time")
    sub = f"{meta['beam']} beam, {det}, {meta['shots']} shots per point, ±1 s.e."
    fig.suptitle(f"{title}\n{sub}" if title else sub, fontsize=11)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path)
        plt.close(fig)
    return fig


def _loc(r: dict) -> tuple:
    """Surface and beam of a row or of a :func:`relative_to` dict."""
    fractal = r["kind"] == "fractal"
    return ("fractal" if fractal else "plane", r["slope_deg"], r["p"] if fractal else None,
            r["beam"])


def _fmt_surface(r: dict) -> str:
    return _surface_label(r) if r["kind"] == "fractal" else (
        "the flat plate" if r["slope_deg"] == 0 else f"the {r['slope_deg']:g}° slope")


def _join(parts: Sequence[str]) -> str:
    parts = list(parts)
    return parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]


def conclusions(rows: Sequence[dict], *, ideal_rows: Sequence[dict] = (),
                reference: str = "Lambertian", z: float = 3.0) -> list[str]:
    """Plain-language findings computed from sweep rows, each true of the numbers given.

    Differences count as significant when they exceed ``z`` combined standard errors (see
    :func:`relative_to`); with a smaller sample fewer of them are, and the sentences say so
    rather than assume. Covers, per beam: brightness on the flat plate (return weight and
    detected photons against ``reference``), the fall-off of the return with slope and with
    fractal roughness, the
    agreement of the Ward normalisations, the bias and the precision against ``reference``;
    and, with ``ideal_rows`` (the same variants without dead time), whether the bias
    differences remain without dead time.

    Args:
        rows: :func:`sweep` rows with the paper's detector (any beams, planes and fractals).
        ideal_rows: :func:`sweep` rows with ``ideal_detector=True`` (optional).
        reference: the variant everything is compared with.
        z: significance threshold in standard errors.
    Returns:
        list of sentences (str).
    """
    out: list[str] = []
    said_fractal = False
    beams = list(dict.fromkeys(r["beam"] for r in rows))
    for beam in beams:
        mine = [r for r in rows if r["beam"] == beam and not r["ideal_detector"]]
        rel = [d for d in relative_to(mine, reference=reference) if d["variant"] != reference]
        if not rel:
            continue
        names = list(dict.fromkeys(d["variant"] for d in rel))
        bsdf_of = {r["variant"]: r.get("bsdf", "") for r in mine}
        tag = f"[{beam} beam] "

        # 1. brightness on the flat plate
        flat = [d for d in rel if d["kind"] != "fractal" and d["slope_deg"] == 0]
        flat_ref = [r for r in mine if r["variant"] == reference and r["kind"] != "fractal"
                    and r["slope_deg"] == 0]
        if flat and flat_ref:
            b = flat_ref[0]
            groups: dict[tuple, list[str]] = {}   # variants with identical numbers, together
            for d in flat:
                key = (round(d["weight_ratio"], 4), round(d["photons_ratio"], 6))
                groups.setdefault(key, []).append(d["variant"])
            parts = []
            for d in flat:
                key = (round(d["weight_ratio"], 4), round(d["photons_ratio"], 6))
                if groups[key][0] != d["variant"]:
                    continue
                label = _join(groups[key])
                parts.append(f"{label} ×{d['weight_ratio']:.3f} in return weight and "
                             f"×{d['photons_ratio']:.2f} ± {d['photons_ratio_se']:.2f} in "
                             f"detected photons")
            s = (f"{tag}On the flat plate, against the {reference} 0.9 plate "
                 f"({b['photons_per_shot']:.2f} ± {b['photons_per_shot_se']:.2f} detected "
                 f"photons/shot): {'; '.join(parts)}.")
            squeezed = [d for d in flat if d["weight_ratio"] - d["photons_ratio"]
                        > z * d["photons_ratio_se"]]
            if squeezed:
                s += (f" Dead time compresses the brightest return"
                      f"{'s' if len(squeezed) > 1 else ''} "
                      f"({_join([d['variant'] for d in squeezed])}): fewer photons are detected "
                      f"than the return weight predicts.")
            out.append(s)

        # 2. fall-off with slope
        planes = [r for r in mine if r["kind"] != "fractal"]
        slopes = sorted({r["slope_deg"] for r in planes})
        if len(slopes) > 1 and slopes[0] == 0:
            lo, hi = slopes[0], slopes[-1]
            w = {(r["variant"], r["slope_deg"]): r["return_weight"] for r in planes}
            falls = sorted(((w[(n, hi)] / w[(n, lo)], n) for n in [reference] + names
                            if (n, lo) in w and (n, hi) in w), reverse=True)
            parts = [f"{n} ×{f:.2f}" for f, n in falls]
            s = (f"{tag}From 0° to {hi:g}° of slope the return weight falls to {_join(parts)} "
                 f"of its nadir value (cos {hi:g}° = {math.cos(math.radians(hi)):.2f}).")
            for n in names:
                ratio = [(sd, w[(n, sd)] / w[(reference, sd)]) for sd in slopes
                         if (n, sd) in w and (reference, sd) in w]
                if len(ratio) > 1 and ratio[0][1] > 1 and ratio[-1][1] < 1:
                    k = next(i for i, (_, v) in enumerate(ratio) if v < 1)
                    (s0, v0), (s1, v1) = ratio[k - 1], ratio[k]
                    cross = s0 + (v0 - 1) / (v0 - v1) * (s1 - s0)
                    s += (f" {n} is brighter than {reference} below about {cross:.0f}° and "
                          f"dimmer beyond.")
            out.append(s)

        # 2b. the return against the reference as the fractal roughens (the traced weights do
        # not depend on the beam: say it once)
        fr = [r for r in mine if r["kind"] == "fractal"]
        ps = sorted({r["p"] for r in fr})
        if len(ps) > 1 and not said_fractal:
            w = {(r["variant"], r["p"]): r["return_weight"] for r in fr}
            lo, hi = ps[0], ps[-1]
            parts = [f"{n} ×{w[(n, lo)] / w[(reference, lo)]:.2f} → ×"
                     f"{w[(n, hi)] / w[(reference, hi)]:.2f}" for n in names
                     if all(k in w for k in ((n, lo), (n, hi), (reference, lo), (reference, hi)))]
            if parts:
                said_fractal = True
                out.append(f"{tag}On the fractal tiles, from p = {lo:g} (roughest) to p = {hi:g}, "
                           f"the return weight against {reference}'s goes: {_join(parts)}.")

        # 3. the Ward normalisations against one another
        wards = [n for n in [reference] + names if bsdf_of.get(n) == "ward"]
        if len(wards) > 1:
            by = {(r["variant"], _loc(r)): r for r in mine}
            keys = list(dict.fromkeys(_loc(r) for r in mine))
            wmax, zmax, where = 0.0, 0.0, ""
            for key in keys:
                rs = [by[(n, key)] for n in wards if (n, key) in by]
                for i in range(len(rs)):
                    for j in range(i + 1, len(rs)):
                        a, c = rs[i], rs[j]
                        wmax = max(wmax, abs(a["return_weight"] / c["return_weight"] - 1))
                        for m, e in (("photons_per_shot", "photons_per_shot_se"),
                                     ("bias_m", "bias_se_m"), ("std_m", "std_se_m")):
                            zz = abs(a[m] - c[m]) / math.hypot(a[e], c[e])
                            if zz > zmax:
                                zmax, where = zz, (f"{m.replace('_m', '').replace('_', ' ')} "
                                                   f"on {_fmt_surface(a)}")
            verdict = (f"agree within {z:g} s.e. everywhere (largest difference {zmax:.1f} s.e., "
                       f"{where})" if zmax <= z else
                       f"differ by up to {zmax:.1f} s.e. ({where})")
            out.append(f"{tag}The {len(wards)} Ward normalisations ({_join(wards)}) differ in "
                       f"return weight by at most {100 * wmax:.1f}% on these surfaces, and "
                       f"their photons/shot, biases and precisions {verdict}.")

        # 4. bias against the reference
        sig = {}
        for d in rel:
            if abs(d["bias_diff_m"]) > z * d["bias_diff_se_m"]:
                sig.setdefault(d["variant"], []).append(d)
        n_surf = len({_loc(r) for r in mine if r["variant"] == reference})
        if sig:
            parts = []
            for n, ds in sig.items():
                lo_cm = 100 * min(d["bias_diff_m"] for d in ds)
                hi_cm = 100 * max(d["bias_diff_m"] for d in ds)
                rng_txt = f"{lo_cm:+.1f} cm" if len(ds) == 1 else f"{lo_cm:+.1f} to {hi_cm:+.1f} cm"
                parts.append(f"{n} on {len(ds)} of {n_surf} surfaces ({rng_txt})")
            rest = [n for n in names if n not in sig]
            s = (f"{tag}Elevation bias differs from {reference}'s by more than {z:g} s.e. for "
                 f"{_join(parts)}.")
            if rest:
                big = max((d for d in rel if d["variant"] in rest),
                          key=lambda d: abs(d["bias_diff_m"]) / max(d["bias_diff_se_m"], 1e-12))
                s += (f" {_join(rest)} never do (largest: {100 * big['bias_diff_m']:+.2f} ± "
                      f"{100 * big['bias_diff_se_m']:.2f} cm, {big['variant']} on "
                      f"{_fmt_surface(big)}).")
        else:
            big = max(rel, key=lambda d: abs(d["bias_diff_m"]) / max(d["bias_diff_se_m"], 1e-12))
            s = (f"{tag}No variant's elevation bias differs from {reference}'s by more than "
                 f"{z:g} s.e. on any surface (largest: {100 * big['bias_diff_m']:+.2f} ± "
                 f"{100 * big['bias_diff_se_m']:.2f} cm, {big['variant']} on "
                 f"{_fmt_surface(big)}).")
        bias_ref = [r["bias_m"] for r in mine if r["variant"] == reference]
        s += (f" {reference}'s own bias ranges over {100 * min(bias_ref):+.2f} to "
              f"{100 * max(bias_ref):+.2f} cm on these surfaces.")
        out.append(s)

        # 5. precision against the reference
        worst = max(rel, key=lambda d: abs(d["std_ratio"] - 1))
        zs = max(abs(d["std_ratio"] - 1) / max(d["std_ratio_se"], 1e-12) for d in rel)
        std_ref = [r["std_m"] for r in mine if r["variant"] == reference]
        dev = abs(worst["std_ratio"] - 1)
        spread = max(std_ref) / min(std_ref) - 1
        s = (f"{tag}Precision is within {100 * dev:.1f}% of {reference}'s for every variant "
             f"and surface (largest: {worst['variant']} on {_fmt_surface(worst)}; the largest "
             f"difference is {zs:.1f} s.e.), while across the surfaces it ranges from "
             f"{100 * min(std_ref):.1f} to {100 * max(std_ref):.1f} cm")
        s += (": the terrain, not the BRDF, sets it." if spread > 5 * dev and dev < 0.1 else ".")
        out.append(s)

    # 6. the same without dead time
    if ideal_rows:
        rel_i = [d for d in relative_to(ideal_rows, reference=reference)
                 if d["variant"] != reference]
        if rel_i:
            big = max(rel_i, key=lambda d: abs(d["bias_diff_m"]) / max(d["bias_diff_se_m"], 1e-12))
            zi = abs(big["bias_diff_m"]) / max(big["bias_diff_se_m"], 1e-12)
            surf = _join(list(dict.fromkeys(_fmt_surface(d) for d in rel_i)))
            beams_i = _join(list(dict.fromkeys(d["beam"] for d in rel_i)))
            s = (f"[ideal detector] Without dead time ({beams_i} beam, {surf}) the largest bias "
                 f"difference from {reference} is {100 * big['bias_diff_m']:+.2f} ± "
                 f"{100 * big['bias_diff_se_m']:.2f} cm ({big['variant']} on "
                 f"{_fmt_surface(big)}, {zi:.1f} s.e.)")
            # the same surfaces and beam with dead time
            locs = {_loc(d) for d in rel_i}
            with_dt = [d for d in relative_to(rows, reference=reference)
                       if d["variant"] != reference and not d["ideal_detector"]
                       and _loc(d) in locs]
            sig_dt = [d for d in with_dt if abs(d["bias_diff_m"]) > z * d["bias_diff_se_m"]]
            if zi <= z and sig_dt:
                s += (f", within {z:g} s.e., whereas with dead time "
                      f"{_join(list(dict.fromkeys(d['variant'] for d in sig_dt)))} differ"
                      f"{'s' if len({d['variant'] for d in sig_dt}) == 1 else ''} significantly "
                      f"on the same surfaces: the BRDF moves the bias through the photon rate "
                      f"at the detector (dead time), not through the geometry of the returns, on these "
                      f"surfaces.")
            elif zi <= z:
                s += f", within {z:g} s.e."
            else:
                s += ": the BRDF changes the bias even without dead time."
            out.append(s)
    return out
