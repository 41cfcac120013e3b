"""The per-product readers of :func:`lidar_mitsuba.products.real.read_product`: one ATL03,
ATL06, ATL07 or ATL08 beam group as a :class:`~lidar_mitsuba.products.real.RealBeam` table of
its segments (what each product measured, where and when, and what stands in for what a
subset dropped, in the beam's notes). Pure (h5py, numpy)."""
from __future__ import annotations

import pathlib
import re

import numpy as np

from ..constants import C_M_PER_NS
from .real import (CLEAR_TWO_WAY_TRANSMISSION, SNOW_REFLECTANCE, SURF_PRIORITY, SURF_TYPES,
                   RealBeam, _num, _rate_hz)


def _atl03(g, **beam) -> RealBeam | None:
    """An ATL03 beam: 20 m geolocation segments, the median height of each segment's
    high-confidence photons, signal photons (``signal_conf_ph >= 3``) per pulse, the 50-shot
    background row nearest each segment and its band."""
    geo = g["geolocation"]
    t = _num(geo, "delta_time")
    if t is None or t.size < 2:
        return None
    h, sig, sig_why = segment_photons(g, geo)
    bg = g["bckgrd_atlas"] if "bckgrd_atlas" in g else None
    lat, lon = _num(geo, "reference_photon_lat"), _num(geo, "reference_photon_lon")
    stand_ins = []
    if (lat is None or lon is None) and np.isfinite(h).any():      # a subset of the photons'
        lat, lon = (_first_photon(g, geo, k) for k in ("lat_ph", "lon_ph"))      # places
        if lat is not None and lon is not None:
            stand_ins.append("geolocation/reference_photon_lat, _lon (each segment's first "
                             "photon's lat_ph, lon_ph)")
    b = RealBeam(**beam, delta_time_s=t, lat_deg=lat, lon_deg=lon, surface_h_m=h,
                 altitude_m=_num(geo, "altitude_sc"),
                 solar_elevation_deg=_num(geo, "solar_elevation"),
                 solar_azimuth_deg=_num(geo, "solar_azimuth"), signal_per_shot=sig,
                 full_sat_fract=_num(geo, "full_sat_fract"),
                 near_sat_fract=_num(geo, "near_sat_fract"),
                 notes={"background": "bckgrd_atlas/bckgrd_rate (50-shot rows nearest each "
                        "segment)", "signal": "signal_conf_ph >= 3 photons per pulse",
                        **({"stand_ins": stand_ins} if stand_ins else {})})
    if sig is None and sig_why is not None:
        b.notes["signal_missing"] = sig_why
    elif sig is None and "heights/h_ph" in g and not np.isfinite(h).any():
        b.notes["signal_missing"] = "no segment's photons (ph_index_beg or h_ph hold fill)"
    elif (sig is None and "heights/pce_mframe_cnt" in g and "heights/ph_id_pulse" in g
            and photon_pulses(g) is None):
        b.notes["signal_missing"] = "pce_mframe_cnt, ph_id_pulse hold fill"
    e = _num(geo, "tx_pulse_energy")
    if e is not None and np.isfinite(e).any():
        b.pulse_energy_uj = e * 1e6
    if "surf_type" in geo:
        st = np.asarray(geo["surf_type"][()])
        if st.ndim == 2 and st.shape[1] == len(SURF_TYPES):
            present = (st == 1).sum(axis=0) >= 0.5 * st.shape[0]    # (fill is not 1)
            b.surface = next((SURF_TYPES[i] for i in SURF_PRIORITY if present[i]), "unknown")
    tb, rate = (_num(bg, "delta_time"), _rate_hz(bg, "bckgrd_rate")) if bg is not None \
        else (None, None)
    if tb is not None and rate is not None and (tb.size == 0 or rate.shape != tb.shape):
        b.notes["background_hz_missing"] = (f"bckgrd_atlas holds {tb.size} rows" if tb.size == 0
                                            else "bckgrd_atlas/bckgrd_rate does not fit its "
                                            "delta_time")
    elif tb is not None and rate is not None and not np.isfinite(tb).any():
        b.notes["background_hz_missing"] = "bckgrd_atlas/delta_time holds fill"
    elif tb is not None and rate is not None and not _atl03s_estimate(bg, rate):
        b.notes["background_hz_missing"] = (
            "bckgrd_atlas/bckgrd_rate is not ATL03's estimate from its rows' counts "
            "(bckgrd_counts_reduced over bckgrd_int_height_reduced and 50 shots: a "
            "simulation's modelled rate, as ours)")
    elif tb is not None and rate is not None:
        rows = np.flatnonzero(np.isfinite(tb))              # (rows with a time)
        k = rows[np.clip(np.searchsorted(tb[rows], t), 0, rows.size - 1)]
        b.background_hz = rate[k]
        height, reduced = _num(bg, "bckgrd_int_height"), _num(bg, "bckgrd_int_height_reduced")
        top = _num(bg, "bckgrd_hist_top")
        if all(a is not None and a.shape == tb.shape for a in (height, reduced, top)):
            b.band_height_m = reduced[k]
            b.signal_span_m = np.maximum(height[k] - reduced[k], 0.0)
            if np.isfinite(h).any():
                b.band_top_above_surface_m = top[k] - np.where(np.isfinite(h), h,
                                                               np.nanmedian(h))
    return b


