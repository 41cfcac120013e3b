"""The realism matrix (``lidar-mitsuba validate --real FILE_OR_DIR ...``): every beam of every
real ICESat-2 file (ATL03, ATL06, ATL07, ATL08; :mod:`lidar_mitsuba.products.real`) against
what the model predicts there, nothing fitted to the file.

For each beam: the measured background (clear and cloudy segments apart) against the
model's (:func:`lidar_mitsuba.night.background_terms`: dark counts, sunlight, the air's and a
cloud's backscatter, the laser's own photons the product's signal finder leaves), the signal
photons per shot on clear segments against a short simulation of the file's own shots over
the surface a user would choose knowing only the product (:data:`PRODUCT_SURFACES`; sea ice
of the central Arctic pack with the relief ``validate``'s twin has,
:func:`~lidar_mitsuba.studies.realism_inputs.product_surface`) through
the detector's dead time (or, with ``signal_shots=0``, the lidar equation alone), the
strong:weak ratios of each beam pair, the spread and tails of ATL03's surface photons (with
issue 41's verdict on them, :mod:`~lidar_mitsuba.studies.realism_shape`), the
saturation fractions, and a verdict with its reason. Cloudy segments are predicted with the
cloud the file's own flags imply (:func:`~lidar_mitsuba.studies.realism_inputs.implied_cloud`:
its apparent reflectance's optical depth, ATL09's ``msw_flag``'s height) or the one given.

The model is the package's: :meth:`~lidar_mitsuba.instrument.Instrument.atlas` with the
beam's energy (the file's ``tx_pulse_energy`` or ATLAS's history), the sun from the file,
:func:`~lidar_mitsuba.radiometry.shot_radiometry` and :func:`~lidar_mitsuba.twin.simulate_over_surface`:
improvements to any of them show up here unchanged.
"""
from __future__ import annotations

import dataclasses
import json
import pathlib
import time

import numpy as np

from ..constants import ALTITUDE_M, REFERENCE_ALBEDO
from . import json_safe

BACKGROUND_AGREES = (0.5, 2.0)
"""Predicted / measured background within this range agrees (issue 41's criterion)."""
SIGNAL_AGREES = (0.7, 1.4)
"""Predicted / measured signal photons per shot within this range agrees (issue 41)."""

from .realism_inputs import (BLOWING_SNOW_TOP_M, LAYER_BASE_M, LAYER_THICKNESS_M,  # noqa: F401
                             PRODUCT_SURFACES, cloud_alternatives,
                             equation_outside_fraction, ice_sheet_snow,
                             implied_cloud, layer_heights_m, pair_clouds, pair_flags,
                             product_surface, ratio_words, read_files, sea_ice_snow,
                             snow_delay, sunlit_albedo)
from .realism_curve import background_curve  # noqa: E402  (the figure's curves)
from .realism_files import (HDF5_SUFFIXES, PACKAGE_DATA, _forest_twins,  # noqa: E402,F401
                            _whole, hdf5_files, labels, real_files)
from .realism_shape import (SEGMENT_M, TAIL_M, TAIL_WINDOW_M,  # noqa: E402,F401
                            atl03_shape as _atl03_shape, segment_residuals_m, shape_stats,
                            shape_verdict)

# ------------------------------------------------------------------------------ measured
def _median(a, mask=None) -> float | None:
    if a is None:
        return None
    a = np.asarray(a, np.float64)
    if mask is not None:
        a = a[mask]
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else None


def measured(rf, rb) -> dict:
    """What the file measured on a beam: background and signal on clear and cloudy
    segments, saturation, and (ATL03) the spread and tails of its surface photons."""
    clear = rb.clear if rb.clear is not None else np.ones(rb.n_segments, bool)
    out = {"segments": rb.n_segments, "clear_fraction": float(np.mean(clear)),
           "cloud_flags": rb.clear is not None,
           "background_clear_hz": _median(rb.background_hz, clear),
           "background_cloudy_hz": _median(rb.background_hz, ~clear),
           "signal_clear": _median(rb.signal_per_shot, clear),
           "signal_cloudy": _median(rb.signal_per_shot, ~clear),
           "full_sat_fract": _mean(rb.full_sat_fract), "near_sat_fract": _mean(rb.near_sat_fract),
           "solar_elevation_deg": _median(rb.solar_elevation_deg), "notes": dict(rb.notes)}
    if rf.product == "ATL03":
        out.update(_atl03_shape(rf.path, rb.name))
    return out


