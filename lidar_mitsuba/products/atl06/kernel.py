"""Compiled ATL06 segment fit (numba): :func:`lidar_mitsuba.products.atl06.reference.fit_segment` and
the :mod:`lidar_mitsuba.products.first_photon_bias` helpers it calls, step for step, over all segments of a track.

The numpy functions stay the reference (the module docstring of :mod:`lidar_mitsuba.products.atl06`
describes the algorithm, and the tests compare the two on the same segments): this file only
removes the per-segment Python overhead (~0.9 ms a segment, 44 % of a DEM granule's time).
Each step of the reference has its twin here under the same name (``_densest_window``,
``_first_window``, ``_refine_window``, ``_final_spread_and_background``, ``_formal_errors``,
``_first_photon_bias``; the dead-time weights' in :mod:`~lidar_mitsuba.products.atl06.dead_time`),
and :func:`fit_segment` strings them together as the reference does.
:func:`fit_all` runs its segments one after the other (``parallel=True`` made the compile twice
as long) without the GIL: :func:`lidar_mitsuba.products.atl06._fit_compiled` gives contiguous blocks of
segments to the host's threads (a sweep task's thread count included).
In the fit, sums run in a different order than numpy's pairwise ones, so results agree to rounding
(~1e-15 relative), except where a photon sits on a window edge within that rounding.
Python's ``min``/``max`` keep the first argument on NaN; :func:`_pmax` and :func:`_pmin` do
the same, so NaNs propagate as in the reference. ``cache=True`` keeps the compiled code.

Sorts, the main cost, are as few as the results allow, each the same to the bit (issue 43):
distributed into buckets (:mod:`~lidar_mitsuba.products.atl06.sorting`), the last iteration's
line, residuals and their sort reused as the final line's (the same line), the
first-photon-bias order (weights, median) merged from that sort's order and the few residuals
above the window (:func:`~.sorting.merged_order`), the densest window in one sweep or none.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from ...numeric import pairwise_sum
from .dead_time import _dead_time_weights, _dead_time_weights_ordered
from .sorting import argsort, first_at_least, has_nan, merged_order, sort, sort_and_order

#: output columns, in order (ints travel as floats and are converted by the caller)
OUT_FIELDS = ("n_seg_pulses", "flags", "n_fit_photons", "h_li", "h_li_sigma", "h_mean",
              "sigma_h_mean", "dh_fit_dx", "h_robust_sprd", "h_rms_misfit",
              "w_surface_window_final", "exit_iteration", "bckgrd", "bckgrd_n_photons",
              "bckgrd_exposure_ns", "fpb_corr_m", "fpb_corr_sigma_m", "fpb_med_corr_m",
              "fpb_gain", "fpb_min_alive", "fpb_n_corr", "snr")
(_N_PULSES, _FLAGS, _N_FIT, _H_LI, _H_LI_SIGMA, _H_MEAN, _SIGMA_H_MEAN, _DH, _SPRD, _RMS,
 _WIN, _EXIT, _BG, _BG_N, _BG_EXP, _FPB, _FPB_SIGMA, _FPB_MED, _GAIN, _MIN_ALIVE, _N_CORR,
 _SNR) = range(len(OUT_FIELDS))

#: the settings ``cfg`` holds, in order (``_atl06_reference.Config``'s fields), then half c
#: and the Gaussian IQR per sigma; the names below index them
CFG_FIELDS = ("n_channels", "dead_time_ns", "paralyzable", "sigma_pulse_m", "footprint_sigma_m",
              "gate_m", "initial_window_m", "min_window_m", "max_iterations", "min_photons",
              "min_span_m", "min_alive_pulses", "max_gain")
(_N_CHANNELS, _DEAD_TIME_NS, _PARALYZABLE, _SIGMA_PULSE_M, _FOOTPRINT_SIGMA_M, _GATE_M, _W0,
 _MIN_WINDOW_M, _MAX_ITERATIONS, _MIN_PHOTONS, _MIN_SPAN_M, _MIN_ALIVE_PULSES, _MAX_GAIN, _HALF_C,
 _IQR_SCALE) = range(len(CFG_FIELDS) + 2)

_TOO_FEW, _LOW_SNR, _LARGE_SPREAD, _FPB_DEAD, _FPB_GAIN, _FPB_DIVERGED, _NOT_CONVERGED = \
    1, 2, 4, 8, 16, 32, 64


@numba.njit(cache=True, nogil=True)
def _pmax(a, b):  # Python's max(a, b): b only when b > a
    return b if b > a else a


@numba.njit(cache=True, nogil=True)
def _pmin(a, b):  # Python's min(a, b): b only when b < a
    return b if b < a else a


@numba.njit(cache=True, nogil=True)
def _line_fit(x, h, sel):
    """Least squares ``h = a + b x`` over ``sel``: (ok, a, b, cov00)."""
    n = 0
    sx = sxx = sh = sxh = 0.0
    for i in range(x.size):
        if sel[i]:
            n += 1
            sx += x[i]
            sxx += x[i] * x[i]
            sh += h[i]
            sxh += x[i] * h[i]
    det = n * sxx - sx * sx
    if n < 2 or not det > 1e-12 * _pmax(1.0, n * sxx):
        return False, 0.0, 0.0, 0.0
    a = (sxx * sh - sx * sxh) / det
    b = (n * sxh - sx * sh) / det
    return True, a, b, sxx / det


@numba.njit(cache=True, nogil=True)
def _lerp(a, b, t):
    """numpy's percentile interpolation (the form it switches to for t >= 0.5)."""
    d = b - a
    return b - d * (1.0 - t) if t >= 0.5 else a + d * t


