"""Sea ice as the real subset sees it: the tails of the surface returns about each 20 m
segment's median, real against a ladder of floe models (nothing fitted).

The real weak beam (``twin.REAL_SUBSET``: gt1l, 14 Oct 2018, snow-covered Arctic sea ice at
night) has more of its signal photons far below and far above their segment's median than a
twin over flat snow. Here the twin's floe is modelled step by step, each step's parameters
taken from published values (:data:`FLOE`, with their sources) and never adjusted to the real
tails:

1. ``flat Ward snow``: the current twin (``validate.real_twin``);
2. ``flat + snow volume 300 um``: the issue's ``--snow-grain-um 300`` (semi-infinite pack);
3. ``floe``: rough sea ice at the footprint scale (a periodic fractal of published rms
   roughness) under a finite snowpack (a wind slab over depth hoar, the October depth of a
   published climatology) over a bare-ice base;
4. ``ridged floe``: the same with the rms roughness of deformed (ridged) ice;
5. ``sea_ice``, ``sea_ice_nansen``: rough sea ice whose relief at the footprint scale has the
   published statistics (rms height and correlation length of airborne laser surveys,
   :mod:`~lidar_mitsuba.ground.sea_ice_surface`: 16 cm and 9 cm rms, 25 m; the 16 cm one with
   the laser profiles' ridge sails, :mod:`~lidar_mitsuba.ground.sea_ice_ridges`) under the
   flat twin's Ward snow, ``sea_ice_gauss``: the 16 cm one without ridges (Gaussian), and
   ``sea_ice_snow``: the 16 cm one with ridges under the floe's snowpack.

Every twin is written to ATL03 and read back by :func:`~lidar_mitsuba.products.atl03.rates.atl03_rates`, the code that
reads the real file, so both sides' residuals come from the same classifier output, the same
segments and the same medians. :func:`tails` counts them beyond +-20 cm with binomial
standard errors; :func:`run` puts the rows side by side with a verdict each; :func:`plot`
draws the histograms.
"""
from __future__ import annotations

import math
import pathlib
import tempfile
import time

import numpy as np

from .. import granule, twin
from ..ground import sea_ice_surface, snow, terrain
from ..ground.surface import SurfaceSpec, sea_ice_spec
from ..products.atl03.rates import atl03_rates

from .realism_shape import FAR_CUT_M, TAIL_M as CUT_M, tails  # noqa: E402,F401 (one home)

#: The floe model's choices and where they come from. Each is a *choice* among published
#: values, made before the runs and never adjusted to the real tails. Where we quote from
#: memory and could not re-read the source here we say so ("recalled").
FLOE = {
    "roughness_rms_m": {
        "value": 0.09,
        "source": "Beckers et al. 2015, Ann. Glaciol. 56(69): mean sea-ice surface roughness "
                  "(sd of relative surface elevation, airborne laser scanner) 0.09 m in the "
                  "Nansen Basin north of Svalbard (0.16 m in Fram Strait); the Nansen Basin "
                  "value for the undeformed floe (choice)"},
    "ridged_rms_m": {
        "value": 0.16,
        "source": "Beckers et al. 2015: 0.16 m, Fram Strait's more deformed ice (choice: "
                  "the ridged rung)"},
    "fractal_p": {
        "value": 1.8,
        "source": "choice: 2-D amplitude filter 1/f^1.8 (Hurst exponent 0.8; a profile "
                  "spectrum f^-2.6), within the 0.7-0.9 Hurst exponents we recall from "
                  "airborne-lidar sea-ice topography (recalled, not re-read here); the "
                  "project's default"},
    "tile_m": {
        "value": 512.0, "grid_m": 0.5,
        "source": "choice: the published rms is a sd over hundreds of metres of scanner "
                  "swath, so the tile carrying it is 512 m (0.5 m grid: footprint sigma / 5.4)"},
    "snow_depth_m": {
        "value": 0.18,
        "source": "Warren et al. 1999, J. Climate 12, 1814: October snow depth on Arctic "
                  "multiyear ice, ~15-20 cm in the basin-mean climatology (recalled, not "
                  "re-read here); 18 cm chosen"},
    "slab": {
        "thickness_m": 0.05, "grain_radius_um": 130.0, "density_kg_m3": 350.0,
        "source": "autumn wind slab on Arctic sea ice: density ~350 kg/m^3 (Sturm et al. "
                  "2002, JGR 107(C10), 8047, SHEBA); specific surface area ~25 m^2/kg "
                  "(MOSAiC snow pits, Macfarlane et al. 2023, Sci. Data 10, 398; recalled), "
                  "optical radius 3 / (917 SSA) = 130 um; 5 cm thick (choice)"},
    "hoar": {
        "grain_radius_um": 330.0, "density_kg_m3": 250.0,
        "source": "depth hoar under it: density ~250 kg/m^3 (Sturm et al. 2002), SSA ~10 "
                  "m^2/kg (Macfarlane et al. 2023; recalled): optical radius 330 um"},
    "ice_albedo_532": {
        "value": 0.65,
        "source": "bare cold first-year sea ice, visible spectral albedo ~0.6-0.7 at 500-550 "
                  "nm (Grenfell & Perovich 1984, JGR 89, 3573; Perovich 1996, CRREL "
                  "Monograph 96-1; recalled). Under 18 cm of snow it hardly matters: the "
                  "slab's transport mean free path is ~1 mm"},
    "snow_optics": {
        "source": "snow.snow_from_grains defaults (natural snow: g 0.80, B 1.6, alpha_ice "
                  "0.04 /m; docs/guide/snow.md)"},
}