def _mean(a) -> float | None:
    if a is None:
        return None
    a = np.asarray(a, np.float64)
    a = a[np.isfinite(a)]
    return float(a.mean()) if a.size else None


# ------------------------------------------------------------------------------ predicted
def beam_energy(rb) -> tuple[float, str]:
    """A real beam's pulse energy [uJ] and its source (:func:`~lidar_mitsuba.twin.beam_energy_uj`)."""
    from ..twin import beam_energy_uj
    e = _median(rb.pulse_energy_uj)
    return beam_energy_uj(rb.strength, e, float(np.nanmedian(rb.delta_time_s)))


def beam_instrument(rb, *, range_m: float):
    """ATLAS as flown for a real beam ``rb``: its strength, its energy (the file's or the
    history's), the spacecraft at ``range_m`` above the surface."""
    from ..instrument import Instrument
    energy, _ = beam_energy(rb)
    return Instrument.atlas(rb.strength, pulse_energy_uj=float(energy),
                            altitude_m=float(range_m))


def _range_m(rb) -> float:
    h = np.nan_to_num(rb.surface_h_m, nan=_median(rb.surface_h_m) or 0.0)
    if rb.altitude_m is None:
        return float(ALTITUDE_M)
    r = rb.altitude_m - h
    return float(np.nanmedian(r)) if np.isfinite(r).any() else float(ALTITUDE_M)


def radiometric_signal(inst, *, z_m: float, surface: dict) -> float:
    """Detected signal photons per shot by the lidar equation alone (no dead time): the
    instrument's reference-plate photons, the air above ``z_m``, the surface's nadir weight
    (Ward snow: ``(rho_d / pi + rho_s / (4 pi alpha^2)) / (0.9 / pi)``; water:
    :func:`~lidar_mitsuba.ground.water.nadir_return_weight`), fill factor and PDE."""
    from ..ground.surface import SurfaceSpec
    from ..radiometry import shot_radiometry
    rad = shot_radiometry(inst, delta_time_s=np.zeros(1), z_m=np.array([z_m]), albedo=0.9,
                          solar_elevation_deg=np.array([-90.0]), solar_azimuth_deg=np.zeros(1))
    if surface.get("water") is not None:
        from ..ground.water import WATER_INDEX_532 as n, cox_munk_mss, nadir_return_weight
        weight = float(nadir_return_weight(n, cox_munk_mss(surface["water"])))
    else:
        w = SurfaceSpec(kind="flat")
        weight = (w.rho_d / np.pi + w.rho_s / (4 * np.pi * w.alpha ** 2)) / (REFERENCE_ALBEDO
                                                                           / np.pi)
    return float(inst.signal_photons * rad.signal_scale[0] * weight * inst.pde
                 * inst.fill_factor)