def _atl03s_estimate(bg, rate: np.ndarray) -> bool:
    """Whether an ATL03 beam's ``bckgrd_rate`` rows are ATL03's estimate from their own counts,
    ``bckgrd_counts_reduced / (50 * 2 * bckgrd_int_height_reduced / c)``
    (docs/physics/night-floor.md, eq. bckgrd-rate): NASA's rows hold it to float32's rounding
    (``tests/test_realism.py``), the rows our ATL03 writes do not (their rate is the modelled
    rate inside the range gate, their counts the gate's: ``products/atl03/fields.py``), and
    the realism matrix predicts ATL03's estimate (the laser photons its finder leaves over a
    band of kilometres), not a modelled rate. Rows that cannot be checked (no counts or band,
    or fill) are taken as NASA's; the check is the median relative difference over the rows
    with counts, above 1e-3."""
    counts, reduced = _num(bg, "bckgrd_counts_reduced"), _num(bg, "bckgrd_int_height_reduced")
    if counts is None or reduced is None or not (counts.shape == reduced.shape == rate.shape):
        return True
    with np.errstate(divide="ignore", invalid="ignore"):
        est = counts / (50.0 * 2.0 * reduced / (C_M_PER_NS * 1e9))
        rel = np.abs(rate / est - 1.0)
    ok = np.isfinite(rel) & (counts > 0)
    return not ok.any() or float(np.median(rel[ok])) <= 1e-3


def segment_photons(g, geo) -> tuple[np.ndarray, np.ndarray | None, str | None]:
    """Each ATL03 segment's median height of its photons of the file's highest confidence
    (4; 3 or 2 in a file that has none higher) [m] (NaN when none), its signal photons
    (``signal_conf_ph >= 3``) per pulse (NaN for segments of fewer than 10 pulses; None
    without photon ids, without the confidences, or without a photon of confidence 3 or more
    in the beam: a rate of 0 would read a subset's missing confidences as no signal, and
    every photon taken as signal would count the background) and why the rate is None (or
    None). Photons that do not fit their index (a subset that cut ``heights`` and not
    ``geolocation``, or one ``heights`` dataset and not the others) are not read."""
    n_seg = geo["delta_time"].shape[0]
    if "segment_ph_cnt" not in geo or "ph_index_beg" not in geo or "heights/h_ph" not in g:
        return np.full(n_seg, np.nan), None, None                    # photons dropped
    cnt = geo["segment_ph_cnt"][()].astype(np.int64).ravel()
    beg = geo["ph_index_beg"][()].astype(np.int64).ravel() - 1
    h_out = np.full(cnt.size, np.nan)
    h = _num(g, "heights/h_ph").ravel()         # (fill values NaN)
    per_photon = [k for k in ("heights/signal_conf_ph", "heights/pce_mframe_cnt",
                              "heights/ph_id_pulse") if k in g]
    used = (cnt > 0) & (beg >= 0)
    if cnt.size == n_seg and beg.size == n_seg and not used.any():
        return h_out, None, "no segment's photons (geolocation/ph_index_beg, segment_ph_cnt)"
    if (cnt.size != n_seg or beg.size != n_seg
            or any(g[k].shape[0] != h.size for k in per_photon)
            or np.any(beg[used] > h.size - cnt[used])):  # (an index at fill, too)
        return np.full(n_seg, np.nan), None, (
            f"heights/h_ph ({h.size} photons) does not fit geolocation/ph_index_beg, "
            "segment_ph_cnt" + (f" or {', '.join(k.split('/')[1] for k in per_photon)}"
                                if per_photon else ""))
    if "heights/signal_conf_ph" in g:
        c = g["heights/signal_conf_ph"][()]
        conf = c.max(axis=1) if c.ndim == 2 else c
        why = None
    else:                                  # every photon a segment's height; none a signal
        conf, why = np.full(h.size, 4), "no heights/signal_conf_ph"
    top = max(int(conf.max()) if conf.size else 4, 2)
    has_ids = ("heights/pce_mframe_cnt" in g and "heights/ph_id_pulse" in g
               and top >= 3 and why is None)  # none of medium confidence: no signal read
    pulse = photon_pulses(g) if has_ids else None     # (None where the ids are fill)
    rate = np.full(cnt.size, np.nan)
    for k, (b, c) in enumerate(zip(beg, cnt)):
        if c <= 0 or b < 0:                        # (no photons)
            continue
        cs = conf[b:b + c]
        s = h[b:b + c][cs >= top]
        s = s[np.isfinite(s)]
        if s.size:
            h_out[k] = np.median(s)
        if pulse is not None:
            p = pulse[b:b + c]
            shots = int(p.max() - p.min() + 1)
            if shots >= 10:
                rate[k] = np.count_nonzero(cs >= 3) / shots
    if pulse is None and why is None and "heights/signal_conf_ph" in g and top < 3:
        why = "no photon of signal_conf_ph >= 3"
    return h_out, (rate if pulse is not None else None), why


