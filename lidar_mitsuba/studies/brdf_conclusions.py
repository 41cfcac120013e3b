"""The BRDF comparison's findings in words (:func:`conclusions`), computed from
:func:`~lidar_mitsuba.studies.brdf_variants.sweep` rows so that each sentence is true of the
numbers given.

In the study's data flow this reads the rows (through :mod:`~lidar_mitsuba.studies.brdf_rows`)
beside the figure (:mod:`~lidar_mitsuba.studies.brdf_plots`). One function per finding, each
returning its sentence (or None when the rows cannot support it): per beam
:func:`_flat_plate_brightness`, :func:`_slope_falloff`, :func:`_fractal_falloff`,
:func:`_ward_normalisations`, :func:`_bias_against_reference`,
:func:`_precision_against_reference`; then :func:`_without_dead_time` over the
ideal-detector rows. Import :func:`conclusions` from
:mod:`~lidar_mitsuba.studies.brdf_variants`.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from .brdf_rows import relative_to, surface_label


@dataclass(frozen=True)
class _Beam:
    """One beam's rows with the paper's detector, and what every finding reads of them."""
    tag: str                    # "[strong beam] ", the sentences' prefix
    mine: list[dict]            # the beam's rows (every variant, every surface)
    rel: list[dict]             # relative_to(mine) without the reference's own
    names: list[str]            # the variants other than the reference, in row order


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
    said_fractal = False        # the traced weights do not depend on the beam: say it once
    for beam in dict.fromkeys(r["beam"] for r in rows):
        mine = [r for r in rows if r["beam"] == beam and not r["ideal_detector"]]
        rel = [d for d in relative_to(mine, reference=reference) if d["variant"] != reference]
        if not rel:
            continue
        b = _Beam(tag=f"[{beam} beam] ", mine=mine, rel=rel,
                  names=list(dict.fromkeys(d["variant"] for d in rel)))
        found = [_flat_plate_brightness(b, reference, z), _slope_falloff(b, reference)]
        if not said_fractal:
            found.append(_fractal_falloff(b, reference))
            said_fractal = found[-1] is not None
        found += [_ward_normalisations(b, reference, z), _bias_against_reference(b, reference, z),
                  _precision_against_reference(b, reference)]
        out += [s for s in found if s]
    if ideal_rows:
        s = _without_dead_time(rows, ideal_rows, reference, z)
        if s:
            out.append(s)
    return out


def _loc(r: dict) -> tuple:
    """Surface and beam of a row or of a :func:`relative_to` dict."""
    fractal = r["kind"] == "fractal"
    return ("fractal" if fractal else "plane", r["slope_deg"], r["p"] if fractal else None,
            r["beam"])


def _fmt_surface(r: dict) -> str:
    return surface_label(r) if r["kind"] == "fractal" else (
        "the flat plate" if r["slope_deg"] == 0 else f"the {r['slope_deg']:g}° slope")


def _join(parts: Sequence[str]) -> str:
    parts = list(parts)
    return parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]


def _most_significant_bias(rel: Sequence[dict]) -> dict:
    """The :func:`relative_to` dict whose bias difference is the most standard errors."""
    return max(rel, key=lambda d: abs(d["bias_diff_m"]) / max(d["bias_diff_se_m"], 1e-12))


def _flat_plate_brightness(b: _Beam, reference: str, z: float) -> str | None:
    """1. Return weight and detected photons on the flat plate against ``reference`` (variants
    with the same numbers named together), and which of them dead time compresses."""
    flat = [d for d in b.rel if d["kind"] != "fractal" and d["slope_deg"] == 0]
    flat_ref = [r for r in b.mine if r["variant"] == reference and r["kind"] != "fractal"
                and r["slope_deg"] == 0]
    if not (flat and flat_ref):
        return None
    ref = flat_ref[0]
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
    s = (f"{b.tag}On the flat plate, against the {reference} 0.9 plate "
         f"({ref['photons_per_shot']:.2f} ± {ref['photons_per_shot_se']:.2f} detected "
         f"photons/shot): {'; '.join(parts)}.")
    squeezed = [d for d in flat if d["weight_ratio"] - d["photons_ratio"]
                > z * d["photons_ratio_se"]]
    if squeezed:
        s += (f" Dead time compresses the brightest return"
              f"{'s' if len(squeezed) > 1 else ''} "
              f"({_join([d['variant'] for d in squeezed])}): fewer photons are detected "
              f"than the return weight predicts.")
    return s


def _slope_falloff(b: _Beam, reference: str) -> str | None:
    """2. How the return weight falls from 0° to the steepest slope, per variant, and where a
    variant brighter than ``reference`` at nadir becomes dimmer."""
    planes = [r for r in b.mine if r["kind"] != "fractal"]
    slopes = sorted({r["slope_deg"] for r in planes})
    if not (len(slopes) > 1 and slopes[0] == 0):
        return None
    lo, hi = slopes[0], slopes[-1]
    w = {(r["variant"], r["slope_deg"]): r["return_weight"] for r in planes}
    falls = sorted(((w[(n, hi)] / w[(n, lo)], n) for n in [reference] + b.names
                    if (n, lo) in w and (n, hi) in w), reverse=True)
    parts = [f"{n} ×{f:.2f}" for f, n in falls]
    s = (f"{b.tag}From 0° to {hi:g}° of slope the return weight falls to {_join(parts)} "
         f"of its nadir value (cos {hi:g}° = {math.cos(math.radians(hi)):.2f}).")
    for n in b.names:
        ratio = [(sd, w[(n, sd)] / w[(reference, sd)]) for sd in slopes
                 if (n, sd) in w and (reference, sd) in w]
        if len(ratio) > 1 and ratio[0][1] > 1 and ratio[-1][1] < 1:
            k = next(i for i, (_, v) in enumerate(ratio) if v < 1)
            (s0, v0), (s1, v1) = ratio[k - 1], ratio[k]
            cross = s0 + (v0 - 1) / (v0 - v1) * (s1 - s0)
            s += (f" {n} is brighter than {reference} below about {cross:.0f}° and "
                  f"dimmer beyond.")
    return s


def _fractal_falloff(b: _Beam, reference: str) -> str | None:
    """2b. The return weight against ``reference``'s from the roughest fractal to the
    smoothest."""
    fr = [r for r in b.mine if r["kind"] == "fractal"]
    ps = sorted({r["p"] for r in fr})
    if len(ps) <= 1:
        return None
    w = {(r["variant"], r["p"]): r["return_weight"] for r in fr}
    lo, hi = ps[0], ps[-1]
    parts = [f"{n} ×{w[(n, lo)] / w[(reference, lo)]:.2f} → ×"
             f"{w[(n, hi)] / w[(reference, hi)]:.2f}" for n in b.names
             if all(k in w for k in ((n, lo), (n, hi), (reference, lo), (reference, hi)))]
    if not parts:
        return None
    return (f"{b.tag}On the fractal tiles, from p = {lo:g} (roughest) to p = {hi:g}, "
            f"the return weight against {reference}'s goes: {_join(parts)}.")


def _ward_normalisations(b: _Beam, reference: str, z: float) -> str | None:
    """3. The Ward normalisations against one another: their largest return-weight ratio, and
    their largest difference in photons/shot, bias or precision in standard errors."""
    bsdf_of = {r["variant"]: r.get("bsdf", "") for r in b.mine}
    wards = [n for n in [reference] + b.names if bsdf_of.get(n) == "ward"]
    if len(wards) <= 1:
        return None
    by = {(r["variant"], _loc(r)): r for r in b.mine}
    keys = list(dict.fromkeys(_loc(r) for r in b.mine))
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
    return (f"{b.tag}The {len(wards)} Ward normalisations ({_join(wards)}) differ in "
            f"return weight by at most {100 * wmax:.1f}% on these surfaces, and "
            f"their photons/shot, biases and precisions {verdict}.")


def _bias_against_reference(b: _Beam, reference: str, z: float) -> str:
    """4. Which variants' bias differs from ``reference``'s by more than ``z`` s.e., on how
    many surfaces and by how much, the largest difference of the others, and the range of
    ``reference``'s own bias."""
    sig = {}
    for d in b.rel:
        if abs(d["bias_diff_m"]) > z * d["bias_diff_se_m"]:
            sig.setdefault(d["variant"], []).append(d)
    n_surf = len({_loc(r) for r in b.mine if r["variant"] == reference})
    if sig:
        parts = []
        for n, ds in sig.items():
            lo_cm = 100 * min(d["bias_diff_m"] for d in ds)
            hi_cm = 100 * max(d["bias_diff_m"] for d in ds)
            rng_txt = f"{lo_cm:+.1f} cm" if len(ds) == 1 else f"{lo_cm:+.1f} to {hi_cm:+.1f} cm"
            parts.append(f"{n} on {len(ds)} of {n_surf} surfaces ({rng_txt})")
        rest = [n for n in b.names if n not in sig]
        s = (f"{b.tag}Elevation bias differs from {reference}'s by more than {z:g} s.e. for "
             f"{_join(parts)}.")
        if rest:
            big = _most_significant_bias([d for d in b.rel if d["variant"] in rest])
            s += (f" {_join(rest)} never do (largest: {100 * big['bias_diff_m']:+.2f} ± "
                  f"{100 * big['bias_diff_se_m']:.2f} cm, {big['variant']} on "
                  f"{_fmt_surface(big)}).")
    else:
        big = _most_significant_bias(b.rel)
        s = (f"{b.tag}No variant's elevation bias differs from {reference}'s by more than "
             f"{z:g} s.e. on any surface (largest: {100 * big['bias_diff_m']:+.2f} ± "
             f"{100 * big['bias_diff_se_m']:.2f} cm, {big['variant']} on "
             f"{_fmt_surface(big)}).")
    bias_ref = [r["bias_m"] for r in b.mine if r["variant"] == reference]
    return s + (f" {reference}'s own bias ranges over {100 * min(bias_ref):+.2f} to "
                f"{100 * max(bias_ref):+.2f} cm on these surfaces.")


