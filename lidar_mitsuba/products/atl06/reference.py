"""The ATL06 fit of one segment in plain numpy: the readable reference of the algorithm that
the module docstring of :mod:`lidar_mitsuba.products.atl06` describes.

In the data flow, :func:`lidar_mitsuba.products.atl06.fit_segments` cuts the track into segments and
hands each one's photons and pulses, in the segment's frame, to :func:`fit_segment` here
(``engine="reference"``) or to its numba twin :func:`lidar_mitsuba.products.atl06.kernel.fit_segment`,
which follows the same steps in the same order (the tests compare every column of the two):

1. :func:`_densest_window`: the ``initial_window_m`` of heights holding the most photons;
2. :func:`_first_window`: a line through them, a preliminary background and spread, and the
   first window about that line;
3. :func:`_refine_window`: the iterated line, background, spread and window;
4. the final line (in :func:`fit_segment`), and :func:`_final_spread_and_background`: its
   spread and the background outside it;
5. :func:`_formal_errors` and :func:`_first_photon_bias` (with its flags); heights, the
   signal-to-noise ratio and the remaining flags in :func:`fit_segment` itself.

Lengths are metres along track (``x``, from the segment centre) and of height (``h``, ``r``);
times are ns of round trip.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .table import FLAG_BITS
from ...constants import C_M_PER_NS
from ..first_photon_bias import (corrected_background_mhz, dead_time_weights, robust_spread,
                                 weighted_median_minus_uniform)

HALF_C = C_M_PER_NS / 2.0   # metres of height per ns of round-trip time


@dataclass(frozen=True)
class Config:
    """The settings of one track's fit (:func:`lidar_mitsuba.products.atl06.fit_segments` documents
    them); ``sigma_pulse_m`` [m] is the pulse sigma in height, ``min_span_m`` [m] the shortest
    along-track span of a selection (half a segment)."""
    n_channels: int
    dead_time_ns: float
    paralyzable: bool
    sigma_pulse_m: float
    footprint_sigma_m: float
    gate_m: float
    initial_window_m: float
    min_window_m: float
    max_iterations: int
    min_photons: int
    min_span_m: float
    min_alive_pulses: float
    max_gain: float


def line_fit(x: np.ndarray, h: np.ndarray):
    """Least-squares ``h = a + b x``; returns (a, b, cov00) or None when singular, ``cov00``
    the intercept's element of ``(G^T G)^-1`` (the rest is never used)."""
    n = x.size
    sx, sxx = x.sum(), (x * x).sum()
    det = n * sxx - sx * sx
    if n < 2 or not det > 1e-12 * max(1.0, n * sxx):
        return None
    sh, sxh = h.sum(), (x * h).sum()
    a = (sxx * sh - sx * sxh) / det
    b = (n * sxh - sx * sh) / det
    return a, b, sxx / det


def _exclusion(win, sig_r, dead_m, cfg: Config) -> float:
    """Half-height of the zone about the line left out of the background count:
    ``max(W / 2, initial_window_m / 2, 5 sigma_r) + c tau / 2``. Not just ``W / 2``: where the
    refinement stops depends on whether photons lie near the window's edge (it stops when the
    band it would cut is empty), and counting outside that edge overestimated the background by
    ~3 % at 1 MHz."""
    s = min(sig_r, 5.0) if np.isfinite(sig_r) else 0.0
    return max(win / 2.0, cfg.initial_window_m / 2.0, 5.0 * s) + dead_m


def _background(x_shot, gate_c, a, b, r_all, excl, n_pulses, cfg: Config):
    """(observed count, exposure [ns], dead-time corrected rate [MHz]) outside ``|r| < excl``."""
    n_out = int(np.count_nonzero(np.abs(r_all) >= excl))
    if gate_c is None:
        exposure_m = n_pulses * max(0.0, cfg.gate_m - 2.0 * excl)
    else:
        line = a + b * x_shot
        g0, g1 = gate_c - cfg.gate_m / 2.0, gate_c + cfg.gate_m / 2.0
        overlap = np.clip(np.minimum(line + excl, g1) - np.maximum(line - excl, g0), 0.0, None)
        exposure_m = float(np.sum(cfg.gate_m - overlap))
    exposure_ns = exposure_m / HALF_C
    if exposure_ns <= 0:
        return n_out, 0.0, float("nan")
    observed = n_out / exposure_ns * 1e3
    return n_out, exposure_ns, corrected_background_mhz(
        observed, n_channels=cfg.n_channels, dead_time_ns=cfg.dead_time_ns,
        paralyzable=cfg.paralyzable)