def simulated(twin_granule, name: str, *, surface: dict, shots: int, seed: int,
              spans_m) -> dict:
    """A short simulation of the beam's first ``shots`` shots over the product's surface
    (:func:`~lidar_mitsuba.studies.realism_inputs.product_surface`: flat, or the rough sea ice
    of its ``relief``): detected signal per shot through dead time, the spread and tails of
    its surface photons about each 20 m segment's median (:func:`segment_residuals_m`; with
    the snow's delay, and over rough sea ice under ``without_snow_delay`` without it, as
    ``validate``'s sea-ice twin has them), saturation as our
    ATL03 writes it, the fraction of signal photons outside each of ``spans_m`` (the leak
    term as it was, kept for comparison) and ``photons``, what ATL03's count of the leak
    needs (:func:`~lidar_mitsuba.night.atl03_leak`; not for the report). Over snow, the
    surface's diffuse share of its photons is lowered by the pack's volume return
    (:func:`~lidar_mitsuba.ground.snow.delay.delay_heights`, seeded ``seed + 1``) before
    all three."""
    import warnings
    from .. import twin
    from ..ground.surface import SurfaceSpec
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        g = twin.simulate_over_surface(twin_granule,
                                       surface=surface.get("relief") or SurfaceSpec(kind="flat"),
                                       beams=name, shots=shots, seed=seed,
                                       progress=False, water_wind_mps=surface.get("water"))
    res = g.beams[0].result
    det = res.detections
    sig = det.is_signal
    dh = res.dh_m[sig]
    pack, share = snow_delay(surface)
    if pack is not None:                 # the snow's volume return, later (ground.snow.delay)
        from ..ground.snow import delay
        dh = delay.delay_heights(dh, pack, share=share, rng=np.random.default_rng(seed + 1))
    n = res.n_shots
    surface_events = np.bincount(det.shot[res.signal_conf >= 2], minlength=n)
    ch = res.instrument.channels
    out = {"shots": n, "signal_per_shot": float(sig.sum() / n),
           "full_sat_fract": float(np.mean(surface_events >= ch)),
           "near_sat_fract": float(np.mean((surface_events >= np.ceil(0.75 * ch))
                                           & (surface_events < ch)))}
    h = res.h_m.copy()                   # every photon, the laser's moved by the snow's delay
    h[sig] += dh - res.dh_m[sig]
    along = res.along_track_m[det.shot[sig]] - res.along_track_m[0]
    out.update(shape_stats(segment_residuals_m(h[sig], along)))
    if pack is not None and surface.get("relief") is not None:   # as validate's rough twin:
        out["without_snow_delay"] = shape_stats(   # no snow delay
            segment_residuals_m(res.h_m[sig], along))
    out["outside_fraction"] = outside_fraction(dh, spans_m)
    from ..detector.impulse import response_of
    from ..trace.stream import gate_heights_m
    out["photons"] = {"shot": det.shot, "h_m": h, "is_signal": sig, "n_shots": n,
                      "gate_center_h_m": gate_heights_m(res.z_ref_m),
                      "range_gate_m": float(res.instrument.range_gate_m),
                      "afterpulse_probability":
                          response_of(res.instrument).afterpulse_probability}
    return out


def outside_fraction(dh_m, spans_m) -> np.ndarray:
    """For each span [m], the fraction of heights ``dh_m`` farther than half of it from their
    median."""
    d = np.sort(np.abs(np.asarray(dh_m, np.float64) - np.median(dh_m))) if np.size(dh_m) \
        else np.zeros(1)
    spans = np.atleast_1d(np.asarray(spans_m, np.float64))
    return 1.0 - np.searchsorted(d, spans / 2.0, side="right") / d.size


def _band(rb):
    """The beam's histogram band (:class:`~lidar_mitsuba.night.HistogramBand`): the file's
    height, top and removed span where it gives them, the polar defaults otherwise."""
    from .. import night
    band = night.HistogramBand(from_file=rb.band_height_m is not None)
    for attr, key in (("height_m", "band_height_m"), ("top_above_surface_m",
                                                      "band_top_above_surface_m"),
                      ("signal_span_m", "signal_span_m")):
        v = getattr(rb, key)
        if v is not None and np.isfinite(v).any():
            setattr(band, attr, v[np.isfinite(v)])
    return band


def band_top_m(rb) -> float:
    """The top of the beam's histogram band above the surface [m] (:func:`_band`'s median)."""
    return float(np.nanmedian(np.atleast_1d(_band(rb).top_above_surface_m)))


