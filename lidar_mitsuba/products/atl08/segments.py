"""ATL08 100 m segments (five ATL03 20 m segments) from classified photons: terrain and canopy
metrics with the real product's names (:mod:`lidar_mitsuba.products.atl08.fields`).

A segment's terrain is reported when it holds at least :data:`MIN_GROUND_PHOTONS` ground
photons, its canopy when it holds at least :data:`MIN_CANOPY_PHOTONS` canopy and
top-of-canopy photons; otherwise those fields keep the fill value. Heights above the ground
("relative") are photon heights minus the ground surface (the final smoothing spline) at the
photon.
"""
from __future__ import annotations

import numpy as np

from .classify import CANOPY, GROUND, TOP_OF_CANOPY
from .fields import GROUPS, RH_PERCENTILES, TERRAIN

SEGMENTS_PER_LAND_SEGMENT = 5
"""ATL08's 100 m segments are five ATL03 20 m geolocation segments (ATL08 ATBD sec. 2)."""
MIN_GROUND_PHOTONS = 5
"""ESTIMATE: fewest ground photons for a terrain height: a line fit and its residual need at
least three; five keep one outlier from deciding the slope (the ATBD reports no terrain
'if too few ground photons', change history 2016 Nov, without a number we could check)."""
MIN_CANOPY_PHOTONS = 50
"""Fewest canopy + top-of-canopy photons for canopy metrics. ESTIMATE, kept from the first
version ("ATL08's own threshold as we read the ATBD"), NOT checked: in session 19 the ATBD's
text on it (release 002, sec. 4.15) could not be reached; what could be read are its change
history ("do not report segment statistics if too few ground photons", sec. 4.15 (3)) and the
data dictionary's ``canopy_rh_conf``, which grades a segment by its *fraction* of canopy
photons (0: under 5 % canopy; 1: over 5 % canopy, under 5 % ground; 2: both over 5 %), a
different kind of criterion (5 % of a 100 m segment's ~150-300 signal photons is 8-15). RH98
of 50 photons is the 49th: with fewer the percentile rests on the single highest photon."""


def _empty(n: int) -> dict:
    """Every field of :data:`GROUPS` but the photons', filled with its fill value."""
    out = {}
    for group, spec in GROUPS.items():
        if group == "signal_photons":
            continue
        for name, f in spec.items():
            out[f"{group}/{name}"] = np.full((n,) + f.shape, f.fill, dtype=f.dtype)
    return out


def land_segments(*, x_m: np.ndarray, h_m: np.ndarray, classes: np.ndarray,
                  ground_h_m: np.ndarray, is_signal: np.ndarray, photon_segment: np.ndarray,
                  delta_time_s: np.ndarray, seg_id: np.ndarray, seg_x_m: np.ndarray,
                  seg_lat_deg: np.ndarray, seg_lon_deg: np.ndarray,
                  seg_solar_elevation_deg: np.ndarray | None = None,
                  seg_solar_azimuth_deg: np.ndarray | None = None,
                  shots_per_m: float | None = None) -> dict:
    """The ``land_segments`` fields (keys ``group/name`` as in
    :data:`lidar_mitsuba.products.atl08.fields.GROUPS`) of every full group of five
    consecutive ATL03 20 m segments.

    Args:
        x_m, h_m, classes, ground_h_m, is_signal: (n,) per photon: along-track distance [m],
            height [m], ``classed_pc_flag``, ground surface at the photon [m], noise-filter
            pass (:class:`~lidar_mitsuba.products.atl08.classify.Classification`).
        photon_segment: (n,) index into the 20 m segment arrays of each photon's segment.
        delta_time_s: (n,) photon times [s since 2018-01-01].
        seg_id, seg_x_m, seg_lat_deg, seg_lon_deg: (m,) the 20 m segments: ATL03
            ``segment_id`` (consecutive), along-track start [m], reference-photon place.
        seg_solar_elevation_deg, seg_solar_azimuth_deg: (m,) the sun, or None (fill).
        shots_per_m: shots per metre of track, for the photon rates (None: fill).
    """
    seg_id = np.asarray(seg_id, np.int64)
    n_full = seg_id.size // SEGMENTS_PER_LAND_SEGMENT
    out = _empty(n_full)
    k_of_photon = np.asarray(photon_segment, np.int64) // SEGMENTS_PER_LAND_SEGMENT
    grp = np.arange(n_full * SEGMENTS_PER_LAND_SEGMENT).reshape(n_full, -1)
    ls = "land_segments/"
    out[ls + "segment_id_beg"][:] = seg_id[grp[:, 0]]
    out[ls + "segment_id_end"][:] = seg_id[grp[:, -1]]
    out[ls + "latitude_20m"][:] = seg_lat_deg[grp]
    out[ls + "longitude_20m"][:] = seg_lon_deg[grp]
    out[ls + "latitude"][:] = np.mean(seg_lat_deg[grp], axis=1)
    out[ls + "longitude"][:] = np.mean(seg_lon_deg[grp], axis=1)
    if seg_solar_elevation_deg is not None:
        elev = np.mean(np.asarray(seg_solar_elevation_deg)[grp], axis=1)
        out[ls + "solar_elevation"][:] = elev
        out[ls + "night_flag"][:] = (elev < 0).astype(np.int32)
    if seg_solar_azimuth_deg is not None:
        out[ls + "solar_azimuth"][:] = np.mean(np.asarray(seg_solar_azimuth_deg)[grp], axis=1)
    seg_len = np.diff(seg_x_m[grp], axis=1).mean() if SEGMENTS_PER_LAND_SEGMENT > 1 else 20.0
    x_mid = seg_x_m[grp[:, 0]] + 0.5 * SEGMENTS_PER_LAND_SEGMENT * seg_len
    for k in range(n_full):
        m = (k_of_photon == k) & is_signal
        if not m.any():
            continue
        t = delta_time_s[m]
        out[ls + "delta_time"][k] = t.mean()
        out[ls + "delta_time_beg"][k] = t.min()
        out[ls + "delta_time_end"][k] = t.max()
        out[ls + "n_seg_ph"][k] = m.sum()
        c = classes[m]
        g, cn = c == GROUND, (c == CANOPY) | (c == TOP_OF_CANOPY)
        n_shots = None if shots_per_m is None else shots_per_m * SEGMENTS_PER_LAND_SEGMENT * seg_len
        _terrain(out, k, x_m[m][g] - x_mid[k], h_m[m][g], ground_h_m[m], x_m[m] - x_mid[k],
                 seg_x_m[grp[k]] + 0.5 * seg_len - x_mid[k], n_shots)
        _canopy(out, k, h_m[m][cn], (h_m - ground_h_m)[m][cn], c[cn], h_m[m][g | cn], n_shots)
    return out