@numba.njit(cache=True, nogil=True)
def _iqr(rs, iqr_scale):
    """(75th - 25th percentile) / iqr_scale of sorted ``rs``, numpy's linear method."""
    n = rs.size
    pos = 0.75 * (n - 1)
    k = int(math.floor(pos))
    q75 = _lerp(rs[k], rs[min(k + 1, n - 1)], pos - k)
    pos = 0.25 * (n - 1)
    k = int(math.floor(pos))
    q25 = _lerp(rs[k], rs[min(k + 1, n - 1)], pos - k)
    return (q75 - q25) / iqr_scale


@numba.njit(cache=True, nogil=True)
def _robust_spread(rs, n_background, lo, hi, iqr_scale):
    """:func:`lidar_mitsuba.products.first_photon_bias.robust_spread` of the residuals ``rs``,
    sorted (:func:`~lidar_mitsuba.products.atl06.sorting.sort`)."""
    n = rs.size
    if n == 0:
        return np.nan
    n_sig = n - n_background
    if n_sig <= 0 or n < 4 or hi <= lo:
        return _iqr(rs, iqr_scale)
    i0 = 0
    i1 = n - 1
    found_above = False
    for i in range(n):
        s = i + 0.5 - n_background * (rs[i] - lo) / (hi - lo)
        if s < 0.25 * n_sig:
            i0 = i
        if not found_above and s > 0.75 * n_sig:
            i1 = i
            found_above = True
    sigma = (rs[i1] - rs[i0]) / iqr_scale
    if not sigma > 0:
        sigma = _iqr(rs, iqr_scale)
    return sigma


@numba.njit(cache=True, nogil=True)
def _lambert_w0(z):
    """Principal branch W0(z) for z in [-1/e, 0] (Halley's iteration)."""
    if z == 0.0:
        return 0.0
    p = math.sqrt(2.0 * (math.e * z + 1.0))
    w = -1.0 + p - p * p / 3.0 + 11.0 / 72.0 * p * p * p     # series about the branch point
    if z > -0.25:
        w = z * (1.0 - z)                                    # small |z|
    for _ in range(100):
        ew = math.exp(w)
        f = w * ew - z
        wp1 = w + 1.0
        if wp1 == 0.0:
            break
        step = f / (ew * wp1 - (w + 2.0) * f / (2.0 * wp1))
        w -= step
        if abs(step) <= 1e-15 * (1.0 + abs(w)):
            break
    return w


@numba.njit(cache=True, nogil=True)
def _corrected_background_mhz(observed, n_channels, dead_time_ns, paralyzable):
    """:func:`lidar_mitsuba.products.first_photon_bias.corrected_background_mhz`."""
    if observed <= 0 or dead_time_ns <= 0:
        return observed
    ro = observed * 1e-3 / n_channels
    x = ro * dead_time_ns
    if paralyzable:
        if x >= 1.0 / math.e:
            return np.nan
        r = -_lambert_w0(-x) / dead_time_ns
    else:
        if x >= 1.0:
            return np.nan
        r = ro / (1.0 - x)
    return r * n_channels * 1e3