def _signal(out: dict, rb, twin_granule, inst, band, surface: dict, z: float, *,
            signal_shots: int, seed: int, forest: dict | None):
    """The beam's signal into ``out`` (the forest twin's, a short simulation's or the lidar
    equation's: :func:`predicted`) and ``(outside fraction, simulated photons for the leak or
    None, signal per shot for the leak or None)``."""
    f_out = photons = leak_signal = None
    if forest is not None:                # the forest twin's (studies.realism_forest)
        out.update({k: forest[k] for k in ("surface", "signal_per_shot", "signal_from",
                                           "forest_shots")}, forest_twin=True,
                   surface_missing=False)
        leak_signal = forest["signal_truth"]
        f_out = equation_outside_fraction(inst, band.signal_span_m, surface=surface)
    elif signal_shots > 0 and twin_granule is not None:
        sim = simulated(twin_granule, rb.name, surface=surface, shots=signal_shots, seed=seed,
                        spans_m=band.signal_span_m)
        photons = sim.pop("photons")
        out.update({k: v for k, v in sim.items() if k != "outside_fraction"})
        f_out = sim["outside_fraction"]
        if rb.signal_span_m is not None and np.isfinite(rb.signal_span_m).any():
            # ATL03 gives each row's span: where its own finder cut (ours, with ATL03's rule,
            # run on its photons, cuts 0.88 m where it cut 1.0: docs/physics/night-floor.md);
            # the laser photons outside it and their afterpulses are the leak
            f_out = f_out + photons["afterpulse_probability"]
            photons = None
            out["outside_fraction"] = float(np.nanmedian(f_out))
        out["leak_from"] = ("the file's span" if photons is None else
                            "our signal finder on the simulated photons")
    else:
        out["signal_per_shot"] = radiometric_signal(inst, z_m=z, surface=surface)
        out["signal_from"] = "lidar equation (no dead time)"
        f_out = equation_outside_fraction(inst, band.signal_span_m, surface=surface)
    return f_out, photons, leak_signal


def predicted(rb, twin_granule, *, signal_shots: int, seed: int, cloud=None,
              forest: dict | None = None, alternatives: list | None = None) -> dict:
    """The model's background (term by term), signal and shape for one beam (``twin_granule``:
    the file's twin, for ``signal_shots > 0``; ``forest``: a forest row's signal and surface
    from its twin, :func:`~lidar_mitsuba.studies.realism_forest.prediction`, in place of the
    flat surface's simulation); with a ``cloud``
    (:class:`~lidar_mitsuba.atmosphere.cloud_layer.Cloud`), also its cloudy segments' background and
    signal (ESTIMATE: the clear signal dimmed by the cloud's two-way transmission; through dead
    time that overstates the loss dead time takes from the dimmer return, without it, with
    ``signal_shots=0``, it ignores dead time; the cloud's forward scattering is the cloud
    model's, not here); with ``alternatives``
    (:func:`~lidar_mitsuba.studies.realism_inputs.cloud_alternatives`, ``cloud`` first), the
    same for each other cloud the file allows (``cloud_alternatives``)."""
    from .. import night
    surface = product_surface(rb)
    range_m = _range_m(rb)
    inst = beam_instrument(rb, range_m=range_m)
    z = float(np.clip(_median(rb.surface_h_m) or 0.0, -500.0, 9000.0))
    band = _band(rb)
    out = {"surface": surface["name"], "surface_missing": bool(surface.get("missing")),
           **({"surface_why": surface["relief_why"]} if "relief_why" in surface else {}),
           "range_m": range_m, "pulse_energy_uj": float(inst.link_budget.pulse_energy_uj),
           "energy_source": beam_energy(rb)[1], "band_from_file": band.from_file}
    f_out, photons, leak_signal = _signal(out, rb, twin_granule, inst, band, surface, z,
                                          signal_shots=signal_shots, seed=seed,
                                          forest=forest)
    t = rb.delta_time_s
    # the geometric sun from the file's time and place (the file's solar_elevation is the
    # apparent one: twin.model_sun)
    ok = np.isfinite(t) & np.isfinite(rb.lat_deg) & np.isfinite(rb.lon_deg)
    sun, az = np.full(t.size, np.nan), np.zeros(t.size)
    if ok.any():
        from ..twin import model_sun
        sun[ok], az[ok] = model_sun(rb.lat_deg[ok], rb.lon_deg[ok], t[ok])
    out["solar_elevation_deg"] = _median(sun)              # geometric (the file's: refracted)
    out["sunlit_albedo"] = albedo = (sunlit_albedo(rb, surface) if forest is None
                                     else forest["floor_albedo"])     # the twin's floor
    kw = dict(delta_time_s=t[ok], z_m=np.full(ok.sum(), z), albedo=albedo,
              solar_elevation_deg=sun[ok], solar_azimuth_deg=np.nan_to_num(az[ok]), band=band,
              outside_fraction=f_out)
    # clear segments in the gaps of the file's own broken deck: its shade (cloud_shade)
    cover = 0.0 if cloud is None or rb.clear is None else float(1.0 - np.mean(rb.clear))
    out["deck_cover"] = cover
    if leak_signal is None:
        leak_signal = out["signal_per_shot"]
    deck = dict(deck=cloud if 0.0 < cover < 1.0 else None,
                deck_cover=cover if cover < 1.0 else 0.0)
    leak = _atl03_leak(inst, photons, band=band, seed=seed + 2, kw={**kw, **deck})
    terms = night.background_terms(inst, signal_per_shot=leak_signal,
                                   leak_hz=leak and leak["leak_hz"], **deck, **kw)
    out["background_terms_hz"] = terms
    out["background_hz"] = terms["total"]
    if leak:
        out["leak"] = leak
    if cloud is not None:
        sig, leak, cloudy = _cloudy(out["signal_per_shot"], inst, photons, band=band, kw=kw,
                                    cloud=cloud, seed=seed + 3, signal_cloud=alternatives
                                    and alternatives[0]["signal_cloud"])
        out["signal_cloudy"] = sig
        if leak:
            out["leak_cloudy"] = leak
        out["background_cloudy_terms_hz"] = cloudy
        out["background_cloudy_hz"] = cloudy["total"]
    if cloud is not None and alternatives:
        out["cloud_alternatives"] = _alternative_rates(out, alternatives, inst, photons,
                                                       band=band, kw=kw, seed=seed + 3)
    return out