# ------------------------------------------------------------------------------ counting
# ------------------------------------------------------------------------------ the ladder
def _fractal(rms_m: float, terrain_seed: int) -> SurfaceSpec:
    """The floe's fractal tile with the published rms (the relief that gives it, for this
    terrain seed: a unit conversion, not a fit)."""
    tile = FLOE["tile_m"]
    p = FLOE["fractal_p"]["value"]
    hf = terrain.fractal(p=p, size_m=tile["value"], grid_m=tile["grid_m"], relief_m=1.0,
                         seed=terrain_seed)
    relief = rms_m / float(np.std(hf.z_m))
    return SurfaceSpec(kind="fractal", p=p, relief_m=relief, size_m=tile["value"],
                       grid_m=tile["grid_m"], terrain_seed=int(terrain_seed))


def floe_snow() -> snow.SnowVolume:
    """The floe's snowpack: a wind slab over depth hoar, finite, over bare ice (:data:`FLOE`)."""
    slab, hoar = FLOE["slab"], FLOE["hoar"]
    return snow.snow_from_grains(
        grain_radius_um=hoar["grain_radius_um"], density_kg_m3=hoar["density_kg_m3"],
        depth_m=FLOE["snow_depth_m"]["value"], base_albedo=FLOE["ice_albedo_532"]["value"],
        crust_m=slab["thickness_m"], crust_grain_um=slab["grain_radius_um"],
        crust_density_kg_m3=slab["density_kg_m3"])


def rough_sea_ice(preset: str, terrain_seed: int, *, ridges: str | None = None) -> SurfaceSpec:
    """Rough sea ice of a published roughness preset
    (:data:`~lidar_mitsuba.ground.sea_ice_surface.PRESETS`: rms height, correlation length and
    ridge sails from airborne laser surveys; ``ridges`` overrides the preset's), the
    ``--surface sea_ice`` tile (1024 m, 1 m grid)."""
    return sea_ice_spec(preset, ridges=ridges, terrain_seed=int(terrain_seed))


def _rms(preset: str) -> float:
    """The rms height [m] of a published sea-ice roughness preset."""
    return sea_ice_surface.PRESETS[preset]["rms_m"]


#: the ladder: name -> (what it is, its rms roughness [m] or None for flat, its snow volume,
#: and for the ``sea_ice`` rungs the surface of terrain seed k)
MODELS = {
    "flat": ("flat Ward snow (the current twin)", None, lambda: None),
    "snow300": ("flat + snow volume 300 um, 350 kg/m^3, semi-infinite (the issue's)", None,
                lambda: snow.snow_from_grains(grain_radius_um=300.0)),
    "floe": ("floe: fractal sea ice, 9 cm rms, under 18 cm snow (5 cm wind slab 130 um over "
             "depth hoar 330 um) over bare ice 0.65", FLOE["roughness_rms_m"]["value"],
             floe_snow),
    "ridged": ("ridged floe: the floe with 16 cm rms", FLOE["ridged_rms_m"]["value"], floe_snow),
    "sea_ice": ("rough sea ice: 16 cm rms, 25 m correlation length (Beckers et al. 2015, Fram "
                "Strait; IceBridge ATM) with ridge sails (Castellani et al. 2014), Ward snow",
                _rms("fram_strait"), lambda: None, lambda k: rough_sea_ice("fram_strait", k)),
    "sea_ice_gauss": ("rough sea ice: 16 cm rms, 25 m, Gaussian (no ridges), Ward snow",
                      _rms("fram_strait"), lambda: None,
                      lambda k: rough_sea_ice("fram_strait", k, ridges="none")),
    "sea_ice_nansen": ("rough sea ice: 9 cm rms, 25 m (Beckers et al. 2015, Nansen Basin)",
                       _rms("nansen_basin"), lambda: None,
                       lambda k: rough_sea_ice("nansen_basin", k)),
    "sea_ice_snow": ("rough sea ice (16 cm, 25 m, ridges) under the floe's 18 cm of snow",
                     _rms("fram_strait"),
                     floe_snow, lambda k: rough_sea_ice("fram_strait", k)),
}


