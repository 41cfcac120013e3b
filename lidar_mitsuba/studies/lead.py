"""An open lead in sea ice (``scenes/lead.xml``): the water's glint against wind speed, the
detector's saturation and first-photon bias over the lead against the floe, and the freeboard
an ATL07-like surface finder (:mod:`lidar_mitsuba.products.atl07`) reads from the photons.

Three measurements, each checked against a closed form where one exists:

* :func:`glint`: the water's mean signal photons per shot (strong beam, ideal detector) for
  wind 0, 2, 5, 10 m/s, from a track *along* the lead (every footprint on water), beside
  Cox-Munk's ``nadir_return_weight x signal_photons`` (photons at the detector) and that times
  fill factor and PDE (detected), with the Poisson standard error of the detected count;
* :func:`saturation`: with each instrument's own dead time (the paper's default instrument,
  3 ns; ATLAS as flown, :meth:`Instrument.atlas`, 3.2 ns), on tracks along the lead and along a
  floe: detected photons per shot, the fraction of channels that fired, the fraction of shots
  whose every channel fired (saturation), and the mean elevation error of the signal photons
  (h - truth) with its standard error; beside the closed forms for a detector whose dead time
  outlasts the pulse (each channel counts the first of its Poisson(lambda) photons:
  ``C (1 - e^-lambda)`` detected, ``(1 - e^-lambda)^C`` saturated, and the first photon's mean
  height, :func:`first_photon_bias_m`);
* :func:`freeboard_retrieval`: a track across the lead for freeboards 0.1, 0.3, 0.5 m (calm
  water, a specular lead), run through the ATL07-like finder: the median freeboard of the floe
  segments against the true freeboard.

``run()`` gathers them into a JSON-able dict; ``plot(doc, path)`` draws it.
"""
from __future__ import annotations

import math
import pathlib
import time

import numpy as np

from ..products import atl07
from ..ground import water
from ..instrument import Instrument
from ..run import SimulationResult, simulate
from ..track import Track

SCENE = pathlib.Path(__file__).resolve().parents[2] / "scenes" / "lead.xml"
"""The lead scene: a lead ``lead_width_m`` (100 m) wide across the track at x = 0."""
WINDS_MPS = (0.0, 2.0, 5.0, 10.0)
FREEBOARDS_M = (0.1, 0.3, 0.5)
SNOW_WEIGHT = 1.154
"""The floes' Ward snow (rho_d 0.9, rho_s 0.05, alpha 0.3) at nadir, in plate units (traced:
9.43 of the plate's 8.17 photons), for the glint panel's reference line."""
NEAR_M = 5.0
"""Half a 150-photon segment over the lead (ATLAS strong beam: ~14 shots, 10 m) [m]."""
FLOE_X_M = 300.0
"""x of the track along the floe [m] (the east floe spans x = 50 .. 700 m)."""


#: ATLAS here keeps the Gaussian pulse: the dead-time closed forms this study checks
#: (first-photon bias, saturation) are for a Gaussian pulse without the receiver's tail,
#: echoes and afterpulses (``pulse_shape="atlas"``, lidar_mitsuba.detector.impulse)
ATLAS_GAUSSIAN = {"pulse_shape": "gaussian"}


def _simulate(*, wind_mps: float, freeboard_m: float = 0.3, instrument: Instrument,
              shots: int, seed: int, over: str | None = None) -> SimulationResult:
    """One run on the lead scene. ``over``: ``"lead"`` (a track along y through the lead's
    middle), ``"floe"`` (along y at x = :data:`FLOE_X_M`) or ``None`` (across the lead, the
    default track along +x)."""
    track = {None: Track(), "lead": Track(heading_deg=90.0),
             "floe": Track(heading_deg=90.0, offset_m=-FLOE_X_M)}[over]
    return simulate(scene_file=str(SCENE), params={"wind_speed_mps": float(wind_mps),
                                                   "freeboard_m": float(freeboard_m)},
                    instrument=instrument, shots=shots, seed=seed, track=track,
                    progress=False)