def _cloudy(signal_per_shot: float, inst, photons, *, band, kw: dict, cloud, seed: int,
            signal_cloud=None):
    """``(signal, leak, background terms)`` under ``cloud`` on the cloudy segments: the clear
    signal dimmed by the two-way transmission of ``signal_cloud`` (the cloud over the
    segments that measure the signal; default ``cloud``), the leak as ATL03 counts it of the
    laser photons ``cloud`` keeps, the background term by term
    (:func:`~lidar_mitsuba.night.background_terms` with ``cloud``)."""
    from .. import night
    transmission = night.cloud_backscatter(cloud)[0]
    sig = signal_per_shot * night.cloud_backscatter(signal_cloud or cloud)[0]
    leak = _atl03_leak(inst, photons, band=band, seed=seed, keep=transmission,
                       kw={**kw, "cloud": cloud})
    terms = night.background_terms(inst, signal_per_shot=signal_per_shot * transmission,
                                   cloud=cloud, leak_hz=leak and leak["leak_hz"], **kw)
    return sig, leak, terms


def _alternative_rates(out: dict, alternatives: list, inst, photons, *, band, kw: dict,
                       seed: int) -> list[dict]:
    """Each cloud of ``alternatives`` with the signal and background [Hz] it predicts
    (:func:`_cloudy`; the first is ``out``'s own cloud)."""
    rows = []
    for k, a in enumerate(alternatives):
        if k == 0:
            sig, bg = out["signal_cloudy"], out["background_cloudy_hz"]
        else:
            sig, _, terms = _cloudy(out["signal_per_shot"], inst, photons, band=band, kw=kw,
                                    cloud=a["cloud"], seed=seed + 1000 * k,
                                    signal_cloud=a["signal_cloud"])
            bg = terms["total"]
        rows.append({**{key: a[key] for key in ("dataset", "from", "circular", "above_band")},
                     "height_unknown": bool(a.get("height_unknown", False)),
                     **a["cloud"].to_dict(), "signal": sig, "background_hz": bg,
                     "signal_optical_depth": a["signal_cloud"].optical_depth})
    return rows