@numba.njit(cache=True, nogil=True)
def _background(x_shot, gate_c, has_gate, a, b, r_all, excl, cfg):
    """:func:`lidar_mitsuba.products.atl06.reference._background`: (n_out, exposure [ns], rate [MHz])."""
    gate_m, half_c = cfg[_GATE_M], cfg[_HALF_C]
    n_out = 0
    for i in range(r_all.size):
        if abs(r_all[i]) >= excl:
            n_out += 1
    if not has_gate:
        exposure_m = x_shot.size * _pmax(0.0, gate_m - 2.0 * excl)
    else:
        exposure_m = 0.0
        for i in range(x_shot.size):
            line = a + b * x_shot[i]
            g0 = gate_c[i] - gate_m / 2.0
            g1 = gate_c[i] + gate_m / 2.0
            overlap = min(line + excl, g1) - max(line - excl, g0)
            exposure_m += gate_m - (overlap if overlap > 0.0 else 0.0)
    exposure_ns = exposure_m / half_c
    if exposure_ns <= 0:
        return n_out, 0.0, np.nan
    observed = n_out / exposure_ns * 1e3
    return n_out, exposure_ns, _corrected_background_mhz(
        observed, int(cfg[_N_CHANNELS]), cfg[_DEAD_TIME_NS], cfg[_PARALYZABLE] != 0.0)


@numba.njit(cache=True, nogil=True)
def _weighted_median_minus_uniform(rs, ws, n_bg, half_w):
    """:func:`lidar_mitsuba.products.first_photon_bias.weighted_median_minus_uniform` of the
    residuals ``rs`` in their stable order and their weights ``ws`` in the same order."""
    total = ws.sum() - n_bg
    if not total > 0:
        return np.nan
    target = 0.5 * total
    c = 0.0
    prev = 0.0
    for k in range(rs.size):
        c += ws[k]
        cdf = c - 0.5 * ws[k] - n_bg * (rs[k] + half_w) / (2.0 * half_w)
        if cdf >= target:
            if k == 0:
                return rs[0]
            f = (target - prev) / (cdf - prev) if cdf > prev else 0.5
            return rs[k - 1] + f * (rs[k] - rs[k - 1])
        prev = cdf
    return rs[rs.size - 1]


@numba.njit(cache=True, nogil=True)
def _span_ok(x, sel, min_photons, min_span_m):
    """``count(sel) >= min_photons and ptp(x[sel]) >= min_span_m``, and the count."""
    n, lo, hi = 0, np.inf, -np.inf
    for i in range(x.size):
        if sel[i]:
            n += 1
            lo = min(lo, x[i])
            hi = max(hi, x[i])
    return n >= min_photons and n > 0 and hi - lo >= min_span_m, n


@numba.njit(cache=True, nogil=True)
def _background_per_m(bg, n_pulses, half_c):
    """:func:`lidar_mitsuba.products.atl06.reference._background_per_m`."""
    return bg * 1e-3 / half_c * n_pulses


@numba.njit(cache=True, nogil=True)
def _exclusion(win, sig_r, dead_m, w0):
    """:func:`lidar_mitsuba.products.atl06.reference._exclusion`."""
    s = _pmin(sig_r, 5.0) if math.isfinite(sig_r) else 0.0
    return _pmax(_pmax(win / 2.0, w0 / 2.0), 5.0 * s) + dead_m


@numba.njit(cache=True, nogil=True)
def _densest_window(h, w0):
    """:func:`lidar_mitsuba.products.atl06.reference._densest_window` (photons all within
    ``w0`` of the lowest: the first window holds them all, and no sort is needed)."""
    if h.size and not has_nan(h) and h.max() <= h.min() + w0:
        return (h >= h.min()) & (h <= h.min() + w0)
    hs, i_best, best = sort(h), 0, -1
    if has_nan(h):                 # (no order: each window's end searched for, as before)
        for i in range(hs.size):
            count = first_at_least(hs, hs[i] + w0, True) - i
            if count > best:
                best = count
                i_best = i
        return (h >= hs[i_best]) & (h <= hs[i_best] + w0)
    end = 0
    for i in range(hs.size):                   # the first fullest window [hs[i], hs[i] + w0]
        top = hs[i] + w0
        while end < hs.size and hs[end] <= top:    # (the windows' ends only move up)
            end += 1
        if end - i > best:
            best = end - i
            i_best = i
    return (h >= hs[i_best]) & (h <= hs[i_best] + w0)


