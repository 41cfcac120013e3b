"""Rows of the BRDF comparison (:mod:`lidar_mitsuba.studies.brdf_variants`): one simulation
reduced to a row (:func:`row_of`), and what the rows are read with: :func:`select`,
:func:`relative_to` (each row against the reference variant's on the same surface) and
:func:`format_table`.

In the study's data flow, :func:`~lidar_mitsuba.studies.brdf_variants.sweep` makes the rows,
and :mod:`~lidar_mitsuba.studies.brdf_conclusions` and :mod:`~lidar_mitsuba.studies.brdf_plots`
read them through these functions. A row is a dict of JSON-able numbers.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..run import SimulationResult

#: Numeric fields of a row that :func:`sweep` fills (all floats; see :func:`row_of`).
ROW_FIELDS = ("photons_per_shot", "photons_per_shot_se", "return_weight", "bias_m", "bias_se_m",
              "std_m", "std_se_m")


def row_of(res: SimulationResult) -> dict:
    """Photons per shot, bias and precision of one run's signal photons, with standard errors.

    Returns:
        A dict of floats (NaN where undefined), and ``n_photons`` (int) and ``shots`` (int):

        * photons_per_shot: detected signal photons / shots [photons/shot].
        * photons_per_shot_se: its standard error, std(per-shot counts, ddof=1) / sqrt(shots).
        * return_weight: footprint-averaged return weight, mean over shots of the Poisson mean
          arrivals / ``signal_photons`` (1 for the flat Lambertian 0.9 plate at nadir;
          before fill factor, PDE and dead time) [-].
        * bias_m, bias_se_m: mean of h - z_ref [m] and its standard error std / sqrt(n) [m].
        * std_m, std_se_m: precision, the standard deviation of h - z_ref [m], and its standard
          error from the photons' kurtosis (std / sqrt(2 (n - 1)) for normal residuals) [m].
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


def surface_label(row: dict) -> str:
    """How a row's surface is named in tables: ``flat``, ``slope 20°`` or ``fractal p=1.8``."""
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
        out.append(f"{surface_label(r):<15}{r['variant']:<23}{r['return_weight']:>7.3f}"
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

    * photons_ratio, photons_ratio_se: photons per shot / the reference's [-];
    * weight_ratio: return weight / the reference's [-];
    * bias_diff_m, bias_diff_se_m: bias - the reference's bias [m];
    * std_ratio, std_ratio_se: precision / the reference's precision [-].

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