def _atl03_leak(inst, photons, *, band, seed: int, kw: dict, keep: float = 1.0,
                realizations: int = 32) -> dict | None:
    """Term 5 as ATL03 counts it (:func:`~lidar_mitsuba.night.atl03_leak`) on a simulation's
    ``photons`` (:func:`simulated`), each laser photon kept with probability ``keep``: noise
    photons at the rate the other terms have inside the range gate
    (:func:`~lidar_mitsuba.night.background_terms` of ``kw`` over a band that is the gate,
    centred on the surface: the air of its upper half, a cloud only where it reaches into
    it), the finder's background the photon cloud's, at least the other terms' rate over
    the band (``kw``'s); its
    summary, or None without photons (``signal_shots=0``: the closed form with the file's
    span; ``realizations``: :func:`~lidar_mitsuba.night.atl03_leak`'s)."""
    if photons is None:
        return None
    from .. import night
    gate_m = photons["range_gate_m"]
    gate = night.HistogramBand(height_m=gate_m, top_above_surface_m=gate_m / 2.0)
    noise_hz = night.background_terms(inst, leak_hz=0.0, **{**kw, "band": gate})["total"]
    band_hz = night.background_terms(inst, leak_hz=0.0, **kw)["total"]
    h = float(np.nanmedian(np.atleast_1d(band.height_m)))
    leak = night.atl03_leak(**photons, noise_hz=noise_hz, band_rate_hz=band_hz,
                            band_height_m=h, keep=keep, rng=np.random.default_rng(seed),
                            realizations=realizations)
    return {**leak.summary(), "gate_noise_hz": noise_hz, "band_rate_hz": band_hz}


# ------------------------------------------------------------------------------ verdicts
def _ratio(pred, meas) -> float | None:
    if pred is None or meas is None or not meas > 0:
        return None
    return float(pred / meas)


def verdict(row: dict) -> tuple[str, str]:
    """``(verdict, reason)`` for a beam's row: agrees / disagrees / cloud uncertain (a beam
    all cloudy: :mod:`~lidar_mitsuba.studies.realism_cloudy`) / cloud missing / surface
    missing / not simulated / not measured, the reason naming the quantity that decides it
    (a forest row with its twin: :func:`~lidar_mitsuba.studies.realism_forest.verdict`)."""
    m, p = row["measured"], row["predicted"]
    bg = _ratio(p["background_hz"], m["background_clear_hz"])
    sig = _ratio(p["signal_per_shot"], m["signal_clear"])
    row["background_ratio"], row["signal_ratio"] = bg, sig
    row["background_cloudy_ratio"] = _ratio(p.get("background_cloudy_hz", p["background_hz"]),
                                            m["background_cloudy_hz"])
    if "signal_cloudy" in p:
        row["signal_cloudy_ratio"] = _ratio(p["signal_cloudy"], m["signal_cloudy"])
    cloudy = m["cloud_flags"] and m["clear_fraction"] == 0
    if p.get("forest_twin"):
        from .realism_forest import verdict as forest_verdict
        return forest_verdict(row)
    if p["surface_missing"]:
        v, why = p.get("missing") or ("surface missing", "the product's surface is not "
                                      "modelled here")
        return v, why + ("; every segment is cloudy and no cloud is given" if cloudy else "")
    if cloudy and m["background_cloudy_hz"] is None and m["signal_cloudy"] is None:
        return "not measured", "the file gives neither a background nor a signal rate"
    if cloudy and "background_cloudy_hz" in p:
        from .realism_cloudy import cloudy_verdict
        return cloudy_verdict(row)
    if cloudy:
        return "cloud missing", ("every segment is cloudy by the product's flags, the file "
                                 "gives no reflectance to read its cloud from and none is given "
                                 "(clear-sky background x"
                                 f"{_fmt(row['background_cloudy_ratio'])} of the cloudy one)")
    lo, hi = BACKGROUND_AGREES
    slo, shi = SIGNAL_AGREES
    bad = []
    if bg is not None and not lo <= bg <= hi:
        bad.append(f"background x{bg:.2f}")
    if sig is not None and not slo <= sig <= shi:
        bad.append(f"signal x{sig:.2f}")
    if bg is None and sig is None:
        return "not measured", "the file gives neither a background nor a signal rate"
    cloud = ("" if m["cloud_flags"] else " (no cloud flag in the file: all segments taken as "
             "clear)")
    if 0.0 < p.get("deck_cover", 0.0) < 1.0 and p["background_terms_hz"]["solar"] > 0:
        cloud += (f"; clear segments in the gaps of the file's deck (cover "
                  f"{p['deck_cover']:.2f}), shaded")
    if bad:
        return "disagrees", ", ".join(bad) + cloud
    return "agrees", ratio_words(bg, m["background_clear_hz"], sig, m["signal_clear"]) + cloud


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.2f}"