def twin_tails(name: str, *, real=None, seed: int = 1, repeats: int = 1,
               shots: int | None = None, out_dir=None, cut_m: float = CUT_M) -> dict:
    """One rung of the ladder: the real subset's twin over model ``name`` (:data:`MODELS`),
    ``repeats`` times (seeds ``seed + k``; a rough floe also gets terrain seed ``k``: a new
    patch of the same ice), each written to ATL03 and read back by
    :func:`~lidar_mitsuba.products.atl03.rates.atl03_rates`; their residuals pooled into :func:`tails`."""
    what, rms, make_snow, *rough = MODELS[name]
    real = twin.read(twin.REAL_SUBSET) if real is None else real
    out = pathlib.Path(out_dir or tempfile.mkdtemp(prefix="sea_ice_"))
    out.mkdir(parents=True, exist_ok=True)
    vol = make_snow()
    resid, per_shot, seg_rms, t0 = [], [], [], time.perf_counter()
    for k in range(int(repeats)):
        surface = (rough[0](k) if rough else SurfaceSpec(kind="flat") if rms is None
                   else _fractal(rms, k))
        g = twin.simulate_over_surface(real, surface=surface, seed=seed + k, shots=shots,
                                       progress=False, snow=vol)
        path = out / f"{name}_{k}_ATL03.h5"
        granule.write_atl03(g, path)
        r = atl03_rates(path, g.beams[0].beam.name)
        resid.append(r["residuals_m"])
        per_shot.append(r["signal_per_shot"])
        seg_rms.append(_segment_rms_m(g.beams[0].result))
    resid = np.concatenate(resid)
    return {"name": name, "model": what, "rms_m": rms,
            "snow": None if vol is None else vol.config(), "repeats": int(repeats),
            "shots": shots, "seconds": time.perf_counter() - t0,
            "signal_per_shot": float(np.mean(per_shot)),
            "surface_segment_rms_m": float(np.sqrt(np.mean(np.square(seg_rms)))),
            "spread_robust_m": float(1.4826 * np.median(np.abs(resid))) if resid.size else None,
            "tails": tails(resid, cut_m=cut_m), "residuals_m": resid}


def _segment_rms_m(result, segment_m: float = 20.0) -> float:
    """The modelled surface's rms height under the shot centres about each 20 m along-track
    segment's median: the relief the segment median leaves in the residuals [m]."""
    along = np.asarray(result.along_track_m, np.float64)
    z = np.asarray(result.surface_z_m, np.float64)
    seg = np.floor((along - along[0]) / segment_m).astype(np.int64)
    dev = np.empty_like(z)
    for k in np.unique(seg):
        sel = seg == k
        dev[sel] = z[sel] - np.median(z[sel])
    return float(np.sqrt(np.mean(dev ** 2)))


# ------------------------------------------------------------------------------ verdicts
_WHY = {
    ("below", "short"): "too few late photons: the receiver's tail (ex-Gaussian, "
                        "detector/impulse.py) has estimated strengths, and the real file "
                        "carries more subsurface delay or a longer instrument tail",
    ("below", "long"): "too many late photons: the snow volume delays more than the real "
                       "floe does (coherent backscatter, which favours short paths, is not "
                       "modelled; finer or denser surface snow would shorten the paths)",
    ("above", "short"): "too few early photons: only surface relief puts light above the "
                        "segment's median, and this model leaves less of it inside a 20 m "
                        "segment (column 'surface rms in 20 m') than the real ice has (a "
                        "p = 1.8 fractal of the published rms: a few cm; the sea_ice rungs: "
                        "the published rms and correlation length, the 9 cm one smoother; "
                        "sea_ice_gauss: no ridge sails, whose sparse relief skews the "
                        "published elevations positively)",
    ("above", "long"): "too many early photons: the modelled relief is rougher at the "
                       "footprint scale than the real floe",
}


def verdict(model: dict, real: dict) -> dict:
    """Each tail of ``model`` (a :func:`tails` dict) against ``real``'s: the difference in
    units of the combined SE, ``agrees`` within 2 SE, else which way and the likely cause."""
    out, notes = {}, []
    for side in ("below", "above"):
        diff = model[side] - real[side]
        se = math.hypot(model[f"{side}_se"], real[f"{side}_se"])
        z = diff / se if se > 0 else float("inf")
        ok = abs(z) <= 2.0
        out[f"{side}_z"] = z
        out[f"{side}_agrees"] = bool(ok)
        if not ok:
            notes.append(f"{side}: {_WHY[(side, 'short' if diff < 0 else 'long')]}")
    both = out["below_agrees"] and out["above_agrees"]
    out["verdict"] = ("agrees (both tails within 2 SE)" if both else
                      "disagrees (" + ", ".join(s for s in ("below", "above")
                                               if not out[f"{s}_agrees"]) + ")")
    out["notes"] = notes
    return out