@numba.njit(cache=True, nogil=True)
def _first_window(x, h, x_shot, gate_c, has_gate, sel, cfg):
    """:func:`lidar_mitsuba.products.atl06.reference._first_window`, the selection ``sel`` updated in
    place (an array returned in a tuple costs reference counting on every call): (ok, W,
    sigma_r, bckgrd); sigma_r 0 where its exact value below w0 / 10 changes nothing."""
    ok, a, b, _ = _line_fit(x, h, sel)
    if not ok:
        return False, 0.0, 0.0, 0.0
    w0, half_c = cfg[_W0], cfg[_HALF_C]
    r_all = h - (a + b * x)
    dead_m = cfg[_DEAD_TIME_NS] * half_c
    _, _, bg = _background(x_shot, gate_c, has_gate, a, b, r_all, w0 / 2.0 + dead_m, cfg)
    if not math.isfinite(bg):
        bg = 0.0
    sigma_exp = math.hypot(cfg[_SIGMA_PULSE_M], cfg[_FOOTPRINT_SIGMA_M] * b)
    r0 = r_all[sel]
    lo, iqr_scale = r0.min(), cfg[_IQR_SCALE]
    # sigma_r is at most the residuals' span / IQR per sigma: under w0 / 10 (twice over),
    # neither W nor the refinement's first exclusion zone depends on it, nor its sort is done
    sig_r = 0.0 if (r0.max() - lo) * 2.0 <= w0 / 10.0 * iqr_scale else _robust_spread(
        sort(r0), _background_per_m(bg, x_shot.size, half_c) * w0, lo, lo + w0, iqr_scale)
    win = _pmax(w0, 6.0 * _pmax(_pmin(sig_r, 5.0), sigma_exp))
    new = np.abs(r_all) < win / 2.0
    if _span_ok(x, new, int(cfg[_MIN_PHOTONS]), cfg[_MIN_SPAN_M])[0]:
        sel[:] = new
    return True, win, sig_r, bg


@numba.njit(cache=True, nogil=True)
def _refine_window(x, h, x_shot, gate_c, has_gate, sel, win, sig_r, bg, cfg):
    """:func:`lidar_mitsuba.products.atl06.reference._refine_window`, the selection ``sel`` updated
    in place: (W, bckgrd, iterations, converged, ``fresh``: ``sel`` is still its last line's
    selection, then the final line, and that line: a, b, cov00, residuals, and its selection's
    residuals sorted and their stable order: :func:`.sorting.sort_and_order`)."""
    n_pulses, half_c, iqr_scale = x_shot.size, cfg[_HALF_C], cfg[_IQR_SCALE]
    dead_m = cfg[_DEAD_TIME_NS] * half_c
    min_photons, min_span_m = int(cfg[_MIN_PHOTONS]), cfg[_MIN_SPAN_M]
    bg_per_m = _background_per_m(bg, n_pulses, half_c)
    it = 0
    converged = fresh = False
    a = b = cov00 = 0.0
    rs, r_all, order = np.empty(0), np.empty(0), np.empty(0, np.int64)
    for it in range(1, int(cfg[_MAX_ITERATIONS]) + 1):
        ok, a, b, cov00 = _line_fit(x, h, sel)
        if not ok:
            fresh = False
            break
        r_all = h - (a + b * x)
        r0 = r_all[sel]
        excl = _exclusion(win, sig_r, dead_m, cfg[_W0])
        _, _, bg_i = _background(x_shot, gate_c, has_gate, a, b, r_all, excl, cfg)
        if math.isfinite(bg_i):
            bg = bg_i
            bg_per_m = _background_per_m(bg, n_pulses, half_c)
        (rs, order), fresh = sort_and_order(r0), True
        sig_r = _pmin(5.0, _robust_spread(rs, bg_per_m * win, -win / 2.0, win / 2.0,
                                          iqr_scale))
        sigma_exp = math.hypot(cfg[_SIGMA_PULSE_M], cfg[_FOOTPRINT_SIGMA_M] * b)
        win_new = _pmax(_pmax(_pmax(6.0 * sigma_exp, 6.0 * sig_r), 0.75 * win),
                        cfg[_MIN_WINDOW_M])
        new = np.abs(r_all) < win_new / 2.0
        if not _span_ok(x, new, min_photons, min_span_m)[0]:
            break                                   # keep the previous selection and window
        win = win_new
        if np.array_equal(new, sel):
            converged = True
            break
        sel[:] = new
        fresh = False
    return win, bg, it, converged, fresh, (a, b, cov00, r_all, rs, order)