def pair_ratios(rows: list[dict]) -> list[dict]:
    """Strong:weak ratios of each beam pair of a file (gt1, gt2, gt3) with both beams:
    background (clear segments) and signal, measured and predicted."""
    out = []
    by = {(r["file"], r["beam"]): r for r in rows}
    for (f, name), r in by.items():
        if r["strength"] != "strong":
            continue
        other = by.get((f, name[:3] + ("r" if name[3] == "l" else "l")))
        if other is None or other["strength"] != "weak":
            continue
        q = {"file": f, "pair": name[:3]}
        for key, mk, pk in (("background", "background_clear_hz", "background_hz"),
                            ("signal", "signal_clear", "signal_per_shot")):
            q[f"{key}_measured"] = _ratio(r["measured"][mk], other["measured"][mk])
            q[f"{key}_predicted"] = _ratio(r["predicted"][pk], other["predicted"][pk])
        q["background_cloudy_measured"] = _ratio(r["measured"]["background_cloudy_hz"],
                                                 other["measured"]["background_cloudy_hz"])
        q["background_cloudy_predicted"] = _ratio(r["predicted"].get("background_cloudy_hz"),
                                                  other["predicted"].get("background_cloudy_hz"))
        q["solar_elevation_deg"] = r["measured"]["solar_elevation_deg"]
        out.append(q)
    return out


# ------------------------------------------------------------------------------ the run
def file_seed(path) -> int:
    """A file's own offset to the run's seed, from its name alone (CRC-32, below 10^6): a
    file's simulated rows are the same whichever folder holds it and whatever other files
    the run reads (the offset was its place in the run's list before)."""
    import zlib
    return zlib.crc32(pathlib.Path(path).name.encode()) % 1_000_000