def _background_per_m(bg_mhz: float, n_pulses: int) -> float:
    """Background photons per metre of window height over the segment's pulses."""
    return bg_mhz * 1e-3 / HALF_C * n_pulses


def _enough_photons(x, sel, cfg: Config) -> bool:
    """Whether the selection ``sel`` holds ``min_photons`` spanning ``min_span_m`` along track."""
    return np.count_nonzero(sel) >= cfg.min_photons and np.ptp(x[sel]) >= cfg.min_span_m


def _densest_window(h, cfg: Config) -> np.ndarray:
    """(n,) bool: the photons in the first of the fullest ``initial_window_m`` height
    intervals ``[h_i, h_i + initial_window_m]`` starting at a photon."""
    hs = np.sort(h)
    w0 = cfg.initial_window_m
    counts = np.searchsorted(hs, hs + w0, side="right") - np.arange(hs.size)
    i_best = int(np.argmax(counts))
    return (h >= hs[i_best]) & (h <= hs[i_best] + w0)


def _first_window(x, h, x_shot, gate_c, sel, cfg: Config):
    """A line through the densest window's photons ``sel``; the background outside the
    initial window (plus a dead time), the photons' robust spread about the line and the
    first window ``W = max(initial_window_m, 6 max(sigma_r, sigma_expected))``, whose photons
    replace ``sel`` when there are enough of them. Returns ``(sel, W [m], sigma_r [m],
    bckgrd [MHz])``, or None when the line is singular."""
    fit = line_fit(x[sel], h[sel])
    if fit is None:
        return None
    a, b, _ = fit
    n_pulses = x_shot.size
    w0 = cfg.initial_window_m
    r_all = h - (a + b * x)
    dead_m = cfg.dead_time_ns * HALF_C
    _, _, bg = _background(x_shot, gate_c, a, b, r_all, w0 / 2.0 + dead_m, n_pulses, cfg)
    bg = 0.0 if not np.isfinite(bg) else bg
    sigma_exp = math.hypot(cfg.sigma_pulse_m, cfg.footprint_sigma_m * b)
    r0 = r_all[sel]
    sig_r = robust_spread(r0, n_background=_background_per_m(bg, n_pulses) * w0,
                          window=(r0.min(), r0.min() + w0))
    win = max(w0, 6.0 * max(min(sig_r, 5.0), sigma_exp))
    new = np.abs(r_all) < win / 2.0
    if _enough_photons(x, new, cfg):
        sel = new
    return sel, win, sig_r, bg


def _refine_window(x, h, x_shot, gate_c, sel, win, sig_r, bg, cfg: Config):
    """At most ``max_iterations`` rounds of: line through ``sel``, background outside the
    exclusion zone, robust spread in the window, new window ``max(6 sigma_expected,
    6 sigma_r, 0.75 W, min_window_m)``; stops when the selection repeats, or keeps the last
    one when the new one has too few photons. Returns ``(sel, W [m], bckgrd [MHz],
    iterations, converged)``."""
    n_pulses = x_shot.size
    dead_m = cfg.dead_time_ns * HALF_C
    bg_per_m = _background_per_m(bg, n_pulses)
    it = 0
    converged = False
    for it in range(1, cfg.max_iterations + 1):
        fit = line_fit(x[sel], h[sel])
        if fit is None:
            break
        a, b, _ = fit
        r_all = h - (a + b * x)
        r0 = r_all[sel]
        excl = _exclusion(win, sig_r, dead_m, cfg)
        _, _, bg_i = _background(x_shot, gate_c, a, b, r_all, excl, n_pulses, cfg)
        if np.isfinite(bg_i):
            bg = bg_i
            bg_per_m = _background_per_m(bg, n_pulses)
        sig_r = min(5.0, robust_spread(r0, n_background=bg_per_m * win,
                                       window=(-win / 2.0, win / 2.0)))
        sigma_exp = math.hypot(cfg.sigma_pulse_m, cfg.footprint_sigma_m * b)
        win_new = max(6.0 * sigma_exp, 6.0 * sig_r, 0.75 * win, cfg.min_window_m)
        new = np.abs(r_all) < win_new / 2.0
        if not _enough_photons(x, new, cfg):
            break                                   # keep the previous selection and window
        win = win_new
        if np.array_equal(new, sel):
            converged = True
            break
        sel = new
    return sel, win, bg, it, converged