def _first_photon(g, geo, key: str) -> np.ndarray | None:
    """``heights/<key>`` at each ATL03 segment's first photon (NaN where it has none), or
    None where the photons or their index are not there or do not fit."""
    if f"heights/{key}" not in g or "ph_index_beg" not in geo or "segment_ph_cnt" not in geo:
        return None
    a = _num(g["heights"], key).ravel()
    beg = geo["ph_index_beg"][()].astype(np.int64).ravel() - 1
    cnt = geo["segment_ph_cnt"][()].astype(np.int64).ravel()
    ok = (beg >= 0) & (cnt > 0) & (beg < a.size)
    if beg.size != geo["delta_time"].shape[0] or not ok.any():
        return None
    out = np.full(beg.size, np.nan)
    out[ok] = a[beg[ok]]
    return out


def photon_pulses(g) -> np.ndarray | None:
    """Each ATL03 photon's pulse number ``pce_mframe_cnt * 200 + ph_id_pulse`` (int64), or
    None where any id is not a pulse's (fill, or ``ph_id_pulse`` outside 1-200): a pulse
    count read from them would be wrong."""
    frame, pid = _num(g, "heights/pce_mframe_cnt"), _num(g, "heights/ph_id_pulse")
    if frame is None or pid is None or not (np.isfinite(frame).all() and np.isfinite(pid).all()
                                           and np.all((pid >= 1) & (pid <= 200))):
        return None
    return frame.astype(np.int64) * 200 + pid.astype(np.int64)


def _flag_clear(reflectance, flag_asr, flag_atm) -> np.ndarray | None:
    """Clear where every flag given says so: apparent reflectance high enough
    (``reflectance`` >= :data:`CLEAR_TWO_WAY_TRANSMISSION` x :data:`SNOW_REFLECTANCE`; a
    segment without one, no fit, counts as cloudy), ASR-based flag <= 2 (clear, any
    confidence), no layer found by the atmospheric profile (a flag that is fill on a segment
    says nothing there). A dataset that is fill everywhere counts as absent; None when none
    is left."""
    parts = []
    for a, ok, fill_says_nothing in (
            (reflectance, lambda v: v >= CLEAR_TWO_WAY_TRANSMISSION * SNOW_REFLECTANCE, False),
            (flag_asr, lambda v: v <= 2, True), (flag_atm, lambda v: v == 0, True)):
        if a is None or not np.isfinite(a).any():
            continue
        with np.errstate(invalid="ignore"):
            parts.append(np.where(np.isfinite(a), ok(a), fill_says_nothing))
    if not parts:
        return None
    return np.logical_and.reduce(parts)


UNFILLED_FLAG_RELEASES = re.compile(r"^(0*1|2\d\d)$")
"""ATL06 releases whose ``cloud_flg_asr`` and ``cloud_flg_atm`` were not filled from ATL09:
001 and the pre-releases (209): 0 on every segment in every such file seen (sessions 26-28:
Snowblower's, glaciersat2's, WaterNoice's, the 209 Pacific), where the same granule's
release 003 (``ATL06_20181014001049_02350102``) flags cloud on every segment."""