def run(paths=None, out_dir=None, *, signal_shots: int = 200, seed: int = 0,
        progress=None, cloud=None) -> dict:
    """The realism matrix over ``paths`` (files or folders; default the package's real
    files): ``realism.json``, ``realism.md`` and ``realism_background.png`` in ``out_dir``
    (when given). ``signal_shots``: shots simulated per beam for its signal (0: the lidar
    equation, no rendering). ``progress``: a callable given one line per beam. ``cloud``: a
    :class:`~lidar_mitsuba.atmosphere.cloud_layer.Cloud` for the cloudy segments (default: each
    beam's own, :func:`~lidar_mitsuba.studies.realism_inputs.implied_cloud`). With
    ``signal_shots > 0`` each ATL03 + ATL08 forest pair's rows are judged against its forest
    twin (:mod:`~lidar_mitsuba.studies.realism_forest`), whose docs the result keeps under
    ``forest_twin`` (:func:`~lidar_mitsuba.studies.forest_twin.write` writes them)."""
    from . import realism_forest
    t0 = time.perf_counter()
    rows, files = [], []
    found: list = []                      # a named file that cannot be used stops it here;
    read, skipped = read_files(real_files(paths, found=found), twins=signal_shots > 0,
                               skippable=found)   # one found in a folder is passed by
    paths = [rf.path for rf, _ in read]
    forest_docs, forest, paired = _forest_twins(paths, signal_shots=signal_shots, seed=seed,
                                                progress=progress)
    label = labels(paths + [p for p, _ in skipped])
    for rf, tg in read:
        path = rf.path
        files.append({"file": label[path], "product": rf.product, "release": rf.release,
                      "missing": label[path] + rf.missing_line()[len(path.name):]})
        implied = pair_clouds(rf.beams) if cloud is None else {}
        flags = pair_flags(rf.beams) if cloud is None else {}
        for rb in rf.beams:
            if tg is not None and rb.name not in {b.beam.name for b in tg.beams}:
                continue                          # no two segments in a row: no shots
            sky = cloud if cloud is not None else implied[rb.name]
            fdoc = forest.get((_whole(path), rb.name))
            fp = None if fdoc is None else realism_forest.prediction(fdoc, rf.product)
            alts = [] if cloud is not None else cloud_alternatives(
                rb, sky, product=rf.product, band_top_m=band_top_m(rb), flags=flags[rb.name])
            row = {"file": label[path], "product": rf.product, "beam": rb.name,
                   "strength": rb.strength, "measured": measured(rf, rb),
                   "cloud": None if sky is None else {
                       **sky.to_dict(), "from": "given" if cloud is not None else
                       "the file's reflectance"},
                   "predicted": predicted(rb, tg, signal_shots=signal_shots,
                                          seed=seed + file_seed(path), cloud=sky, forest=fp,
                                          alternatives=alts)}
            if fp is not None:
                row["measured"]["signal_forest"] = fp["signal_measured"]
            elif row["predicted"]["surface_missing"] and rb.surface == "unknown":
                row["predicted"]["missing"] = ("surface missing", (
                    "the file does not say its surface (no surf_type, or fill): a flat plate "
                    "of albedo 0.1 stands in; beam, energy and sky as given"))
            elif row["predicted"]["surface_missing"]:
                row["predicted"]["missing"] = realism_forest.missing(
                    signal_shots=signal_shots, paired=_whole(path) in paired)
            row["verdict"], row["reason"] = verdict(row)
            shape = (None if row["predicted"]["surface_missing"] else
                     shape_verdict(row["measured"], row["predicted"]))
            if shape is not None:                 # ATL03: issue 41's spread and tails
                row["shape"] = shape
            rows.append(row)
            if progress is not None:
                progress(format_row(row))
    files += [{"file": label[p], "product": None, "release": None,
               "missing": f"{label[p]}: passed by ({why})"} for p, why in skipped]
    doc = {"signal_shots": int(signal_shots), "files": files, "rows": rows,
           "cloud": None if cloud is None else dataclasses.asdict(cloud),
           "pairs": pair_ratios(rows), "seconds": time.perf_counter() - t0,
           "curve": background_curve(), "forest_twin": forest_docs}
    if out_dir is not None:
        from . import realism_report
        out = pathlib.Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        realism_report.plot(doc, out / "realism_background.png")
        (out / "realism.json").write_text(json.dumps(json_safe(doc), indent=1))
        (out / "realism.md").write_text(realism_report.report_md(doc))
    return doc


def format_row(r: dict) -> str:
    """One beam's line: file, beam, measured and predicted background and signal, verdict."""
    m, p = r["measured"], r["predicted"]

    def k(v):
        return "-" if v is None else f"{v / 1e3:.1f}"

    def s(v):
        return "-" if v is None else f"{v:.2f}"
    # a beam with no clear segment is judged on its cloudy ones, with the cloud: say those
    # (not the clear sky's prediction beside a dash, under a verdict it did not give)
    bg, bg_p, bg_w = m["background_clear_hz"], p["background_hz"], "bg"
    if bg is None and m.get("background_cloudy_hz") is not None:
        bg, bg_p, bg_w = m["background_cloudy_hz"], p.get("background_cloudy_hz"), "bg cloudy"
    sig, sig_p, sig_w = m.get("signal_forest", m["signal_clear"]), p["signal_per_shot"], "sig"
    if sig is None and m.get("signal_cloudy") is not None:
        sig, sig_p, sig_w = m["signal_cloudy"], p.get("signal_cloudy"), "sig cloudy"
    return (f"{r['file'][:34]:<34} {r['beam']} {r['strength']:<6} "
            f"{bg_w} {k(bg)}/{k(bg_p)} kHz {sig_w} {s(sig)}/{s(sig_p)}  {r['verdict']}")