def glint(*, winds_mps=WINDS_MPS, shots: int = 1000, seed: int = 1,
          instrument: Instrument | None = None) -> list[dict]:
    """The water's return against wind speed, one row per wind (see the module docstring).

    Row keys: ``wind_mps``, ``mss`` (Cox-Munk), ``weight_closed`` (``nadir_return_weight``),
    ``mu_closed`` / ``mu_traced`` (photons per shot at the detector: closed form / the run's
    Poisson means), ``detected_closed`` / ``detected`` / ``detected_se`` (per shot, after
    fill factor and PDE; SE = sqrt(count) / shots, Poisson), ``z`` (detected - closed in SEs).
    """
    inst = instrument or Instrument(beam="strong", ideal_detector=True)
    n = water.WATER_INDEX_532 / water.AIR_IOR            # the plugin's relative index
    rows = []
    for u in winds_mps:
        res = _simulate(wind_mps=u, instrument=inst, shots=shots, seed=seed, over="lead")
        d = res.detections
        count = int(np.count_nonzero(d.is_signal))
        mss = water.cox_munk_mss(u)
        w = water.nadir_return_weight(n, mss)
        eff = inst.fill_factor * inst.pde
        closed, det = w * inst.signal_photons * eff, count / res.n_shots
        se = math.sqrt(max(count, 1)) / res.n_shots
        rows.append({"wind_mps": float(u), "mss": float(mss), "weight_closed": float(w),
                     "mu_closed": float(w * inst.signal_photons),
                     "mu_traced": float(np.mean(d.mean_photons_per_shot)),
                     "detected_closed": float(closed), "detected": float(det),
                     "detected_se": float(se), "z": float((det - closed) / se),
                     "shots": res.n_shots, "seconds": float(res.timings_s["total_s"])})
    return rows


def first_photon_bias_m(lam: float, sigma_h_m: float, *, statistic: str = "mean") -> float:
    """Height [m] above the truth of the photons a channel detects when it receives
    Poisson(``lam``) photons per shot with Gaussian heights of sd ``sigma_h_m`` and its dead
    time outlasts the pulse (only the first, i.e. highest, photon counts). The detected
    height's distribution is ``F(z) = (e^{-lam (1 - Phi(z / sigma_h))} - e^{-lam}) / (1 -
    e^{-lam})``; ``statistic``: its ``"mean"`` (``b - int_a^b F dz``) or ``"median"``
    (``F = 1/2``), numerically. 0 as lam -> 0; the mean is ~0.53 sigma_h at lam = 2."""
    if lam <= 0:
        return 0.0
    from scipy.special import ndtr
    z = np.linspace(-8.0, 8.0, 16001)
    cdf = (np.exp(-lam * (1.0 - ndtr(z))) - math.exp(-lam)) / -math.expm1(-lam)
    if statistic == "mean":
        return float(sigma_h_m * (z[-1] - np.trapezoid(cdf, z)))
    if statistic == "median":
        return float(sigma_h_m * np.interp(0.5, cdf, z))
    raise ValueError(f"statistic must be 'mean' or 'median' (got {statistic!r})")