def _unfilled_flags(g, asr, atm) -> bool:
    """Whether an ATL06 beam's two cloud flags are 0 on every segment of a file of a release
    (:data:`UNFILLED_FLAG_RELEASES`) that did not fill them: then they say nothing."""
    from .real import release_of
    if asr is None or atm is None:
        return False
    vals = np.concatenate([asr[np.isfinite(asr)], atm[np.isfinite(atm)]])
    if not vals.size or np.any(vals != 0):
        return False
    release = release_of(g.file, pathlib.Path(g.file.filename))
    return bool(release and UNFILLED_FLAG_RELEASES.match(release.strip()))


def _sub(s, name: str):
    """Group ``name`` of segment group ``s``, or an empty mapping where a subset dropped it
    (its datasets then read as absent: :func:`~lidar_mitsuba.products.real._num`)."""
    return s[name] if name in s else {}


def _atl06(g, **beam) -> RealBeam | None:
    """An ATL06 beam: 40 m land-ice segments every 20 m. Signal per shot: the fitted
    photons less the background expected in the final window, per pulse,
    ``(n_fit_photons - bckgrd * w_surface_window_final * 2 / c * n_seg_pulses) /
    n_seg_pulses``, on segments of quality 0."""
    s = g["land_ice_segments"]
    t = _num(s, "delta_time")
    if t is None:
        return None
    gp = _sub(s, "geophysical")
    fs = _sub(s, "fit_statistics")
    bg = _rate_hz(gp, "bckgrd")
    n_fit, n_pulses, w = (_num(fs, k) for k in ("n_fit_photons", "n_seg_pulses",
                                                "w_surface_window_final"))
    sig, stand_ins = None, []
    if n_fit is not None and n_pulses is not None:
        noise = (bg * w * 2.0 / (C_M_PER_NS * 1e9) * n_pulses
                 if bg is not None and w is not None else 0.0)
        if bg is None or w is None:                    # the window's noise left in
            gone = ("geophysical/bckgrd" if bg is None
                    else "fit_statistics/w_surface_window_final")
            stand_ins.append(f"{gone} (the fitted photons' background not taken off the "
                             "signal)")
        sig = np.where(n_pulses > 0, (n_fit - noise) / np.where(n_pulses > 0, n_pulses, 1),
                       np.nan)
        q = _num(s, "atl06_quality_summary")
        if q is not None:
            sig = np.where(q == 0, sig, np.nan)
    from .real_surface import dem_said, dem_surface
    surface = dem_surface(s)
    stand_ins += [] if dem_said(s) else [
        ("dem/dem_flag" if "dem/dem_flag" not in s else "dem/dem_flag's flag_meanings")
        + " (the surface taken as land ice, where ATL06 is made; r_eff held against snow's)"]
    r_eff = _num(gp, "r_eff") if surface == "land ice" else None     # held against snow's
    if r_eff is not None and not np.isfinite(r_eff).any():
        r_eff = None                        # (fill everywhere: as absent)
    asr, atm = _num(gp, "cloud_flg_asr"), _num(gp, "cloud_flg_atm")
    unfilled = r_eff is None and _unfilled_flags(g, asr, atm)   # (the flags alone decide)
    if unfilled:
        asr = atm = None
    clear = _flag_clear(r_eff, asr, atm)
    h = _num(s, "h_li")
    return RealBeam(**beam, delta_time_s=t, lat_deg=_num(s, "latitude"),
                    lon_deg=_num(s, "longitude"),
                    surface_h_m=h,
                    solar_elevation_deg=_num(gp, "solar_elevation"),
                    solar_azimuth_deg=_num(gp, "solar_azimuth"), background_hz=bg,
                    signal_per_shot=sig, clear=clear, reflectance=r_eff,
                    layer_class=_num(gp, "msw_flag"), layer_count=atm,
                    surface=surface,
                    notes={"background": "geophysical/bckgrd",
                           "signal": "(n_fit_photons - background in the window) / "
                           "n_seg_pulses, quality 0",
                           "clear": ("r_eff >= 0.45, " if r_eff is not None else "")
                           + "cloud_flg_asr <= 2, cloud_flg_atm == 0",
                           **({"clear_missing": "cloud_flg_asr, cloud_flg_atm are 0 on every "
                               "segment, as release 001 and the pre-releases leave them: not "
                               "filled from ATL09"} if unfilled else {}),
                           **({"stand_ins": stand_ins} if stand_ins else {})})