@numba.njit(cache=True, nogil=True)
def _final_spread_and_background(x_shot, gate_c, has_gate, a, b, r_all, rs, win, bg, cfg):
    """:func:`lidar_mitsuba.products.atl06.reference._final_spread_and_background` (``rs``:
    the final residuals sorted): (sigma_r, n_bg_out, exposure [ns], bckgrd)."""
    half_c = cfg[_HALF_C]
    sig_r = _robust_spread(rs, _background_per_m(bg, x_shot.size, half_c) * win, -win / 2.0,
                           win / 2.0, cfg[_IQR_SCALE])
    excl = _exclusion(win, sig_r, cfg[_DEAD_TIME_NS] * half_c, cfg[_W0])
    n_bg_out, exposure_ns, bg_final = _background(x_shot, gate_c, has_gate, a, b, r_all, excl,
                                                  cfg)
    if math.isfinite(bg_final):
        bg = bg_final
    return sig_r, n_bg_out, exposure_ns, bg


@numba.njit(cache=True, nogil=True)
def _formal_errors(r0, b, cov00, win, n_bg_out, exposure_ns, n_pulses, cfg):
    """:func:`lidar_mitsuba.products.atl06.reference._formal_errors`: (expected noise photons,
    h_rms_misfit, sigma_h_mean)."""
    half_c = cfg[_HALF_C]
    bg_obs_mhz = n_bg_out / exposure_ns * 1e3 if exposure_ns > 0 else 0.0
    n_fit = r0.size
    n_noise_obs = bg_obs_mhz * 1e-3 * (win / half_c) * n_pulses
    n_sig = _pmax(0.0, n_fit - n_noise_obs)
    sigma_exp = math.hypot(cfg[_SIGMA_PULSE_M], cfg[_FOOTPRINT_SIGMA_M] * b)
    h_rms = math.sqrt(np.mean(r0 ** 2))
    sigma_photon_est = math.sqrt((n_noise_obs * (win / math.sqrt(12.0)) ** 2
                                  + n_sig * sigma_exp ** 2) / n_fit)
    return n_noise_obs, h_rms, math.sqrt(cov00) * _pmax(sigma_photon_est, h_rms)