# ------------------------------------------------------------------------------ the study
def run(*, quick: bool = False, seed: int = 1, out_dir=None,
        models=("flat", "snow300", "floe", "ridged", "sea_ice", "sea_ice_gauss",
                "sea_ice_nansen", "sea_ice_snow")) -> dict:
    """The real subset's tails and each model's beside them, with verdicts and run times.
    ``quick``: one twin per model (1128 shots); otherwise four (new seeds and, on the rough
    floes, new patches of ice), pooled."""
    out = pathlib.Path(out_dir or tempfile.mkdtemp(prefix="sea_ice_"))
    t0 = time.perf_counter()
    real = twin.read(twin.REAL_SUBSET)
    r = atl03_rates(twin.REAL_SUBSET, real.beams[0].beam.name)
    doc = {"quick": bool(quick), "seed": int(seed), "cut_m": CUT_M, "floe": FLOE,
           "real": {"file": twin.REAL_SUBSET.name, "signal_per_shot": r["signal_per_shot"],
                    "spread_robust_m": r["spread_robust_m"],
                    "tails": tails(r["residuals_m"]), "residuals_m": r["residuals_m"]},
           "rows": []}
    for name in models:
        row = twin_tails(name, real=real, seed=seed, repeats=1 if quick else 4,
                         out_dir=out / name)
        row.update(verdict(row["tails"], doc["real"]["tails"]))
        doc["rows"].append(row)
    doc["seconds"] = time.perf_counter() - t0
    return doc


def format_table(doc: dict) -> str:
    """The rows as a markdown table (real first)."""
    def pct(t, side):
        return f"{100 * t[side]:.1f} +- {100 * t[side + '_se']:.1f}"
    rt = doc["real"]["tails"]
    lines = ["| data | photons | below -20 cm [%] | above +20 cm [%] | above +30 cm [%] | "
             "robust sd [cm] | surface rms in 20 m [cm] | signal/shot | time [s] | verdict |",
             "|---|---|---|---|---|---|---|---|---|---|",
             f"| real ({doc['real']['file']}) | {rt['n']} | {pct(rt, 'below')} | "
             f"{pct(rt, 'above')} | {pct(rt, 'above_far')} | "
             f"{100 * doc['real']['spread_robust_m']:.1f} | | "
             f"{doc['real']['signal_per_shot']:.2f} | | |"]
    for row in doc["rows"]:
        t = row["tails"]
        lines.append(f"| {row['model']} | {t['n']} | {pct(t, 'below')} ({row['below_z']:+.1f} "
                     f"SE) | {pct(t, 'above')} ({row['above_z']:+.1f} SE) | "
                     f"{pct(t, 'above_far')} | "
                     f"{100 * row['spread_robust_m']:.1f} | "
                     f"{100 * row['surface_segment_rms_m']:.1f} | {row['signal_per_shot']:.2f} | "
                     f"{row['seconds']:.0f} | {row['verdict']} |")
    notes = [f"- **{row['name']}**: " + "; ".join(row["notes"]) for row in doc["rows"]
             if row["notes"]]
    return "\n".join(lines + [""] + notes)


def plot(doc: dict, path) -> None:
    """The residual histograms (real and each model, density, log y) with the +-cut marked."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    cut = doc.get("cut_m", CUT_M)
    bins = np.linspace(-1.0, 1.0, 81)
    fig, ax = plt.subplots(figsize=(8, 4.8))
    rt = doc["real"]["tails"]
    ax.hist(doc["real"]["residuals_m"], bins=bins, density=True, histtype="step", color="k",
            lw=2.0, label=f"real: {100 * rt['below']:.1f} % below, {100 * rt['above']:.1f} % "
                          "above")
    colours = ("tab:red", "tab:orange", "tab:blue", "tab:green", "tab:purple", "tab:brown",
               "tab:pink", "tab:olive")
    for row, c in zip(doc["rows"], colours):
        t = row["tails"]
        ax.hist(row["residuals_m"], bins=bins, density=True, histtype="step", color=c, lw=1.2,
                label=f"{row['name']}: {100 * t['below']:.1f} %, {100 * t['above']:.1f} %")
    for x in (-cut, cut):
        ax.axvline(x, color="k", ls="--", lw=0.8)
    ax.set_yscale("log")
    ax.set_xlabel("signal photon height - 20 m segment median [m]")
    ax.set_ylabel("density [1/m]")
    ax.set_title(f"{doc['real']['file']}: tails beyond +-{100 * cut:.0f} cm, real vs floe "
                 "models (nothing fitted)", fontsize=10)
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