def _final_spread_and_background(x_shot, gate_c, a, b, r_all, r0, win, bg, cfg: Config):
    """About the final line ``h = a + b x`` (residuals ``r_all``, ``r0`` those selected): the
    robust spread in the window ``W`` and the background outside the exclusion zone. Returns
    ``(sigma_r [m], n_bg_out, exposure [ns], bckgrd [MHz])``, ``bckgrd`` the last finite
    estimate."""
    n_pulses = x_shot.size
    sig_r = robust_spread(r0, n_background=_background_per_m(bg, n_pulses) * win,
                          window=(-win / 2.0, win / 2.0))
    excl = _exclusion(win, sig_r, cfg.dead_time_ns * HALF_C, cfg)
    n_bg_out, exposure_ns, bg_final = _background(x_shot, gate_c, a, b, r_all, excl, n_pulses,
                                                  cfg)
    if np.isfinite(bg_final):
        bg = bg_final
    return sig_r, n_bg_out, exposure_ns, bg


def _formal_errors(r0, b, cov00, win, n_bg_out, exposure_ns, n_pulses, cfg: Config):
    """The ATBD's formal error of ``h_mean``: ``sigma_photon_est`` from the expected noise
    and signal spreads in the window, scaled by the intercept's least-squares variance
    ``cov00``; ``r0`` the window's residuals [m]. Returns ``(expected noise photons in the
    window, h_rms_misfit [m], sigma_h_mean [m])``."""
    bg_obs_mhz = n_bg_out / exposure_ns * 1e3 if exposure_ns > 0 else 0.0
    n_fit = r0.size
    n_noise_obs = bg_obs_mhz * 1e-3 * (win / HALF_C) * n_pulses
    n_sig = max(0.0, n_fit - n_noise_obs)
    sigma_exp = math.hypot(cfg.sigma_pulse_m, cfg.footprint_sigma_m * b)
    h_rms = float(np.sqrt(np.mean(r0 ** 2)))
    sigma_photon_est = math.sqrt((n_noise_obs * (win / math.sqrt(12.0)) ** 2
                                  + n_sig * sigma_exp ** 2) / n_fit)
    return n_noise_obs, h_rms, math.sqrt(cov00) * max(sigma_photon_est, h_rms)


def _first_photon_bias(r_all, win, bg, n_pulses, cfg: Config) -> tuple[dict, int]:
    """The first-photon-bias correction of the window's residuals (:mod:`lidar_mitsuba.products.first_photon_bias`):
    window photons plus those up to two dead times earlier (higher) are weighted by the
    inverse of the fraction of channel-pulses alive, and the background (``bg`` [MHz]) is
    subtracted. Returns the ``fpb_*`` columns and the flags ``fpb_diverged``, ``fpb_dead``
    and ``fpb_gain`` they raise."""
    dead_m = cfg.dead_time_ns * HALF_C
    ext = (r_all > -win / 2.0) & (r_all < win / 2.0 + 2.0 * dead_m)
    r_ext = r_all[ext]
    w_ext, ok = dead_time_weights(-r_ext / HALF_C, n_pulses=n_pulses, n_channels=cfg.n_channels,
                                  dead_time_ns=cfg.dead_time_ns, paralyzable=cfg.paralyzable)
    in_win = np.abs(r_ext) < win / 2.0
    rw, ww = r_ext[in_win], w_ext[in_win]
    n_bg_true = (bg if np.isfinite(bg) else 0.0) * 1e-3 * (win / HALF_C) * n_pulses
    n_corr = float(ww.sum() - n_bg_true)
    alive = 1.0 / ww
    min_alive = float(np.nanmin(alive)) if np.any(np.isfinite(alive)) else float("nan")
    gain = float(ww.sum() / rw.size) if rw.size else float("nan")
    with np.errstate(invalid="ignore", divide="ignore"):
        centroid = float(np.sum(ww * rw) / n_corr) if n_corr > 0 else float("nan")
        fpb_corr = centroid - float(np.mean(rw))
        fpb_sigma = float(np.sqrt(np.sum((ww * (rw - centroid)) ** 2)) / n_corr) \
            if n_corr > 0 else float("nan")
    fpb_med = (weighted_median_minus_uniform(rw, ww, n_bg=n_bg_true, half_w=win / 2.0)
               if np.all(np.isfinite(ww)) else float("nan"))
    flags = 0
    if not (ok and np.all(np.isfinite(ww)) and n_corr > 0 and np.isfinite(fpb_corr)):
        flags |= FLAG_BITS["fpb_diverged"]
    if not (min_alive * n_pulses * cfg.n_channels >= cfg.min_alive_pulses):
        flags |= FLAG_BITS["fpb_dead"]
    if not (gain <= cfg.max_gain):
        flags |= FLAG_BITS["fpb_gain"]
    return dict(fpb_corr_m=fpb_corr, fpb_corr_sigma_m=fpb_sigma, fpb_med_corr_m=fpb_med,
                fpb_gain=gain, fpb_min_alive=min_alive, fpb_n_corr=n_corr), flags