@numba.njit(cache=True, nogil=True)
def _first_photon_bias(r_all, win, bg, n_pulses, cfg, sel, sel_order):
    """:func:`lidar_mitsuba.products.atl06.reference._first_photon_bias`: (fpb_corr_m,
    fpb_corr_sigma_m, fpb_med_corr_m, fpb_gain, fpb_min_alive, fpb_n_corr, flags);
    ``sel_order``: ``r_all[sel]``'s stable order where known (else empty: no merge)."""
    n_channels, dead_time_ns, half_c = int(cfg[_N_CHANNELS]), cfg[_DEAD_TIME_NS], cfg[_HALF_C]
    dead_m = dead_time_ns * half_c
    ext = (r_all > -win / 2.0) & (r_all < win / 2.0 + 2.0 * dead_m)
    r_ext = r_all[ext]
    order = (merged_order(r_all, ext, sel, sel_order, r_ext) if sel_order.size  # (no NaN in
             else argsort(r_ext))                                     # r_ext: 2 comparisons)
    if cfg[_PARALYZABLE] != 0.0:
        w_ext, ok_w = _dead_time_weights(-r_ext / half_c, n_pulses, n_channels, dead_time_ns,
                                         True)
    else:
        w_ext, ok_w = _dead_time_weights_ordered(r_ext, order, n_pulses, n_channels,
                                                 dead_time_ns, half_c), True
    in_win = np.abs(r_ext) < win / 2.0
    n_bg_true = (bg if math.isfinite(bg) else 0.0) * 1e-3 * (win / half_c) * n_pulses
    # (the window's photons in order: the sums of numba's ww.sum(), np.sum(ww * rw), np.mean(rw))
    m, w_sum, wr_sum, r_sum = 0, 0.0, 0.0, 0.0
    min_alive, any_finite, all_finite = np.inf, False, True
    for e in range(r_ext.size):
        if in_win[e]:
            w, r = w_ext[e], r_ext[e]
            m, w_sum, wr_sum, r_sum = m + 1, w_sum + w, wr_sum + w * r, r_sum + r
            alive = 1.0 / w
            if math.isfinite(alive):
                any_finite = True
            if not math.isnan(alive):
                min_alive = min(min_alive, alive)
            if not math.isfinite(w):
                all_finite = False
    n_corr, min_alive = w_sum - n_bg_true, min_alive if any_finite else np.nan
    gain = w_sum / m if m else np.nan
    centroid = wr_sum / n_corr if n_corr > 0 else np.nan
    fpb_corr = centroid - (r_sum / m if m else np.nan)
    fpb_sigma = np.nan
    if n_corr > 0:                     # (np.sum((ww * (rw - centroid)) ** 2), in one pass)
        d2 = 0.0
        for e in range(r_ext.size):
            if in_win[e]:
                d = w_ext[e] * (r_ext[e] - centroid)
                d2 += d * d
        fpb_sigma = math.sqrt(d2) / n_corr
    fpb_med = np.nan
    if all_finite:                 # the window's photons in their stable order (rw's argsort)
        rs, ws = np.empty(m), np.empty(m)
        k = 0
        for e in order:
            if in_win[e]:
                rs[k], ws[k] = r_ext[e], w_ext[e]
                k += 1
        fpb_med = _weighted_median_minus_uniform(rs, ws, n_bg_true, win / 2.0)
    flags = 0
    if not (ok_w and all_finite and n_corr > 0 and math.isfinite(fpb_corr)):
        flags |= _FPB_DIVERGED
    if not (min_alive * n_pulses * n_channels >= cfg[_MIN_ALIVE_PULSES]):
        flags |= _FPB_DEAD
    if not (gain <= cfg[_MAX_GAIN]):
        flags |= _FPB_GAIN
    return fpb_corr, fpb_sigma, fpb_med, gain, min_alive, n_corr, flags