def _terrain(out: dict, k: int, dx: np.ndarray, h: np.ndarray, ground_at: np.ndarray,
             dx_all: np.ndarray, dx_20m: np.ndarray, n_shots: float | None) -> None:
    """Segment ``k``'s terrain fields from its ground photons (``dx`` [m] from the segment's
    mid-point, heights ``h`` [m]); ``ground_at``, ``dx_all``: the ground surface at every
    signal photon of the segment and their ``dx`` (for ``h_te_interp``)."""
    p = "land_segments/terrain/"
    out[p + "n_te_photons"][k] = h.size
    if n_shots:
        out[p + "photon_rate_te"][k] = h.size / n_shots
    if dx_all.size:
        i = int(np.argmin(np.abs(dx_all)))
        out[p + "h_te_interp"][k] = ground_at[i]
    if h.size < MIN_GROUND_PHOTONS:
        return
    out[p + "h_te_mean"][k] = h.mean()
    out[p + "h_te_median"][k] = np.median(h)
    out[p + "h_te_min"][k] = h.min()
    out[p + "h_te_max"][k] = h.max()
    out[p + "h_te_std"][k] = h.std()
    xbar = dx.mean()
    sxx = float(np.sum((dx - xbar) ** 2))
    if sxx <= 0:
        return
    slope = float(np.sum((dx - xbar) * (h - h.mean())) / sxx)
    icpt = h.mean() - slope * xbar                     # the line at the mid-point (dx = 0)
    res = h - (icpt + slope * dx)
    sigma = np.sqrt(np.sum(res ** 2) / max(h.size - 2, 1))
    out[p + "h_te_best_fit"][k] = icpt
    out[p + "terrain_slope"][k] = slope
    out[p + "h_te_uncertainty"][k] = sigma * np.sqrt(1.0 / h.size + xbar ** 2 / sxx)
    half = 0.5 * (dx_20m[1] - dx_20m[0]) if dx_20m.size > 1 else 10.0
    has = np.array([np.any(np.abs(dx - c) <= half) for c in dx_20m])
    out[p + "h_te_best_fit_20m"][k] = np.where(has, icpt + slope * dx_20m,
                                               TERRAIN["h_te_best_fit_20m"].fill)


def _canopy(out: dict, k: int, h_abs: np.ndarray, h_rel: np.ndarray, c: np.ndarray,
            h_all: np.ndarray, n_shots: float | None) -> None:
    """Segment ``k``'s canopy fields from its canopy and top-of-canopy photons (heights
    above the ellipsoid ``h_abs`` and above the ground ``h_rel`` [m], classes ``c``);
    ``h_all``: the ground and canopy photons' heights (the centroid)."""
    p = "land_segments/canopy/"
    out[p + "n_ca_photons"][k] = int(np.sum(c == CANOPY))
    out[p + "n_toc_photons"][k] = int(np.sum(c == TOP_OF_CANOPY))
    if n_shots:
        out[p + "photon_rate_can"][k] = c.size / n_shots
    if h_all.size:
        out[p + "centroid_height"][k] = h_all.mean()
    ok = np.isfinite(h_rel)
    h_abs, h_rel, c = h_abs[ok], h_rel[ok], c[ok]
    if h_rel.size < MIN_CANOPY_PHOTONS:
        return
    q = np.asarray(RH_PERCENTILES, np.float64)
    out[p + "canopy_h_metrics"][k] = np.percentile(h_rel, q)
    out[p + "canopy_h_metrics_abs"][k] = np.percentile(h_abs, q)
    out[p + "h_canopy"][k] = np.percentile(h_rel, 98)
    out[p + "h_canopy_abs"][k] = np.percentile(h_abs, 98)
    for key, fn in (("mean", np.mean), ("median", np.median), ("max", np.max),
                    ("min", np.min)):
        out[p + f"h_{key}_canopy"][k] = fn(h_rel)
        out[p + f"h_{key}_canopy_abs"][k] = fn(h_abs)
    out[p + "h_dif_canopy"][k] = out[p + "h_canopy"][k] - out[p + "h_median_canopy"][k]
    out[p + "canopy_openness"][k] = h_rel.std()
    toc = h_rel[c == TOP_OF_CANOPY]
    if toc.size > 1:
        out[p + "toc_roughness"][k] = toc.std()