def _precision_against_reference(b: _Beam, reference: str) -> str:
    """5. The largest relative difference in precision from ``reference``'s, against the
    range of ``reference``'s precision over the surfaces."""
    worst = max(b.rel, key=lambda d: abs(d["std_ratio"] - 1))
    zs = max(abs(d["std_ratio"] - 1) / max(d["std_ratio_se"], 1e-12) for d in b.rel)
    std_ref = [r["std_m"] for r in b.mine if r["variant"] == reference]
    dev = abs(worst["std_ratio"] - 1)
    spread = max(std_ref) / min(std_ref) - 1
    s = (f"{b.tag}Precision is within {100 * dev:.1f}% of {reference}'s for every variant "
         f"and surface (largest: {worst['variant']} on {_fmt_surface(worst)}; the largest "
         f"difference is {zs:.1f} s.e.), while across the surfaces it ranges from "
         f"{100 * min(std_ref):.1f} to {100 * max(std_ref):.1f} cm")
    return s + (": the terrain, not the BRDF, sets it." if spread > 5 * dev and dev < 0.1
                else ".")


def _without_dead_time(rows: Sequence[dict], ideal_rows: Sequence[dict], reference: str,
                       z: float) -> str | None:
    """6. The largest bias difference from ``reference`` without dead time, and whether the
    variants that differ significantly with dead time do so on the same surfaces."""
    rel_i = [d for d in relative_to(ideal_rows, reference=reference)
             if d["variant"] != reference]
    if not rel_i:
        return None
    big = _most_significant_bias(rel_i)
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
        return s + (f", within {z:g} s.e., whereas with dead time "
                    f"{_join(list(dict.fromkeys(d['variant'] for d in sig_dt)))} differ"
                    f"{'s' if len({d['variant'] for d in sig_dt}) == 1 else ''} significantly "
                    f"on the same surfaces: the BRDF moves the bias through the photon rate "
                    f"at the detector (dead time), not through the geometry of the returns, "
                    f"on these surfaces.")
    if zi <= z:
        return s + f", within {z:g} s.e."
    return s + ": the BRDF changes the bias even without dead time."