def _shot_stats(res: SimulationResult) -> dict:
    """Detected photons, channels fired, saturation and the signal photons' elevation error
    of one run (every shot on one surface), beside the dead-time closed forms.

    Keys: ``mu_per_shot`` (the shots' mean Poisson mean at the detector), ``eligible_per_shot``
    (after fill factor and PDE: ``C lam``), ``detected_per_shot`` and ``detected_se`` (signal
    photons; SE of the mean over shots), ``detected_closed`` (``C (1 - e^-lam)`` under dead
    time, ``C lam`` without), ``channels_fired`` (mean fraction of channels with a signal
    detection), ``saturated`` (fraction of shots whose every channel detected a signal
    photon) and ``saturated_closed`` (``(1 - e^-lam)^C``), ``bias_m`` / ``bias_se_m`` (mean
    h - z_ref of the signal photons [m], SE clustered by shot), ``bias_closed_m``
    (:func:`first_photon_bias_m`, 0 without dead time), ``noise_per_shot`` (noise photons
    detected per shot, left out of the rest)."""
    inst, d = res.instrument, res.detections
    c, n_shots = inst.channels, res.n_shots
    sig = np.asarray(d.is_signal, bool)
    shot = d.shot[sig].astype(np.int64)
    per_shot = np.bincount(shot, minlength=n_shots)
    fired = np.bincount(np.unique(shot * c + d.channel[sig]) // c, minlength=n_shots)
    dh = res.dh_m[sig]
    # mean of h - truth over photons; its SE clusters the photons by shot (a shot's photons
    # share its dead channels), the ratio estimator's sqrt(sum r_s^2) / N
    bias = float(dh.mean()) if dh.size else float("nan")
    r = np.bincount(shot, weights=dh - bias, minlength=n_shots)
    se = float(math.sqrt(np.sum(r * r)) / max(dh.size, 1))
    mu = float(np.mean(d.mean_photons_per_shot))
    lam = mu * inst.fill_factor * inst.pde / c
    dead = inst.effective_dead_time_ns > 0
    fpb = first_photon_bias_m(lam, inst.ranging_sigma_m) if dead else 0.0
    return {"shots": n_shots, "mu_per_shot": mu, "eligible_per_shot": lam * c,
            "detected_per_shot": float(per_shot.mean()),
            "detected_se": float(per_shot.std(ddof=1) / math.sqrt(n_shots)),
            "detected_closed": float(c * -math.expm1(-lam) if dead else c * lam),
            "channels_fired": float(fired.mean() / c),
            "saturated": float(np.mean(fired == c)),
            "saturated_closed": float((-math.expm1(-lam)) ** c),
            "bias_m": bias, "bias_se_m": se, "bias_closed_m": fpb,
            "noise_per_shot": float(np.count_nonzero(~sig) / n_shots)}


def saturation(*, wind_mps: float = 0.0, shots: int = 1000, seed: int = 2,
               instruments: dict | None = None) -> list[dict]:
    """Saturation and first-photon bias over the lead and over the floe, one row per
    instrument and surface (keys: ``instrument``, ``surface``, ``dead_time_ns`` and
    :func:`_shot_stats`'s). ``instruments``: ``{name: Instrument}`` (default: the paper's
    strong beam with its 3 ns dead time, and ATLAS as flown, strong beam, 3.2 ns, with the
    Gaussian pulse the closed forms assume: :data:`ATLAS_GAUSSIAN`)."""
    instruments = instruments or {"paper": Instrument(beam="strong"),
                                  "atlas": Instrument.atlas("strong", **ATLAS_GAUSSIAN)}
    rows = []
    for name, inst in instruments.items():
        for k, over in enumerate(("lead", "floe")):
            res = _simulate(wind_mps=wind_mps, instrument=inst, shots=shots,
                            seed=seed + k, over=over)
            rows.append({"instrument": name, "surface": over, "wind_mps": float(wind_mps),
                         "dead_time_ns": float(inst.effective_dead_time_ns),
                         **_shot_stats(res)})
    return rows


def _lam(res: SimulationResult, shots: np.ndarray) -> float:
    """Mean photons per channel per shot after fill factor and PDE over ``shots`` (bool)."""
    inst = res.instrument
    return float(np.mean(res.detections.mean_photons_per_shot[shots]) * inst.fill_factor
                 * inst.pde / inst.channels)


def _freeboard_row(res: SimulationResult, fb: float, *, signal: str,
                   lead_width_m: float) -> dict:
    """One freeboard row (keys in :func:`freeboard_retrieval`)."""
    seg = atl07.segments_from_result(res, signal=signal)
    lead = atl07.flag_leads(seg)
    f = atl07.freeboard(seg, lead)
    x_seg = np.interp(seg.along_m, res.along_track_m, res.shot_x_m)
    over = np.abs(x_seg) < lead_width_m / 2.0                 # truth: centre over water
    near = np.abs(x_seg) < lead_width_m / 2.0 + NEAR_M
    floe = f[~lead & np.isfinite(f)]
    _, ssh, used = atl07.lead_heights(seg, lead)
    kept = np.concatenate([np.arange(a + 1, b - 1) if b - a >= 3 else np.arange(a, b)
                           for a, b in atl07.lead_runs(lead)] or [np.zeros(0, int)])
    ssh_se = (float(math.sqrt(np.mean(seg.h_se_m[kept] ** 2) / kept.size)) if kept.size
              else float("nan"))
    iqr = np.subtract(*np.percentile(floe, [75, 25])) if floe.size else float("nan")
    fse = float(atl07.MEDIAN_SE_FACTOR * iqr / atl07.IQR_PER_SIGMA / math.sqrt(max(floe.size, 1)))
    inst = res.instrument
    margin = lead_width_m / 2.0, 4.0 * inst.footprint_sigma_m
    lead_shots = np.abs(res.shot_x_m) < margin[0] - margin[1]
    floe_shots = np.abs(res.shot_x_m) > margin[0] + margin[1]
    closed = 0.0
    if inst.effective_dead_time_ns > 0:       # the median's differential first-photon bias
        closed = (first_photon_bias_m(_lam(res, floe_shots), inst.ranging_sigma_m,
                                      statistic="median")
                  - first_photon_bias_m(_lam(res, lead_shots), inst.ranging_sigma_m,
                                        statistic="median"))
    med = float(np.median(floe)) if floe.size else float("nan")
    return {"freeboard_true_m": float(fb), "freeboard_m": med,
            "freeboard_se_m": float(math.hypot(fse, ssh_se)), "error_m": med - float(fb),
            "error_closed_m": float(closed),
            "sea_surface_m": float(np.mean(ssh)) if ssh.size else None,
            "segments": len(seg), "leads": int(lead.sum()), "lead_runs": int(ssh.size),
            "lead_segments_used": int(used.sum()),
            "leads_over_water": int((lead & near).sum()), "water_segments": int(over.sum()),
            "rate_lead": float(np.median(seg.photon_rate[over])),
            "rate_floe": float(np.median(seg.photon_rate[~over])),
            "lam_lead": _lam(res, lead_shots), "lam_floe": _lam(res, floe_shots),
            "seconds": float(res.timings_s["total_s"])}


def freeboard_retrieval(*, freeboards_m=FREEBOARDS_M, wind_mps: float = 0.0,
                        shots: int = 1600, seed: int = 3,
                        instrument: Instrument | None = None, signal: str = "truth",
                        lead_width_m: float = 100.0) -> list[dict]:
    """The ATL07-like finder (:mod:`lidar_mitsuba.products.atl07`, default rule) on a track across the
    lead, one row per true freeboard (default instrument: ATLAS as flown, strong beam, with
    its dead time).

    Row keys: ``freeboard_true_m``; ``freeboard_m``, the median freeboard of the non-lead
    segments, and ``freeboard_se_m``, its SE (``sqrt(pi/2) (IQR / 1.349) / sqrt(n)``) and
    the sea surface's (the rms ``h_se_m`` of the lead segments used / sqrt(n)) in
    quadrature; ``error_m`` (retrieved - true); ``error_closed_m``, the error the dead time
    predicts: the median first-photon bias (:func:`first_photon_bias_m`) at the floe's
    photons per channel minus that at the lead's (0 for an ideal detector);
    ``sea_surface_m``; ``segments``, ``leads`` (flagged), ``lead_runs``,
    ``lead_segments_used``, ``leads_over_water`` (flagged segments whose centre is over the
    water or within :data:`NEAR_M` of it: an edge segment mostly of water may have its centre
    just outside), ``water_segments`` (segments whose centre is over the water);
    ``rate_lead`` / ``rate_floe`` (median photon rates, photons per shot); ``lam_lead`` /
    ``lam_floe`` (photons per channel per shot reaching the detector's channels, away from
    the edges).
    """
    inst = instrument or Instrument.atlas("strong", **ATLAS_GAUSSIAN)
    rows = []
    for k, fb in enumerate(freeboards_m):
        res = _simulate(wind_mps=wind_mps, freeboard_m=fb, instrument=inst, shots=shots,
                        seed=seed + k)
        rows.append(_freeboard_row(res, fb, signal=signal, lead_width_m=lead_width_m))
    return rows


def run(*, quick: bool = False) -> dict:
    """All three studies (``quick``: fewer shots) with their wall times [s]."""
    t0 = time.perf_counter()
    n = 400 if quick else 1000
    doc = {"scene": SCENE.name, "glint": glint(shots=n)}
    t1 = time.perf_counter()
    doc["saturation"] = saturation(shots=n)
    t2 = time.perf_counter()
    doc["freeboard"] = freeboard_retrieval(shots=1600)
    doc["freeboard_ideal"] = freeboard_retrieval(
        shots=1600, instrument=Instrument.atlas("strong", ideal_detector=True, **ATLAS_GAUSSIAN))
    t3 = time.perf_counter()
    doc["timings_s"] = {"glint": t1 - t0, "saturation": t2 - t1, "freeboard": t3 - t2,
                        "total": t3 - t0}
    return doc


def plot(doc: dict, path=None):
    """Three panels: glint against wind (traced vs Cox-Munk), the first-photon bias over
    lead and floe (measured vs closed form), the retrieved freeboard against the truth.
    Saves to ``path`` (PNG) when given; returns the Figure."""
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2), dpi=110)
    g = doc["glint"]
    u = np.array([r["wind_mps"] for r in g])
    ax = axes[0]
    uu = np.linspace(0.0, max(u.max(), 1.0), 200)
    w = water.nadir_return_weight(water.WATER_INDEX_532 / water.AIR_IOR, water.cox_munk_mss(uu))
    scale = g[0]["detected_closed"] / g[0]["weight_closed"]
    ax.plot(uu, w * scale, "-", color="tab:blue", label="Cox-Munk closed form")
    ax.errorbar(u, [r["detected"] for r in g], yerr=[2 * r["detected_se"] for r in g],
                fmt="o", color="k", label="simulated (2 SE)")
    ax.axhline(scale * SNOW_WEIGHT, color="0.5", ls=":", lw=1,
               label=f"Ward snow ({SNOW_WEIGHT:g} x plate)")
    ax.set(xlabel="wind speed [m/s]", ylabel="detected signal photons per shot",
           title="glint of the lead (ideal detector)", yscale="log")
    ax.yaxis.set_major_formatter(plt.FormatStrFormatter("%g"))
    ax.yaxis.set_minor_formatter(plt.FormatStrFormatter("%g"))
    ax.legend(fontsize=8)
    ax = axes[1]
    names = list(dict.fromkeys(r["instrument"] for r in doc["saturation"]))
    for k, name in enumerate(names):
        color = f"C{k + 2}"
        rows = [r for r in doc["saturation"] if r["instrument"] == name]
        xs = np.arange(len(rows)) + 3 * k
        ax.errorbar(xs, [100 * r["bias_m"] for r in rows],
                    yerr=[200 * r["bias_se_m"] for r in rows], fmt="o", color=color,
                    label=f"{name}: measured (2 SE)")
        ax.plot(xs, [100 * r["bias_closed_m"] for r in rows], "x", color=color, ms=9,
                label=f"{name}: first-photon closed form")
        for x, r in zip(xs, rows):
            ax.annotate(f"{r['surface']}\n{r['detected_per_shot']:.1f}/shot",
                        (x, 100 * r["bias_m"]), xytext=(0, -14), textcoords="offset points",
                        fontsize=7, ha="center", va="top")
    ax.set_xlim(-1, 3 * len(names) - 1)
    ax.set_ylim(min(0.0, ax.get_ylim()[0]) - 0.5, ax.get_ylim()[1] + 0.3)
    ax.set(ylabel="signal photons' h - truth [cm]", xticks=[],
           title="first-photon bias under dead time (wind 0)")
    ax.legend(fontsize=7)
    ax = axes[2]
    for key, color, label in (("freeboard", "tab:red", "ATLAS, dead time"),
                              ("freeboard_ideal", "tab:blue", "ATLAS, ideal detector")):
        rows = doc.get(key) or []
        fb = np.array([r["freeboard_true_m"] for r in rows])
        ax.errorbar(fb, [100 * r["error_m"] for r in rows],
                    yerr=[200 * r["freeboard_se_m"] for r in rows], fmt="o", color=color,
                    label=f"{label} (2 SE)")
        ax.plot(fb, [100 * r["error_closed_m"] for r in rows], "x", color=color, ms=9,
                label=f"{label}: differential first-photon bias")
    ax.axhline(0.0, color="k", ls=":", lw=1)
    ax.set(xlabel="true freeboard [m]", ylabel="retrieved - true freeboard [cm]",
           title="ATL07-like finder (150-photon segments, wind 0)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path)
        plt.close(fig)
    return fig