def _atl07(g, **beam) -> RealBeam | None:
    """An ATL07 beam: 150-photon sea-ice segments. Height above the ellipsoid:
    ``height_segment_height + height_segment_mss`` (tides and the inverted barometer, a few
    dm, left in); signal per shot: ``photon_rate`` on snow-covered ice
    (``height_segment_type == 1``)."""
    s = g["sea_ice_segments"]
    t = _num(s, "delta_time")
    if t is None:
        return None
    geo = _sub(s, "geolocation")
    hts = _sub(s, "heights")
    gp = _sub(s, "geophysical")
    st = _sub(s, "stats")
    h = _num(hts, "height_segment_height")
    mss = _num(gp, "height_segment_mss")
    stand_ins = []
    if h is not None and mss is None:                  # heights above the mean sea surface
        stand_ins.append("geophysical/height_segment_mss (heights above the mean sea "
                         "surface taken as above the ellipsoid)")
    h = h + mss if h is not None and mss is not None else h
    rate = _num(st, "photon_rate")
    kind = _num(hts, "height_segment_type")
    if rate is not None and kind is not None:
        rate = np.where(kind == 1, rate, np.nan)
    elif rate is not None:                             # leads and cloud-covered ones too
        stand_ins.append("heights/height_segment_type (the signal's photon_rate on every "
                         "segment, not snow-covered ice's alone)")
    asr = _num(st, "asr_25")
    if asr is not None and not np.isfinite(asr).any():
        asr = None                          # (fill everywhere: as absent)
    clear = _flag_clear(asr, _num(st, "cloud_flag_asr"), _num(st, "cloud_flag_atm"))
    band = _num(st, "background_int_height")
    conc = _num(st, "ice_conc")
    return RealBeam(**beam, delta_time_s=t, lat_deg=_num(s, "latitude"),
                    lon_deg=_num(s, "longitude"), surface_h_m=h,
                    solar_elevation_deg=_num(geo, "solar_elevation"),
                    solar_azimuth_deg=_num(geo, "solar_azimuth"),
                    background_hz=_rate_hz(st, "backgr_r_200"), signal_per_shot=rate, clear=clear,
                    reflectance=asr, reflectance_photons=_num(hts, "height_segment_asr_calc"),
                    layer_class=_num(st, "msw_flag"), layer_count=_num(st, "cloud_flag_atm"),
                    band_height_m=band,
                    ice_fraction=None if conc is None else conc / 100.0, surface="sea ice",
                    notes={"background": "stats/backgr_r_200 (ATL03's 50-shot rate)",
                           "signal": "stats/photon_rate on snow-covered ice (type 1)",
                           "clear": "asr_25 >= 0.45, cloud_flag_asr <= 2, cloud_flag_atm == 0",
                           **({"stand_ins": stand_ins} if stand_ins else {})})


def _atl08(g, **beam) -> RealBeam | None:
    """An ATL08 beam: 100 m land segments. Surface: ``terrain/h_te_best_fit``; signal per
    shot: terrain and canopy photon rates (``photon_rate_te + photon_rate_can``); no
    background rate."""
    s = g["land_segments"]
    t = _num(s, "delta_time")
    if t is None:
        return None
    ter = _sub(s, "terrain")
    can = _sub(s, "canopy")
    te, cn = _num(ter, "photon_rate_te"), _num(can, "photon_rate_can")
    sig = None if te is None else te + (np.nan_to_num(cn) if cn is not None else 0.0)
    stand_ins = ["canopy/photon_rate_can (the signal the terrain's photons alone)"] \
        if te is not None and cn is None else []
    h = _num(ter, "h_te_best_fit")
    return RealBeam(**beam, delta_time_s=t, lat_deg=_num(s, "latitude"),
                    lon_deg=_num(s, "longitude"),
                    surface_h_m=h,
                    solar_elevation_deg=_num(s, "solar_elevation"),
                    solar_azimuth_deg=_num(s, "solar_azimuth"), signal_per_shot=sig,
                    clear=_flag_clear(None, None, _num(s, "cloud_flag_atm")), surface="land",
                    notes={"signal": "photon_rate_te + photon_rate_can",
                           "clear": "cloud_flag_atm == 0",
                           **({"stand_ins": stand_ins} if stand_ins else {})})


READERS = {"ATL03": _atl03, "ATL06": _atl06, "ATL07": _atl07, "ATL08": _atl08}
