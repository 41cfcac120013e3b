"""Clouds, fog, haze and blowing snow between the lidar and the ground.

Set-up. A flat Lambertian (albedo 0.9) ground plate (10 km wide) under a homogeneous layer
in a ``null``-bounded box (a "layer in the air", traced by ``mediapathlength`` with 8
vertices per path: :mod:`lidar_mitsuba.trace.materials`), built as a Python scene dict
(:func:`layer_scene`). The lidar is ATLAS's strong beam as this project models it
(:meth:`Instrument.atlas`: 16 channels, 3.2 ns non-paralyzable dead time, 1.5 ns pulse,
10.9 m footprint, 45 m field of view, ~63 photons per shot reaching the detector from the
0.9 plate, PDE 0.2 and fill factor 0.8), at night (a December site: no sun) so that the
noise does not matter; the signal photons alone are analysed (``is_signal``).

Task A (:func:`cloud_table`, :func:`cheap_model`): a water cloud (albedo 1, Henyey-Greenstein
g = 0.85) of optical depth tau, 1.0-1.5 km above the ground ("high") and 50-250 m (``low``,
as ``scenes/fog.xml``). Per tau, with dead time and with an ideal detector (same seed):

* detected signal photons per shot relative to clear sky, beside exp(-2 tau) (the unscattered
  part), and from a direct trace (:func:`trace_split`) the unscattered and the
  forward-scattered parts of the ground's return seen in the field of view;
* the mean elevation of the signal photons relative to clear sky, ``dh_total``, with its
  standard error (clustered by shot), split exactly into (i) the change of the first-photon
  bias, ``fpb_change = (dead - ideal)(tau) - (dead - ideal)(clear)``, and (ii) the
  forward-scatter delay, ``delay = ideal(tau) - ideal(clear)``.

"Model no more than a scene needs": a cheap model of the cloud, the clear-sky ground return
times exp(-2 tau) (no scattered light, no delay; run as the clear plate with the pulse
energy times exp(-2 tau)), against the full trace, per tau and cloud height: where its
elevation error exceeds 1 cm or its photon-count error exceeds 5 %.

Published comparison: Yang, Marshak, Varnai et al. 2011 (IEEE TGRS 49(12), 4910): the
clear-sky first-photon bias is about 6.5 cm; cloud attenuation lowers the photon count and
so the first-photon bias, forward scattering lengthens the paths; at cloud optical depth 1
the mean surface elevation is 4.0-6.0 cm lower than in clear sky. :func:`compare_yang` puts
our tau = 1 numbers beside theirs and says why they differ.

Task B (:func:`night_background`): a blowing-snow layer 0-50 m (g = 0.8) or a haze layer
0-500 m (g = 0.7, a typical aerosol value at 532 nm) of optical depth 0.05, 0.2, 0.5 (albedo
1) over the ground, seen by the weak beam (the real ATL03 subset is gt1l, weak): the layer's
own detected laser photons per shot more than 2 m above the ground, converted to the rate a
background estimate would read: photons per shot / window duration (2 W / c for a window of
W metres), for the instrument's 30 m range gate and for windows as long as the layer. Palm et
al. 2011 (JGR 116, D16123) and 2017 (The Cryosphere 11, 2555) describe blowing snow as
ICESat and CALIPSO observe it (layers mostly within a few hundred metres of the surface,
frequent over Antarctica and in winter); no number of theirs is used here.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..constants import C_M_PER_NS
from ..geotrack import Site
from ..instrument import ATLAS_PULSE_ENERGY_UJ, Instrument
from ..run import simulate
from ..trace.lazy import mi

NIGHT = Site(epoch_utc="2019-12-21T04:00:00Z")
"""The default site (northern Greenland) in the polar night: no solar background."""
TAUS = (0.0, 0.25, 0.5, 1.0, 2.0)
HIGH = (1000.0, 1500.0)
LOW = (50.0, 250.0)
CHEAP_HEIGHTS = (LOW, (300.0, 500.0), HIGH, (5000.0, 5500.0))
HALF_WIDTH_M = 5000.0
YANG_2011 = {"clear_fpb_m": 0.065, "dh_tau1_m": (-0.060, -0.040)}
CHEAP_BIAS_TOL_M, CHEAP_COUNT_TOL = 0.01, 0.05


def layer_scene(*, tau: float, base_m: float, top_m: float, albedo: float = 1.0,
                g: float = 0.85, ground_albedo: float = 0.9,
                half_width_m: float = HALF_WIDTH_M) -> dict:
    """A Lambertian ground plate at z = 0 under a homogeneous layer between ``base_m`` and
    ``top_m`` of vertical optical depth ``tau`` (no layer where ``tau`` is 0)."""
    T = mi.ScalarTransform4f
    d = {"type": "scene",
         "ground": {"type": "rectangle", "to_world": T().scale([half_width_m] * 2 + [1]),
                    "bsdf": {"type": "diffuse",
                             "reflectance": {"type": "uniform", "value": ground_albedo}}}}
    if tau > 0:
        h = top_m - base_m
        d["layer"] = {"type": "cube", "bsdf": {"type": "null"},
                      "to_world": T().translate([0, 0, (base_m + top_m) / 2])
                      .scale([0.96 * half_width_m, 0.96 * half_width_m, h / 2]),
                      "interior": {"type": "homogeneous", "sigma_t": tau / h,
                                   "albedo": albedo, "phase": {"type": "hg", "g": g}}}
    return d


def clustered_mean(x: np.ndarray, shot: np.ndarray, n_shots: int) -> tuple[float, float]:
    """Mean of ``x`` over photons and its standard error with the photons of a shot as one
    cluster (a ratio estimator: they share the shot's dead time). NaN without photons."""
    n = np.bincount(shot, minlength=n_shots).astype(float)
    if n.sum() < 2:
        return float("nan"), float("nan")
    s = np.bincount(shot, weights=x, minlength=n_shots)
    m = s.sum() / n.sum()
    r = s - m * n
    return float(m), float(math.sqrt(n_shots / (n_shots - 1) * np.sum(r * r)) / n.sum())


def _per_shot(counts: np.ndarray) -> tuple[float, float]:
    return float(counts.mean()), float(counts.std(ddof=1) / math.sqrt(counts.size))


def run_case(*, scene: dict, shots: int, seed: int, paths_per_shot: int = 128,
             instrument: Instrument | None = None, min_height_m: float | None = None) -> dict:
    """One simulate() run: signal photons per shot (detected, and the Poisson mean before the
    detector) and the mean elevation of the signal photons (h - z_ref) with standard errors;
    ``min_height_m``: also the signal photons per shot above that height (a layer's own)."""
    inst = instrument or Instrument.atlas("strong")
    t0 = time.perf_counter()
    res = simulate(instrument=inst, scene=scene, shots=shots, seed=seed,
                   paths_per_shot=paths_per_shot, progress=False, site=NIGHT,
                   keep_returns=False)
    d = res.detections
    sig = d.is_signal
    n, n_se = _per_shot(np.bincount(d.shot[sig], minlength=shots).astype(float))
    dh, dh_se = clustered_mean(res.dh_m[sig], d.shot[sig], shots)
    out = {"shots": shots, "signal_per_shot": n, "signal_per_shot_se": n_se,
           "mu_per_shot": float(np.mean(d.mean_photons_per_shot)), "dh_m": dh, "dh_se_m": dh_se,
           "run_out_shots": int(d.run_out_shots.size), "integrator": res.config["integrator"],
           "seconds": time.perf_counter() - t0}
    if min_height_m is not None:
        up = sig & (res.dh_m > min_height_m)
        counts = np.bincount(d.shot[up], minlength=shots).astype(float)
        out["above_per_shot"], out["above_per_shot_se"] = _per_shot(counts)
        out["above_dh_m"] = res.dh_m[up]
    return out


def trace_split(scene: dict, *, shots: int = 2000, paths_per_shot: int = 64, seed: int = 7,
                instrument: Instrument | None = None) -> dict:
    """The ground's return traced without pulse, detector or photons (weights per path, the
    clear plate = 1; the returns in the range gate): its unscattered part (first vertex on
    the ground), its forward-scattered part in the field of view (``scattered_up``: the part
    whose last vertex is in the layer, scattered on the way up), and the weighted mean
    elevation of all of it (an ideal detector's expected mean dh: the forward-scatter delay),
    with standard errors over shots."""
    inst = instrument or Instrument.atlas("strong")
    d = inst.integrator_dict(max_depth=8)
    d.update(type="mediapathlength", pulse_sigma_ns=0.0)
    r = mi.load_dict(d).trace(mi.load_dict(scene), shot_x_m=np.zeros(shots),
                              shot_y_m=np.zeros(shots), paths_per_shot=paths_per_shot,
                              seed=seed)
    h = inst.altitude_m - C_M_PER_NS * np.asarray(r.time_ns, np.float64) / 2.0
    # the ground's light in the range gate, whatever its last vertex: light reflected by
    # the ground and scattered forward in the cloud on its way up has its vertex there
    ground = np.abs(h) <= inst.range_gate_m / 2

    def part(keep):
        w = np.bincount(r.shot[keep], weights=r.weight[keep], minlength=shots) / paths_per_shot
        return _per_shot(w)
    direct, direct_se = part(ground & (r.depth == 1) & (r.z_m < 1.0))
    scat, scat_se = part(ground & ((r.depth > 1) | (r.z_m >= 1.0)))
    up, _ = part(ground & (r.z_m >= 1.0))
    w = np.where(ground, r.weight, 0.0)
    sw = np.bincount(r.shot, weights=w, minlength=shots)
    shw = np.bincount(r.shot, weights=w * h, minlength=shots)
    m = shw.sum() / sw.sum()
    res = shw - m * sw
    se = math.sqrt(shots / (shots - 1) * np.sum(res * res)) / sw.sum()
    return {"direct": direct, "direct_se": direct_se, "scattered": scat,
            "scattered_se": scat_se, "scattered_up": up, "delay_dh_m": float(m), "delay_dh_se_m": float(se)}


def _diff(a, b, key):
    return a[key + "_m"] - b[key + "_m"], math.hypot(a[key + "_se_m"], b[key + "_se_m"])


def cloud_table(*, base_m: float, top_m: float, taus=TAUS, shots: int = 4000,
                seed: int = 1, paths_per_shot: int = 128, g: float = 0.85,
                trace_shots: int = 2000) -> list[dict]:
    """One row per tau: photons relative to clear, exp(-2 tau), the traced unscattered and
    scattered parts, and ``dh_total = fpb_change + delay`` (see the module) with SEs [m]."""
    dead_inst, ideal_inst = Instrument.atlas("strong"), Instrument.atlas("strong",
                                                                         ideal_detector=True)
    runs = {}
    for tau in sorted(set(taus) | {0.0}):
        sc = layer_scene(tau=tau, base_m=base_m, top_m=top_m, g=g)
        runs[tau] = {k: run_case(scene=sc, shots=shots, seed=seed, paths_per_shot=paths_per_shot,
                                 instrument=i) for k, i in (("dead", dead_inst),
                                                            ("ideal", ideal_inst))}
        runs[tau]["split"] = trace_split(sc, shots=trace_shots, seed=seed + 100)
    c = runs[0.0]
    rows = []
    for tau in taus:
        r = runs[tau]
        dh, dh_se = _diff(r["dead"], c["dead"], "dh")
        delay, delay_se = _diff(r["ideal"], c["ideal"], "dh")
        fpb_t = r["dead"]["dh_m"] - r["ideal"]["dh_m"]
        fpb_c = c["dead"]["dh_m"] - c["ideal"]["dh_m"]
        ratio = r["dead"]["signal_per_shot"] / c["dead"]["signal_per_shot"]
        rows.append({
            "tau": tau, "base_m": base_m, "top_m": top_m, "shots": shots,
            "signal_per_shot": r["dead"]["signal_per_shot"],
            "signal_per_shot_se": r["dead"]["signal_per_shot_se"],
            "ideal_signal_per_shot": r["ideal"]["signal_per_shot"],
            "signal_vs_clear": ratio,
            "signal_vs_clear_se": ratio * math.hypot(
                r["dead"]["signal_per_shot_se"] / r["dead"]["signal_per_shot"],
                c["dead"]["signal_per_shot_se"] / c["dead"]["signal_per_shot"]),
            "mu_vs_clear": r["dead"]["mu_per_shot"] / c["dead"]["mu_per_shot"],
            "exp_minus_2tau": math.exp(-2 * tau),
            "traced_direct": r["split"]["direct"], "traced_direct_se": r["split"]["direct_se"],
            "traced_scattered": r["split"]["scattered"],
            "traced_scattered_se": r["split"]["scattered_se"],
            "traced_scattered_up": r["split"]["scattered_up"],
            "traced_delay_dh_m": r["split"]["delay_dh_m"] - c["split"]["delay_dh_m"],
            "traced_delay_dh_se_m": math.hypot(r["split"]["delay_dh_se_m"],
                                               c["split"]["delay_dh_se_m"]),
            "dh_dead_m": r["dead"]["dh_m"], "dh_ideal_m": r["ideal"]["dh_m"],
            "dh_total_m": dh, "dh_total_se_m": dh_se,
            "fpb_m": fpb_t, "fpb_change_m": fpb_t - fpb_c,
            "fpb_change_se_m": math.hypot(dh_se, delay_se),
            "delay_m": delay, "delay_se_m": delay_se,
            "run_out_shots": r["dead"]["run_out_shots"],
            "seconds": r["dead"]["seconds"] + r["ideal"]["seconds"]})
    return rows


def cheap_model(full_rows: list[dict], *, shots: int = 4000, seed: int = 1) -> list[dict]:
    """The cheap model (clear plate, pulse energy x exp(-2 tau), dead time) against the full
    trace's rows (:func:`cloud_table`, any heights): its photon-count and elevation errors
    (cheap - full) with SEs, and whether they pass 5 % and 1 cm."""
    e0 = ATLAS_PULSE_ENERGY_UJ["strong"]
    clear = layer_scene(tau=0.0, base_m=0.0, top_m=1.0)
    cheap = {}
    for tau in sorted({r["tau"] for r in full_rows}):
        inst = Instrument.atlas("strong", pulse_energy_uj=e0 * math.exp(-2 * tau))
        cheap[tau] = run_case(scene=clear, shots=shots, seed=seed + 17, instrument=inst)
    clear_dead = {(r["base_m"], r["top_m"]): r["dh_dead_m"] - r["dh_total_m"]
                  for r in full_rows if r["tau"] == 0.0}
    out = []
    for r in full_rows:
        if r["tau"] == 0.0:
            continue
        c = cheap[r["tau"]]
        full_dh = r["dh_dead_m"]
        count_err = c["signal_per_shot"] / r["signal_per_shot"] - 1
        count_se = (1 + count_err) * math.hypot(c["signal_per_shot_se"] / c["signal_per_shot"],
                                                r["signal_per_shot_se"] / r["signal_per_shot"])
        bias_err = c["dh_m"] - full_dh
        bias_se = math.hypot(c["dh_se_m"], r["dh_total_se_m"])
        out.append({"tau": r["tau"], "base_m": r["base_m"], "top_m": r["top_m"],
                    "cheap_signal_per_shot": c["signal_per_shot"],
                    "full_signal_per_shot": r["signal_per_shot"],
                    "count_error": count_err, "count_error_se": count_se,
                    "cheap_dh_m": c["dh_m"], "full_dh_m": full_dh,
                    "clear_dh_m": clear_dead[(r["base_m"], r["top_m"])],
                    "bias_error_m": bias_err, "bias_error_se_m": bias_se,
                    "count_ok": abs(count_err) <= CHEAP_COUNT_TOL,
                    "bias_ok": abs(bias_err) <= CHEAP_BIAS_TOL_M})
    return out


def night_background(*, kind: str = "snow", taus=(0.05, 0.2, 0.5), shots: int = 3000,
                     seed: int = 3, beam: str = "weak", paths_per_shot: int = 128,
                     min_height_m: float = 2.0) -> list[dict]:
    """A layer on the ground (``"snow"``: 0.1-50 m, g 0.8; ``"haze"``: 0.1-500 m, g 0.7;
    albedo 1): its own detected laser photons per shot more than ``min_height_m`` above the
    ground (the range gate widened to hold the whole layer) and the rates they make
    [Hz]: over the 30 m range gate (the part of the layer inside it), over the layer's
    height above ``min_height_m``, and over a 5 km window (the whole layer)."""
    top, g = {"snow": (50.0, 0.8), "haze": (500.0, 0.7)}[kind]
    gate_m = 2 * (top + 20.0)
    inst = Instrument.atlas(beam, range_gate_m=gate_m)
    gate30 = Instrument.atlas(beam).range_gate_m
    rows = []
    for tau in taus:
        sc = layer_scene(tau=tau, base_m=0.1, top_m=top, g=g)
        r = run_case(scene=sc, shots=shots, seed=seed, paths_per_shot=paths_per_shot,
                     instrument=inst, min_height_m=min_height_m)
        dh = r.pop("above_dh_m")
        n = r["above_per_shot"]
        in30 = float(np.sum(dh <= gate30 / 2)) / shots
        def rate(count, window_m):
            return count / (2 * window_m / C_M_PER_NS * 1e-9)
        rows.append({"kind": kind, "beam": beam, "tau": tau, "top_m": top, "g": g,
                     "above_per_shot": n, "above_per_shot_se": r["above_per_shot_se"],
                     "above_in_30m_gate_per_shot": in30,
                     "rate_30m_gate_hz": rate(in30, gate30),
                     "rate_30m_gate_se_hz": rate(r["above_per_shot_se"], gate30)
                     * (in30 / n if n > 0 else 1.0),
                     "rate_layer_hz": rate(n, top - min_height_m),
                     "rate_5km_hz": rate(n, 5000.0),
                     "ground_signal_per_shot": r["signal_per_shot"] - n,
                     "seconds": r["seconds"]})
    return rows


def compare_yang(rows: list[dict]) -> dict:
    """Our tau = 1 numbers (high cloud) beside Yang et al. 2011's, and why they differ."""
    clear = next(r for r in rows if r["tau"] == 0.0)
    one = next(r for r in rows if r["tau"] == 1.0)
    lo, hi = YANG_2011["dh_tau1_m"]
    return {
        "ours_clear_fpb_m": clear["fpb_m"], "yang_clear_fpb_m": YANG_2011["clear_fpb_m"],
        "ours_dh_tau1_m": one["dh_total_m"], "ours_dh_tau1_se_m": one["dh_total_se_m"],
        "ours_fpb_change_m": one["fpb_change_m"], "ours_delay_m": one["delay_m"],
        "ours_traced_delay_m": one["traced_delay_dh_m"],
        "yang_dh_tau1_m": [lo, hi],
        "within_yang": bool(lo <= one["dh_total_m"] <= hi),
        "why": (
            "Both say the same thing: the cloud lowers the surface, by a smaller first-photon "
            "bias and by forward-scatter delays. The size differs because (1) our clear-sky "
            "first-photon bias is smaller than their 6.5 cm (ATLAS's strong beam here spreads "
            "~10 detected photons over 16 channels with a 3.2 ns dead time; the fewer photons "
            "per channel, the smaller the bias), and the part of the cloud effect that is the "
            "lost bias can be no larger than the clear-sky bias; (2) our receiver sees 22.5 m "
            "around the shot (45 m field of view), so from a cloud 1-1.5 km up only light "
            "scattered within ~20 mrad of nadir comes back, which is late by millimetres; "
            "the delay that remains comes from rare light scattered forward in the cloud on "
            "its way up (large weight, heavy tail); (3) a Henyey-Greenstein g = 0.85 phase "
            "function has a weaker forward peak than a Mie droplet phase function, which "
            "keeps more light near nadir and within the field of view; (4) one homogeneous "
            "slab 1-1.5 km up and a flat Lambertian ground: their cloud geometry and surface "
            "differ (not reproduced here)."),
    }


def run(*, quick: bool = False) -> dict:
    """Task A (high and low cloud, the cheap model over cloud heights, the comparison with
    Yang et al. 2011) and task B (night background from blowing snow and haze)."""
    t0 = time.perf_counter()
    shots, ppp, tshots = (1500, 128, 1000) if quick else (6000, 512, 4000)
    heights = (LOW, HIGH) if quick else CHEAP_HEIGHTS
    tables = {}
    for base, top in heights:
        tables[f"{base:g}-{top:g} m"] = cloud_table(base_m=base, top_m=top, shots=shots,
                                                    paths_per_shot=ppp, trace_shots=tshots)
    all_rows = [r for rows in tables.values() for r in rows]
    cheap = cheap_model(all_rows, shots=shots)
    bg_shots = 1000 if quick else 6000
    background = {k: night_background(kind=k, shots=bg_shots) for k in ("snow", "haze")}
    return {"set_up": {"instrument": "Instrument.atlas('strong'), night", "shots": shots,
                       "paths_per_shot": ppp, "trace_shots": tshots, "quick": quick,
                       "cloud": "albedo 1, HG g 0.85", "ground": "Lambertian 0.9 plate"},
            "clouds": tables, "cheap_model": cheap,
            "cheap_model_fails": [r for r in cheap if not (r["count_ok"] and r["bias_ok"])],
            "yang_2011": compare_yang(tables[f"{HIGH[0]:g}-{HIGH[1]:g} m"]),
            "night_background": background,
            "night_background_needed_hz": 15e3 - 2.6e3,
            "seconds": time.perf_counter() - t0}


def plot(doc: dict, path) -> None:
    """Photons vs clear, the elevation change and its two causes, the cheap model's errors
    and the night background rates, in one figure saved to ``path``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 4, figsize=(18, 4.2))
    for name, rows in doc["clouds"].items():
        tau = np.array([r["tau"] for r in rows])
        ax[0].errorbar(tau, [r["signal_vs_clear"] for r in rows],
                       [r["signal_vs_clear_se"] for r in rows], marker="o", label=name)
        line = ax[1].errorbar(tau, [100 * r["dh_total_m"] for r in rows],
                              [100 * r["dh_total_se_m"] for r in rows], marker="o",
                              label=f"{name}: total")
        ax[1].plot(tau, [100 * r["fpb_change_m"] for r in rows], "--",
                   color=line[0].get_color(), label=f"{name}: first-photon bias")
        ax[1].plot(tau, [100 * r["traced_delay_dh_m"] for r in rows], ":",
                   color=line[0].get_color(), label=f"{name}: delay (traced)")
        ch = [r for r in doc["cheap_model"] if f"{r['base_m']:g}-{r['top_m']:g} m" == name]
        ax[2].errorbar([r["tau"] for r in ch], [100 * r["bias_error_m"] for r in ch],
                       [100 * r["bias_error_se_m"] for r in ch], marker="o", label=name)
    t = np.linspace(0, 2, 50)
    ax[0].plot(t, np.exp(-2 * t), "k:", label="exp(-2 tau)")
    ax[0].set(xlabel="cloud optical depth", ylabel="detected signal / clear", yscale="log")
    ax[1].axhspan(-6, -4, color="0.85", label="Yang et al. 2011, tau 1")
    ax[1].set(xlabel="cloud optical depth", ylabel="mean elevation - clear [cm]")
    ax[2].axhspan(-1, 1, color="0.9")
    ax[2].set(xlabel="cloud optical depth", ylabel="cheap model - full [cm]")
    for kind, rows in doc["night_background"].items():
        ax[3].plot([r["tau"] for r in rows], [r["rate_30m_gate_hz"] / 1e3 for r in rows],
                   "o-", label=f"{kind}: 30 m gate")
        ax[3].plot([r["tau"] for r in rows], [r["rate_layer_hz"] / 1e3 for r in rows],
                   "s--", label=f"{kind}: layer height")
    ax[3].axhline(doc["night_background_needed_hz"] / 1e3, color="k", ls=":",
                  label="15 - 2.6 kHz")
    ax[3].set(xlabel="layer optical depth", ylabel="equivalent background [kHz]",
              yscale="log")
    for a in ax:
        a.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ------------------------------------------------------------- the cheap kernel in runs
KERNEL_CASES = ((0.25, 1000.0, 1500.0), (1.0, 1000.0, 1500.0), (2.0, 1000.0, 1500.0),
                (0.5, 300.0, 500.0), (1.0, 300.0, 500.0), (0.5, 50.0, 250.0),
                (1.0, 50.0, 250.0), (0.5, 5.0, 60.0))
"""(tau, base, top) of the kernel chart: high, mid and low clouds, and fog in the gate."""


def _signal_stats(res) -> dict:
    d = res.detections
    sig = d.is_signal
    n = res.n_shots
    counts = np.bincount(d.shot[sig], minlength=n).astype(float)
    dh, dh_se = clustered_mean(res.dh_m[sig], d.shot[sig], n)
    q = np.quantile(res.dh_m[sig], [0.05, 0.5, 0.95]) if sig.any() else [np.nan] * 3
    return {"signal_per_shot": float(counts.mean()),
            "signal_per_shot_se": float(counts.std(ddof=1) / math.sqrt(n)),
            "dh_m": dh, "dh_se_m": dh_se, "dh_q05_m": float(q[0]), "dh_q50_m": float(q[1]),
            "dh_q95_m": float(q[2])}


def kernel_vs_full(*, cases=KERNEL_CASES, shots: int = 3000, seed: int = 1,
                   ground_albedo: float = 0.9, beam: str = "strong") -> list[dict]:
    """The cloud as a kernel on the clear ground (``simulate(cloud=...)``,
    :mod:`lidar_mitsuba.atmosphere.cloud_kernel`) against the full media trace of the same
    layer over the same Lambertian plate (``simulate(scene=...)``), ATLAS at night with its
    dead time: detected signal per shot, mean elevation and its 5/50/95 % quantiles. A row
    passes where the count agrees within 5 % and the mean within 1 cm (beyond 2 SE)."""
    from ..atmosphere import cloud_kernel as ck
    from ..atmosphere.cloud_layer import Cloud
    inst = Instrument.atlas(beam)
    rows = []
    for tau, base, top in cases:
        c = Cloud.water(tau, base, top)
        t0 = time.perf_counter()
        full = simulate(instrument=inst, scene=ck.layer_scene_dict(c, ground_albedo=ground_albedo),
                        shots=shots, seed=seed, progress=False, site=NIGHT, keep_returns=False)
        t1 = time.perf_counter()
        plate = ck.layer_scene_dict(Cloud.water(0.0, base, top), ground_albedo=ground_albedo)
        cheap = simulate(instrument=inst, scene=plate, cloud=c, shots=shots, seed=seed + 1,
                         progress=False, site=NIGHT, keep_returns=False)
        t2 = time.perf_counter()
        f, k = _signal_stats(full), _signal_stats(cheap)
        tab = ck.table_for(c, inst)
        count_err = k["signal_per_shot"] / f["signal_per_shot"] - 1
        count_se = math.hypot(k["signal_per_shot_se"] / k["signal_per_shot"],
                              f["signal_per_shot_se"] / f["signal_per_shot"],
                              tab.forward_se / tab.total)
        dh_err, dh_se = k["dh_m"] - f["dh_m"], math.hypot(k["dh_se_m"], f["dh_se_m"])
        rows.append({"tau": tau, "base_m": base, "top_m": top, "ground_albedo": ground_albedo,
                     "forward_share": tab.forward / tab.total, "full": f, "kernel": k,
                     "count_error": count_err, "count_error_se": count_se,
                     "dh_error_m": dh_err, "dh_error_se_m": dh_se,
                     "ok": bool(abs(count_err) <= CHEAP_COUNT_TOL + 2 * count_se
                                and abs(dh_err) <= CHEAP_BIAS_TOL_M + 2 * dh_se),
                     "full_s": t1 - t0, "kernel_s": t2 - t1, "table_s": tab.seconds})
    return rows


def plot_kernel(rows: list[dict], path) -> None:
    """The kernel against the full trace: count and mean-elevation errors per case."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 3, figsize=(14, 4))
    names = [f"{r['base_m']:g}-{r['top_m']:g} m\ntau {r['tau']:g}" for r in rows]
    x = np.arange(len(rows))
    ax[0].errorbar(x, [100 * r["count_error"] for r in rows],
                   [200 * r["count_error_se"] for r in rows], fmt="o")
    ax[0].axhspan(-100 * CHEAP_COUNT_TOL, 100 * CHEAP_COUNT_TOL, color="0.9")
    ax[0].set(ylabel="kernel / full - 1, signal per shot [%] (2 SE)")
    ax[1].errorbar(x, [100 * r["dh_error_m"] for r in rows],
                   [200 * r["dh_error_se_m"] for r in rows], fmt="o")
    ax[1].axhspan(-100 * CHEAP_BIAS_TOL_M, 100 * CHEAP_BIAS_TOL_M, color="0.9")
    ax[1].set(ylabel="kernel - full, mean elevation [cm] (2 SE)")
    for key, mk in (("full", "o"), ("kernel", "x")):
        ax[2].plot(x, [100 * r[key]["dh_m"] for r in rows], mk, label=f"{key}: mean")
        ax[2].plot(x, [100 * r[key]["dh_q05_m"] for r in rows], mk, alpha=0.4,
                   label=f"{key}: 5 %")
    ax[2].set(ylabel="elevation - truth [cm]")
    ax[2].legend(fontsize=7)
    for a in ax:
        a.set_xticks(x, names, fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