@numba.njit(cache=True, nogil=True)
def fit_segment(x, h, x_shot, gate_c, has_gate, cfg, out):
    """:func:`lidar_mitsuba.products.atl06.reference.fit_segment` into ``out`` (its
    :data:`OUT_FIELDS` row, pre-filled with the table's defaults). ``cfg``: float64 array of
    :data:`CFG_FIELDS`, then half c [m/ns] and the IQR per sigma."""
    n_pulses = x_shot.size
    out[_N_PULSES] = n_pulses
    out[_FLAGS] = 0
    if x.size < int(cfg[_MIN_PHOTONS]) or n_pulses == 0:
        out[_FLAGS] = _TOO_FEW
        out[_N_FIT] = x.size
        return
    sel = _densest_window(h, cfg[_W0])
    good, n_sel = _span_ok(x, sel, int(cfg[_MIN_PHOTONS]), cfg[_MIN_SPAN_M])
    if not good:
        out[_FLAGS] = _TOO_FEW
        out[_N_FIT] = n_sel
        return
    ok, win, sig_r, bg = _first_window(x, h, x_shot, gate_c, has_gate, sel, cfg)
    if not ok:
        out[_FLAGS] = _TOO_FEW
        return
    win, bg, it, converged, fresh, last = _refine_window(x, h, x_shot, gate_c, has_gate, sel,
                                                         win, sig_r, bg, cfg)
    flags = 0
    if not converged and it >= int(cfg[_MAX_ITERATIONS]):
        flags |= _NOT_CONVERGED
    if fresh:          # the final line is the last iteration's (sel is still its selection)
        a, b, cov00, r_all, rs, order = last
    else:
        ok, a, b, cov00 = _line_fit(x, h, sel)                     # the final line
        if not ok:
            out[_FLAGS] = flags | _TOO_FEW
            return
        r_all, order = h - (a + b * x), np.empty(0, np.int64)
    r0 = r_all[sel]
    n_fit = r0.size
    if not fresh:
        rs = sort(r0)
    sig_r, n_bg_out, exposure_ns, bg = _final_spread_and_background(
        x_shot, gate_c, has_gate, a, b, r_all, rs, win, bg, cfg)
    n_noise_obs, h_rms, sigma_h_mean = _formal_errors(r0, b, cov00, win, n_bg_out, exposure_ns,
                                                      n_pulses, cfg)
    fpb_corr, fpb_sigma, fpb_med, gain, min_alive, n_corr, fpb_flags = _first_photon_bias(
        r_all, win, bg, n_pulses, cfg, sel, order)
    flags |= fpb_flags
    snr = (n_fit - n_noise_obs) / n_noise_obs if n_noise_obs > 0 else np.inf
    if n_fit - n_noise_obs < 5.0 * math.sqrt(_pmax(n_noise_obs, 1.0)):
        flags |= _LOW_SNR
    h_li = a + fpb_corr
    h_li_sigma = _pmax(sigma_h_mean, fpb_sigma) if math.isfinite(fpb_sigma) else sigma_h_mean
    if not (sig_r < 1.0 and h_li_sigma < 1.0):
        flags |= _LARGE_SPREAD
    out[_H_LI], out[_H_LI_SIGMA], out[_H_MEAN], out[_SIGMA_H_MEAN] = (h_li, h_li_sigma, a,
                                                                       sigma_h_mean)
    out[_DH], out[_SPRD], out[_RMS], out[_N_FIT] = b, sig_r, h_rms, n_fit
    out[_WIN], out[_EXIT], out[_BG], out[_BG_N], out[_BG_EXP] = (win, it, bg, n_bg_out,
                                                                 exposure_ns)
    out[_FPB], out[_FPB_SIGMA], out[_FPB_MED], out[_GAIN] = fpb_corr, fpb_sigma, fpb_med, gain
    out[_MIN_ALIVE], out[_N_CORR], out[_SNR], out[_FLAGS] = min_alive, n_corr, snr, flags


@numba.njit(cache=True, nogil=True)
def fit_all(along, h, shot_along, gate, has_gate, centres, p0, p1, s0, s1, cfg, out):
    """Every segment: photons ``p0[k]:p1[k]`` of ``along``/``h`` and shots ``s0[k]:s1[k]``
    of ``shot_along``/``gate`` about centre ``centres[k]``, into ``out[k]`` (pre-filled)."""
    for k in range(centres.size):
        c = centres[k]
        fit_segment(along[p0[k]:p1[k]] - c, h[p0[k]:p1[k]], shot_along[s0[k]:s1[k]] - c,
                    gate[s0[k]:s1[k]], has_gate, cfg, out[k])


@numba.njit(cache=True, nogil=True)
def reference_heights(shot_along, z_ref, centres, s0, s1, out):
    """:func:`lidar_mitsuba.products.atl06._fill_reference_heights` compiled: per segment ``k``
    (shots ``s0[k]:s1[k]``), the least-squares line through ``z_ref`` [m] at ``centres[k]``
    [m] (their mean when singular), into ``out[k]``; segments without shots are left alone.
    The sums are numpy's (:func:`lidar_mitsuba.numeric.pairwise_sum`), so the column is the
    numpy loop's to the bit."""
    for k in range(centres.size):
        a = s0[k]
        n = s1[k] - a
        if n < 1:
            continue
        c = centres[k]
        x, xx, xh = np.empty(n), np.empty(n), np.empty(n)
        for i in range(n):
            x[i] = shot_along[a + i] - c
            xx[i] = x[i] * x[i]
            xh[i] = x[i] * z_ref[a + i]
        sx = pairwise_sum(x, 0, n)
        sxx = pairwise_sum(xx, 0, n)
        sh = pairwise_sum(z_ref, a, n)
        det = n * sxx - sx * sx
        if n < 2 or not det > 1e-12 * _pmax(1.0, n * sxx):
            out[k] = sh / n
        else:
            out[k] = (sxx * sh - sx * pairwise_sum(xh, 0, n)) / det