def fit_segment(x, h, x_shot, gate_c, cfg: Config) -> dict:
    """Fit one segment: photons at along-track offsets ``x`` [m] (from the centre) and heights
    ``h`` [m], both (n,); ``x_shot`` (n_pulses,) the offsets of its pulses [m]; ``gate_c``
    their gate centres [m] or None. Returns the segment's :class:`~lidar_mitsuba.products.atl06.
    SegmentTable` columns by name (those it leaves out keep their defaults)."""
    n_pulses = x_shot.size
    out = {"n_seg_pulses": n_pulses, "flags": 0}
    too_few = FLAG_BITS["too_few_photons"]
    if x.size < cfg.min_photons or n_pulses == 0:
        out.update(flags=too_few, n_fit_photons=int(x.size))
        return out
    sel = _densest_window(h, cfg)
    if not _enough_photons(x, sel, cfg):
        out.update(flags=too_few, n_fit_photons=int(np.count_nonzero(sel)))
        return out
    first = _first_window(x, h, x_shot, gate_c, sel, cfg)
    if first is None:
        out["flags"] = too_few
        return out
    sel, win, sig_r, bg = first
    sel, win, bg, it, converged = _refine_window(x, h, x_shot, gate_c, sel, win, sig_r, bg, cfg)
    flags = 0
    if not converged and it >= cfg.max_iterations:
        flags |= FLAG_BITS["window_not_converged"]
    fit = line_fit(x[sel], h[sel])                             # the final line
    if fit is None:
        out["flags"] = flags | too_few
        return out
    a, b, cov00 = fit
    r_all = h - (a + b * x)
    r0 = r_all[sel]
    n_fit = r0.size
    sig_r, n_bg_out, exposure_ns, bg = _final_spread_and_background(x_shot, gate_c, a, b, r_all,
                                                                    r0, win, bg, cfg)
    n_noise_obs, h_rms, sigma_h_mean = _formal_errors(r0, b, cov00, win, n_bg_out,
                                                      exposure_ns, n_pulses, cfg)
    fpb, fpb_flags = _first_photon_bias(r_all, win, bg, n_pulses, cfg)
    flags |= fpb_flags
    snr = (n_fit - n_noise_obs) / n_noise_obs if n_noise_obs > 0 else float("inf")
    if n_fit - n_noise_obs < 5.0 * math.sqrt(max(n_noise_obs, 1.0)):
        flags |= FLAG_BITS["low_snr"]
    h_li = a + fpb["fpb_corr_m"]
    fpb_sigma = fpb["fpb_corr_sigma_m"]
    h_li_sigma = max(sigma_h_mean, fpb_sigma) if np.isfinite(fpb_sigma) else sigma_h_mean
    if not (sig_r < 1.0 and h_li_sigma < 1.0):
        flags |= FLAG_BITS["large_spread"]
    out.update(h_li=h_li, h_li_sigma=h_li_sigma, h_mean=a, sigma_h_mean=sigma_h_mean,
               dh_fit_dx=b, h_robust_sprd=sig_r, h_rms_misfit=h_rms, n_fit_photons=n_fit,
               w_surface_window_final=win, exit_iteration=it, bckgrd=bg,
               bckgrd_n_photons=n_bg_out, bckgrd_exposure_ns=exposure_ns, **fpb, snr=snr,
               flags=flags)
    return out
