"""ATL06-style land-ice surface finding and first-photon-bias correction. Pure numpy/scipy.

A simplified, documented form of the ICESat-2 ATL06 land-ice algorithm (Smith et al., ATL06
ATBD: "ATLAS/ICESat-2 L3A Land Ice Height"), run on our photons:

**Segments.** 40 m along-track segments every 20 m (50 % overlap). Segment ``k`` is centred
on ``x_atc = x0 + 20 (k + 1)`` (``x0`` the first shot's along-track position) and holds the
shots and photons with along-track position in ``[x_atc - 20, x_atc + 20)``. ``segment_id``
is ``k + 1``: the segment spans the 20 m ATL03-like geosegments ``k`` and ``k + 1`` counted
from 0 at the first shot, so ``x_atc = x0 + 20 * segment_id``.

**Surface finding** (ATBD 3.1-3.2, with the "backup" signal-finding strategy since our photons
carry no ATL03 classification):

1. initial window: the ``initial_window_m`` (10 m) height interval holding the most photons;
   an initial line fit on those photons, then the window becomes
   ``max(initial_window_m, 6 max(sigma_r, sigma_expected))`` about that line;
2. iterate (at most ``max_iterations``, 20): least-squares line ``h = h_mean + dh_fit_dx x``
   (``x`` from the segment centre) through the selected photons; residuals ``r``; the
   background-corrected robust spread ``sigma_r`` of the selected residuals (see
   :func:`robust_spread`), capped at 5 m; ``sigma_expected = sqrt(sigma_pulse_h^2 +
   (footprint_sigma * dh_fit_dx)^2)``; new window ``W = max(6 sigma_expected, 6 sigma_r,
   0.75 W_last, 3 m)`` (i.e. +-3 sigma); select ``|r| < W / 2``. Stop when the selection stops
   changing. If a new selection has fewer than 10 photons or spans less than 20 m along track,
   the previous one is kept (as the ATBD does).
3. ``h_mean``, ``dh_fit_dx`` are the final line, ``w_surface_window_final`` the final ``W``.

**Background** ``bckgrd`` [MHz]: rate of detection-eligible background photon events (i.e. after
fill factor and PDE: what an ideal detector would count) for the whole detector (all channels),
corrected for dead-time losses. Counted from the segment's photons outside an exclusion zone
about the fitted line, ``|r| < E`` with ``E = max(W / 2, initial_window_m / 2, 5 sigma_r) +
c tau / 2`` (the window, at least the initial 10 m window whose edge does not depend on where
the refinement stopped, a 5-sigma guard against signal tails, and one dead time of shadow
below the surface), inside the range gate: ``rate = n_out / (N_pulses * (gate - 2E))``, gate
and zone in time units (per-shot overlap of zone and gate when the gate centres are known).
The observed per-channel rate ``r_o = rate / C`` is then corrected for dead time:
``r = r_o / (1 - r_o tau)`` (non-paralyzable) or the root of ``r_o = r exp(-r tau)``
(paralyzable).

**First-photon-bias correction** (ATBD 3.3, event by event instead of in 25 ps bins): each
window photon is weighted by the inverse of the fraction of channel-pulses alive when it
arrived, and the weighted, background-subtracted residuals give the corrections
(:mod:`lidar_mitsuba.fpb`, whose docstring derives them):

* ``fpb_corr_m = sum(w r) / (sum(w) - N_bg) - mean(r)``, added to ``h_mean``;
* ``fpb_med_corr_m``: the median of the corrected, background-subtracted residuals;
* ``fpb_gain = sum(w) / n``, ``fpb_min_alive``, ``fpb_n_corr = sum(w) - N_bg``.

**Heights**: ``h_li = h_mean + fpb_corr_m``, mean-based because the reference ``z_ref`` is a
footprint mean; ``h_mean + fpb_med_corr_m`` is the ATBD's median-based alternative (more robust
to background, but on rough terrain, whose residuals about the line are skewed, it sits a few
mm below the mean). ``h_li_sigma = max(sigma_h_mean, fpb_corr_sigma_m)`` as in the
ATBD: ``sigma_h_mean`` is the least-squares intercept error scaled by the per-photon spread
``max(sigma_photon_est, h_rms_misfit)``, and ``fpb_corr_sigma_m`` the error of the weighted
centroid, ``sqrt(sum w^2 (r - rbar)^2) / (sum w - N_bg)``.

**Flags** (``flags`` bit mask, :data:`FLAG_BITS`); any set bit makes ``atl06_quality_summary``
1, and flagged segments stay in the table but are left out of :func:`summarize`.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import pathlib
from dataclasses import dataclass

import numpy as np

from .constants import C_M_PER_NS, FWHM_PER_SIGMA
from .fpb import (corrected_background_mhz, dead_time_weights, robust_spread,
                  weighted_median_minus_uniform)
from .resources import host_pool, host_threads

HALF_C = C_M_PER_NS / 2.0   # metres of height per ns of round-trip time

FLAG_BITS: dict[str, int] = {
    "too_few_photons": 1,      # < min_photons selected, or they span < 20 m along track
    "low_snr": 2,              # window count not 5 sigma above its expected background
    "large_spread": 4,         # h_robust_sprd >= 1 m or h_li_sigma >= 1 m (ATBD summary flag)
    "fpb_dead": 8,             # P_alive * N * C < min_alive_pulses at some window photon
    "fpb_gain": 16,            # corrected / observed count > max_gain
    "fpb_diverged": 32,        # correction non-finite, non-positive count, or no convergence
    "window_not_converged": 64,  # selection still changing after max_iterations
}
"""Reasons a segment is flagged (bits of ``SegmentTable.flags``)."""

FIELDS: dict[str, tuple[str, str]] = {
    "segment_id": ("1", "segment number: the segment spans 20 m geosegments segment_id-1 and "
                   "segment_id (from 0 at the first shot); x_atc = x0 + 20 segment_id"),
    "x_atc": ("meters", "along-track position of the segment centre"),
    "h_li": ("meters", "corrected surface height at the segment centre: h_mean + fpb_corr_m"),
    "h_li_sigma": ("meters", "formal error of h_li: max(sigma_h_mean, fpb_corr_sigma_m)"),
    "h_mean": ("meters", "least-squares line height at the segment centre, uncorrected"),
    "sigma_h_mean": ("meters", "error of h_mean (LS covariance x per-photon spread)"),
    "dh_fit_dx": ("meters/meters", "along-track slope of the fitted line"),
    "h_robust_sprd": ("meters", "background-corrected robust spread of the window residuals "
                      "(interquartile range of the signal / 1.349: a Gaussian sigma)"),
    "h_rms_misfit": ("meters", "RMS of the window residuals"),
    "n_fit_photons": ("1", "photons in the final window"),
    "n_seg_pulses": ("1", "laser pulses (shots) in the segment"),
    "w_surface_window_final": ("meters", "final surface window height W (residuals |r| < W/2)"),
    "exit_iteration": ("1", "refinement iterations run"),
    "bckgrd": ("MHz", "background rate for the whole detector: detection-eligible photon events "
               "(after fill factor and PDE) per microsecond, corrected for dead time"),
    "bckgrd_n_photons": ("1", "photons counted for bckgrd (outside the exclusion zone)"),
    "bckgrd_exposure_ns": ("ns", "gate time outside the exclusion zone, summed over pulses"),
    "fpb_corr_m": ("meters", "first-photon-bias correction added to h_mean (mean-based)"),
    "fpb_corr_sigma_m": ("meters", "error of the corrected centroid"),
    "fpb_med_corr_m": ("meters", "median of the corrected residual distribution "
                       "(median-based correction relative to h_mean)"),
    "fpb_gain": ("1", "corrected / observed photon count in the window"),
    "fpb_min_alive": ("1", "smallest probability that a channel was alive at a window photon"),
    "fpb_n_corr": ("1", "corrected signal photon count in the window (background removed)"),
    "snr": ("1", "(window count - expected background) / expected background"),
    "flags": ("1", "bit mask of reasons to distrust the segment: " + ", ".join(
        f"{v}={k}" for k, v in FLAG_BITS.items())),
    "atl06_quality_summary": ("1", "0: good, 1: flagged (flags != 0)"),
    "h_ref_m": ("meters", "truth: least-squares line of the shots' z_ref at the segment centre "
                "(NaN without truth)"),
}


@dataclass
class SegmentTable:
    """One row per 40 m segment; every attribute is an (n_segments,) array. See
    :data:`FIELDS` for units and meanings, and the module docstring for the algorithm."""
    segment_id: np.ndarray
    x_atc: np.ndarray
    h_li: np.ndarray
    h_li_sigma: np.ndarray
    h_mean: np.ndarray
    sigma_h_mean: np.ndarray
    dh_fit_dx: np.ndarray
    h_robust_sprd: np.ndarray
    h_rms_misfit: np.ndarray
    n_fit_photons: np.ndarray
    n_seg_pulses: np.ndarray
    w_surface_window_final: np.ndarray
    exit_iteration: np.ndarray
    bckgrd: np.ndarray
    bckgrd_n_photons: np.ndarray
    bckgrd_exposure_ns: np.ndarray
    fpb_corr_m: np.ndarray
    fpb_corr_sigma_m: np.ndarray
    fpb_med_corr_m: np.ndarray
    fpb_gain: np.ndarray
    fpb_min_alive: np.ndarray
    fpb_n_corr: np.ndarray
    snr: np.ndarray
    flags: np.ndarray
    atl06_quality_summary: np.ndarray
    h_ref_m: np.ndarray

    def __len__(self) -> int:
        return int(self.segment_id.size)

    @property
    def good(self) -> np.ndarray:
        """(n_segments,) bool: unflagged segments."""
        return self.atl06_quality_summary == 0

    def flag_reasons(self, i: int) -> list[str]:
        """Names of the flags set on segment ``i``."""
        return [k for k, v in FLAG_BITS.items() if int(self.flags[i]) & v]

    def to_dict(self, *, json_safe: bool = True) -> dict:
        """Columns by name. ``json_safe``: lists with NaN as None (for ``json.dumps``);
        otherwise the numpy arrays themselves."""
        out = {}
        for f in dataclasses.fields(self):
            a = getattr(self, f.name)
            if json_safe:
                a = [None if isinstance(v, float) and not math.isfinite(v) else v
                     for v in a.tolist()]
            out[f.name] = a
        return out


# --------------------------------------------------------------------------- line fit

def _line_fit(x: np.ndarray, h: np.ndarray):
    """Least-squares ``h = a + b x``; returns (a, b, (G^T G)^-1) or None when singular."""
    n = x.size
    sx, sxx = x.sum(), (x * x).sum()
    det = n * sxx - sx * sx
    if n < 2 or not det > 1e-12 * max(1.0, n * sxx):
        return None
    sh, sxh = h.sum(), (x * h).sum()
    a = (sxx * sh - sx * sxh) / det
    b = (n * sxh - sx * sh) / det
    cov = np.array([[sxx, -sx], [-sx, n]]) / det
    return a, b, cov


# --------------------------------------------------------------------------- segment fitting

@dataclass(frozen=True)
class _Config:
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


def _exclusion(win, sig_r, dead_m, cfg: _Config) -> float:
    """Half-height of the zone about the line left out of the background count:
    ``max(W / 2, initial_window_m / 2, 5 sigma_r) + c tau / 2``. Not just ``W / 2``: where the
    refinement stops depends on whether photons lie near the window's edge (it stops when the
    band it would cut is empty), and counting outside that edge overestimated the background by
    ~3 % at 1 MHz."""
    s = min(sig_r, 5.0) if np.isfinite(sig_r) else 0.0
    return max(win / 2.0, cfg.initial_window_m / 2.0, 5.0 * s) + dead_m


def _background(x_shot, gate_c, a, b, r_all, excl, n_pulses, cfg: _Config):
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


def _fit_segment(x, h, x_shot, gate_c, cfg: _Config) -> dict:
    """Fit one segment: photons at along-track offsets ``x`` (from the centre) and heights
    ``h``; ``x_shot`` the offsets of its pulses; ``gate_c`` their gate centres or None."""
    n_pulses = x_shot.size
    out = {"n_seg_pulses": n_pulses, "flags": 0}
    flags = 0
    dead_m = cfg.dead_time_ns * HALF_C
    if x.size < cfg.min_photons or n_pulses == 0:
        out["flags"] = FLAG_BITS["too_few_photons"]
        out["n_fit_photons"] = int(x.size)
        return out

    # initial window: the densest initial_window_m of heights, then a line through it
    hs = np.sort(h)
    w0 = cfg.initial_window_m
    counts = np.searchsorted(hs, hs + w0, side="right") - np.arange(hs.size)
    i_best = int(np.argmax(counts))
    sel = (h >= hs[i_best]) & (h <= hs[i_best] + w0)
    if np.count_nonzero(sel) < cfg.min_photons or np.ptp(x[sel]) < cfg.min_span_m:
        out["flags"] = FLAG_BITS["too_few_photons"]
        out["n_fit_photons"] = int(np.count_nonzero(sel))
        return out
    fit = _line_fit(x[sel], h[sel])
    if fit is None:
        out["flags"] = FLAG_BITS["too_few_photons"]
        return out
    a, b, cov = fit
    r_all = h - (a + b * x)
    # preliminary background: outside the initial window (plus a dead time)
    _, _, bg = _background(x_shot, gate_c, a, b, r_all, w0 / 2.0 + dead_m, n_pulses, cfg)
    bg = 0.0 if not np.isfinite(bg) else bg
    bg_per_m = bg * 1e-3 / HALF_C * n_pulses          # background photons per metre of window
    sigma_exp = math.hypot(cfg.sigma_pulse_m, cfg.footprint_sigma_m * b)
    r0 = r_all[sel]
    sig_r = robust_spread(r0, n_background=bg_per_m * w0, window=(r0.min(), r0.min() + w0))
    win = max(w0, 6.0 * max(min(sig_r, 5.0), sigma_exp))
    new = np.abs(r_all) < win / 2.0
    if np.count_nonzero(new) >= cfg.min_photons and np.ptp(x[new]) >= cfg.min_span_m:
        sel = new

    # iterative refinement
    it = 0
    converged = False
    for it in range(1, cfg.max_iterations + 1):
        fit = _line_fit(x[sel], h[sel])
        if fit is None:
            break
        a, b, cov = fit
        r_all = h - (a + b * x)
        r0 = r_all[sel]
        excl = _exclusion(win, sig_r, dead_m, cfg)
        _, _, bg_i = _background(x_shot, gate_c, a, b, r_all, excl, n_pulses, cfg)
        if np.isfinite(bg_i):
            bg = bg_i
            bg_per_m = bg * 1e-3 / HALF_C * n_pulses
        sig_r = min(5.0, robust_spread(r0, n_background=bg_per_m * win,
                                       window=(-win / 2.0, win / 2.0)))
        sigma_exp = math.hypot(cfg.sigma_pulse_m, cfg.footprint_sigma_m * b)
        win_new = max(6.0 * sigma_exp, 6.0 * sig_r, 0.75 * win, cfg.min_window_m)
        new = np.abs(r_all) < win_new / 2.0
        if np.count_nonzero(new) < cfg.min_photons or np.ptp(x[new]) < cfg.min_span_m:
            break                                   # keep the previous selection and window
        win = win_new
        if np.array_equal(new, sel):
            converged = True
            break
        sel = new
    if not converged and it >= cfg.max_iterations:
        flags |= FLAG_BITS["window_not_converged"]

    fit = _line_fit(x[sel], h[sel])
    if fit is None:
        out["flags"] = flags | FLAG_BITS["too_few_photons"]
        return out
    a, b, cov = fit
    r_all = h - (a + b * x)
    r0 = r_all[sel]
    n_fit = r0.size
    sig_r = robust_spread(r0, n_background=bg_per_m * win, window=(-win / 2.0, win / 2.0))
    excl = _exclusion(win, sig_r, dead_m, cfg)
    n_bg_out, exposure_ns, bg_final = _background(x_shot, gate_c, a, b, r_all, excl, n_pulses, cfg)
    if np.isfinite(bg_final):
        bg = bg_final
    bg_obs_mhz = n_bg_out / exposure_ns * 1e3 if exposure_ns > 0 else 0.0

    # formal errors (ATBD): sigma_photon_est from expected noise and signal spreads
    win_ns = win / HALF_C
    n_noise_obs = bg_obs_mhz * 1e-3 * win_ns * n_pulses
    n_sig = max(0.0, n_fit - n_noise_obs)
    sigma_exp = math.hypot(cfg.sigma_pulse_m, cfg.footprint_sigma_m * b)
    h_rms = float(np.sqrt(np.mean(r0 ** 2)))
    sigma_photon_est = math.sqrt((n_noise_obs * (win / math.sqrt(12.0)) ** 2
                                  + n_sig * sigma_exp ** 2) / n_fit)
    sigma_h_mean = math.sqrt(cov[0, 0]) * max(sigma_photon_est, h_rms)

    # first-photon bias: window photons plus those up to two dead times earlier (higher)
    ext = (r_all > -win / 2.0) & (r_all < win / 2.0 + 2.0 * dead_m)
    r_ext = r_all[ext]
    w_ext, ok = dead_time_weights(-r_ext / HALF_C, n_pulses=n_pulses, n_channels=cfg.n_channels,
                                  dead_time_ns=cfg.dead_time_ns, paralyzable=cfg.paralyzable)
    in_win = np.abs(r_ext) < win / 2.0
    rw, ww = r_ext[in_win], w_ext[in_win]
    n_bg_true = (bg if np.isfinite(bg) else 0.0) * 1e-3 * win_ns * n_pulses
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
    if not (ok and np.all(np.isfinite(ww)) and n_corr > 0 and np.isfinite(fpb_corr)):
        flags |= FLAG_BITS["fpb_diverged"]
    if not (min_alive * n_pulses * cfg.n_channels >= cfg.min_alive_pulses):
        flags |= FLAG_BITS["fpb_dead"]
    if not (gain <= cfg.max_gain):
        flags |= FLAG_BITS["fpb_gain"]
    snr = (n_fit - n_noise_obs) / n_noise_obs if n_noise_obs > 0 else float("inf")
    if n_fit - n_noise_obs < 5.0 * math.sqrt(max(n_noise_obs, 1.0)):
        flags |= FLAG_BITS["low_snr"]
    h_li = a + fpb_corr
    h_li_sigma = max(sigma_h_mean, fpb_sigma) if np.isfinite(fpb_sigma) else sigma_h_mean
    if not (sig_r < 1.0 and h_li_sigma < 1.0):
        flags |= FLAG_BITS["large_spread"]
    out.update(h_li=h_li, h_li_sigma=h_li_sigma, h_mean=a, sigma_h_mean=sigma_h_mean,
               dh_fit_dx=b, h_robust_sprd=sig_r, h_rms_misfit=h_rms, n_fit_photons=n_fit,
               w_surface_window_final=win, exit_iteration=it, bckgrd=bg,
               bckgrd_n_photons=n_bg_out, bckgrd_exposure_ns=exposure_ns,
               fpb_corr_m=fpb_corr, fpb_corr_sigma_m=fpb_sigma, fpb_med_corr_m=fpb_med,
               fpb_gain=gain, fpb_min_alive=min_alive, fpb_n_corr=n_corr, snr=snr, flags=flags)
    return out


_INT_FIELDS = {"segment_id", "n_fit_photons", "n_seg_pulses", "exit_iteration",
               "bckgrd_n_photons", "flags", "atl06_quality_summary"}


def fit_segments(*, photon_along_m: np.ndarray, h_m: np.ndarray, shot: np.ndarray,
                 channel: np.ndarray, n_shots: int, shot_along_m: np.ndarray, n_channels: int,
                 dead_time_ns: float, paralyzable: bool, pulse_sigma_ns: float,
                 range_gate_m: float, segment_length_m: float = 40.0,
                 segment_step_m: float = 20.0, z_ref_m: np.ndarray | None = None,
                 gate_center_h_m: np.ndarray | None = None, footprint_sigma_m: float = 0.0,
                 initial_window_m: float = 10.0, min_window_m: float = 3.0,
                 max_iterations: int = 20, min_photons: int = 10,
                 min_alive_pulses: float = 3.0, max_gain: float = 5.0,
                 x0_m: float | None = None, engine: str = "auto") -> SegmentTable:
    """ATL06-style segments from detected photons (see the module docstring).

    Args:
        photon_along_m: (n,) along-track position of each photon [m] (its shot's footprint
            centre, as ATLAS places them: ``shot_along_m[shot]``).
        h_m: (n,) photon heights [m]; shot: (n,) shot index; channel: (n,) detector channel
            (only checked: the correction pools the statistically identical channels).
        n_shots: shots in the track; shot_along_m: (n_shots,) along-track position [m],
            non-decreasing.
        n_channels: detector channels C; dead_time_ns: dead time (0: ideal detector);
        paralyzable: dead-time model; pulse_sigma_ns: transmit pulse sigma [ns];
        range_gate_m: height of the range gate [m].
        segment_length_m, segment_step_m: 40 m segments every 20 m.
        z_ref_m: (n_shots,) truth reference heights; fills ``h_ref_m`` (else NaN).
        gate_center_h_m: (n_shots,) height of each shot's gate centre [m] (instrument telemetry;
            ``simulate`` centres the gate on z_ref). ``None``: the exclusion zone is assumed to
            lie inside the gate.
        footprint_sigma_m: footprint sigma [m], for the expected spread on slopes.
        initial_window_m, min_window_m, max_iterations, min_photons: surface-finding settings.
        min_alive_pulses: flag ``fpb_dead`` when, at some window photon, fewer than this many
            of the ``N C`` channel-pulses are expected alive (``P_alive N C < 3``): the dead
            fraction there rests on too few live channels to be trusted. (The ATBD's test,
            ``P_alive < 1 / (2 C)``, flags e.g. every smooth 12-photon 4-channel segment, where
            this correction still removes 97 % of the bias; and any threshold on this noisy
            per-segment minimum biases the kept segments, so it is set where it rarely fires.)
        max_gain: flag ``fpb_gain`` when the corrected / observed count exceeds it.
        x0_m: along-track origin of the segment grid [m] (centres at ``x0 + 20 (k + 1)``);
            default the first shot's. A track fitted in sections passes the whole track's.
        engine: ``"compiled"`` (numba: :mod:`lidar_mitsuba._atl06_kernel`, ~10-20x faster),
            ``"reference"`` (the plain numpy :func:`_fit_segment`, ~1 ms a segment; the tests
            check that both give the same table to 1e-9) or ``"auto"``: compiled from
            :data:`COMPILE_MIN_SEGMENTS` segments on (its first compile takes ~20 s, then
            numba's on-disk cache <1 s). The choice depends on the track alone, so a track
            gives the same bits in every process.
    """
    if engine not in ("auto", "compiled", "reference"):
        raise ValueError(f"engine must be 'auto', 'compiled' or 'reference' (got {engine!r})")
    along = np.asarray(photon_along_m, np.float64)
    h = np.asarray(h_m, np.float64)
    shot = np.asarray(shot, np.int64)
    channel = np.asarray(channel)
    shot_along = np.asarray(shot_along_m, np.float64)
    if not (along.shape == h.shape == shot.shape == channel.shape):
        raise ValueError("photon arrays must have the same shape")
    if shot_along.shape != (n_shots,):
        raise ValueError(f"shot_along_m must have shape ({n_shots},)")
    if shot_along.size > 1 and np.any(np.diff(shot_along) < 0):
        raise ValueError("shot_along_m must be non-decreasing")
    if channel.size and (channel.min() < 0 or channel.max() >= n_channels):
        raise ValueError(f"channel out of range [0, {n_channels})")
    if dead_time_ns < 0 or not segment_length_m > 0 or not segment_step_m > 0:
        raise ValueError("dead_time_ns must be >= 0 and segment sizes > 0")
    cfg = _Config(n_channels=int(n_channels), dead_time_ns=float(dead_time_ns),
                  paralyzable=bool(paralyzable), sigma_pulse_m=float(pulse_sigma_ns) * HALF_C,
                  footprint_sigma_m=float(footprint_sigma_m), gate_m=float(range_gate_m),
                  initial_window_m=float(initial_window_m), min_window_m=float(min_window_m),
                  max_iterations=int(max_iterations), min_photons=int(min_photons),
                  min_span_m=0.5 * segment_length_m,
                  min_alive_pulses=float(min_alive_pulses),
                  max_gain=float(max_gain))
    order = np.argsort(along, kind="stable")
    along, h = along[order], h[order]
    half = segment_length_m / 2.0
    if n_shots == 0:
        centres = np.zeros(0)
    else:
        x0, x1 = (shot_along[0] if x0_m is None else float(x0_m)), shot_along[-1]
        n_seg = int(math.floor((x1 - x0 - segment_length_m) / segment_step_m + 1e-9)) + 1
        centres = x0 + half + segment_step_m * np.arange(max(n_seg, 0))
    gate = None if gate_center_h_m is None else np.asarray(gate_center_h_m, np.float64)
    zref = None if z_ref_m is None else np.asarray(z_ref_m, np.float64)
    names = [f.name for f in dataclasses.fields(SegmentTable)]
    cols = {k: np.full(centres.size, -1 if k in _INT_FIELDS else np.nan,
                       np.int64 if k in _INT_FIELDS else np.float64) for k in names}
    cols["segment_id"] = np.arange(1, centres.size + 1)
    cols["x_atc"] = centres
    cols["n_fit_photons"][:] = 0
    if engine == "auto":
        engine = "compiled" if centres.size >= COMPILE_MIN_SEGMENTS else "reference"
    shot0 = np.searchsorted(shot_along, centres - half, side="left")
    shot1 = np.searchsorted(shot_along, centres + half, side="left")
    if engine == "compiled":
        _fit_compiled(cols, along, h, shot_along, gate, centres, half, shot0, shot1, cfg)
    for k, c in enumerate(centres):
        s0, s1 = shot0[k], shot1[k]
        if engine == "reference":
            p0, p1 = np.searchsorted(along, [c - half, c + half], side="left")
            res = _fit_segment(along[p0:p1] - c, h[p0:p1], shot_along[s0:s1] - c,
                               None if gate is None else gate[s0:s1], cfg)
            for name, v in res.items():
                cols[name][k] = v
        if zref is not None and s1 - s0 >= 1:
            xs = shot_along[s0:s1] - c
            fit = _line_fit(xs, zref[s0:s1])
            cols["h_ref_m"][k] = fit[0] if fit is not None else float(np.mean(zref[s0:s1]))
    cols["atl06_quality_summary"] = (cols["flags"] != 0).astype(np.int64)
    return SegmentTable(**cols)


COMPILE_MIN_SEGMENTS = 1000
"""``engine="auto"`` compiles the kernel for tracks of this many segments (20 km) or more:
fewer cost the reference less than the compile."""
#: fewest segments worth a thread of their own in the compiled fit
_SEGMENTS_PER_THREAD_MIN = 256


def _fit_compiled(cols: dict, along, h, shot_along, gate, centres, half: float, s0, s1,
                  cfg: _Config) -> None:
    """Every segment through the compiled kernel, into ``cols`` (pre-filled defaults);
    segment ``k`` holds shots ``s0[k]:s1[k]``."""
    from . import _atl06_kernel as K
    from .fpb import IQR_PER_SIGMA
    p0 = np.searchsorted(along, centres - half, side="left")
    p1 = np.searchsorted(along, centres + half, side="left")
    cfg_v = np.array([float(getattr(cfg, name)) for name in K.CFG_FIELDS]
                     + [HALF_C, IQR_PER_SIGMA], np.float64)
    out = np.column_stack([cols[name].astype(np.float64) for name in K.OUT_FIELDS])
    gate_v = np.zeros(shot_along.size) if gate is None else gate
    centres = np.asarray(centres, np.float64)

    def fit(a: int, b: int) -> None:      # segments a..b-1 (the kernel releases the GIL)
        K.fit_all(along, h, shot_along, gate_v, gate is not None, centres[a:b], p0[a:b],
                  p1[a:b], s0[a:b], s1[a:b], cfg_v, out[a:b])

    # segments are independent: contiguous blocks on the host's threads, same results
    pool = host_pool()
    blocks = max(1, min(host_threads(), centres.size // _SEGMENTS_PER_THREAD_MIN))
    cuts = np.linspace(0, centres.size, blocks + 1).astype(int)
    for job in [pool.submit(fit, a, b) for a, b in zip(cuts[:-1], cuts[1:])]:
        job.result()
    for i, name in enumerate(K.OUT_FIELDS):
        cols[name][:] = out[:, i]


# --------------------------------------------------------------------------- files and summary

def segments_from_atl03(path: str | os.PathLike, **options) -> SegmentTable:
    """Fit segments to one of our ATL03-like files (:func:`lidar_mitsuba.atl03.read`).

    Detector settings come from the file's ``config['instrument']`` (files written before the
    noise fields existed get no dead-time model choice (non-paralyzable), a 30 m gate, and no
    noise). The gate is centred on each shot's ``z_ref_m``, as ``simulate`` does, and ``z_ref_m``
    fills ``h_ref_m``. ``options`` are passed to :func:`fit_segments`.
    """
    from . import atl03
    d = atl03.read(path)
    inst = d["config"]["instrument"]
    dead = 0.0 if inst.get("ideal_detector", False) else float(inst.get("dead_time_ns", 3.0))
    fwhm = float(inst.get("pulse_fwhm_ns", 1.0))
    kw = dict(photon_along_m=d["along_track_m"][d["shot"]], h_m=d["h_m"], shot=d["shot"],
              channel=d["channel"], n_shots=d["n_shots"], shot_along_m=d["along_track_m"],
              n_channels=d["n_channels"], dead_time_ns=dead,
              paralyzable=bool(inst.get("paralyzable", False)),
              pulse_sigma_ns=fwhm / FWHM_PER_SIGMA,
              range_gate_m=float(inst.get("range_gate_m", 30.0)),
              z_ref_m=d["z_ref_m"], gate_center_h_m=d["z_ref_m"],
              footprint_sigma_m=float(inst.get("footprint_diameter_m", 10.0)) / 4.0)
    kw.update(options)
    return fit_segments(**kw)


def segments_from_result(result, **options) -> SegmentTable:
    """Fit segments to a :class:`~lidar_mitsuba.simulate.SimulationResult` directly, without
    writing a file: the same photons, gate and truth as :func:`segments_from_atl03` reads
    from the file that ``atl03.write(result, ...)`` would write. ``options`` are passed to
    :func:`fit_segments`."""
    d = result.detections
    kw = dict(photon_along_m=result.along_track_m[d.shot], h_m=result.h_m, shot=d.shot,
              channel=d.channel, n_shots=result.n_shots, shot_along_m=result.along_track_m,
              z_ref_m=result.z_ref_m, gate_center_h_m=result.z_ref_m,
              **instrument_settings(result.instrument))
    kw.update(options)
    return fit_segments(**kw)


def instrument_settings(inst) -> dict:
    """:func:`fit_segments`' detector settings for an
    :class:`~lidar_mitsuba.instrument.Instrument` as simulated."""
    return dict(n_channels=inst.channels, dead_time_ns=inst.effective_dead_time_ns,
                paralyzable=inst.paralyzable, pulse_sigma_ns=inst.pulse_sigma_ns,
                range_gate_m=inst.range_gate_m, footprint_sigma_m=inst.footprint_sigma_m)


def write(table: SegmentTable, path: str | os.PathLike, *, attrs: dict | None = None
          ) -> pathlib.Path:
    """Write ``table`` as ``land_ice_segments/<name>`` datasets (attrs ``units``,
    ``description``) to ``path`` atomically: a temporary file in the same folder, renamed on
    success and removed on failure. ``attrs``: extra root attributes (JSON-encoded if not
    str/number)."""
    from . import __version__
    from .atl03 import atomic_h5file
    path = pathlib.Path(path)
    with atomic_h5file(path) as f:
        f.attrs["lidar_mitsuba_version"] = __version__
        f.attrs["description"] = ("ATL06-like land-ice segments (lidar_mitsuba.atl06): 40 m "
                                  "segments every 20 m, first-photon-bias corrected")
        f.attrs["flag_bits"] = json.dumps(FLAG_BITS)
        for k, v in (attrs or {}).items():
            f.attrs[k] = v if isinstance(v, (str, int, float)) else json.dumps(v)
        g = f.create_group("land_ice_segments")
        for name, (units, desc) in FIELDS.items():
            ds = g.create_dataset(name, data=np.asarray(getattr(table, name)))
            ds.attrs["units"] = units
            ds.attrs["description"] = desc
    return path


def read(path: str | os.PathLike) -> SegmentTable:
    """Read a table written by :func:`write`."""
    import h5py
    with h5py.File(path, "r") as f:
        g = f["land_ice_segments"]
        return SegmentTable(**{name: g[name][()] for name in FIELDS})


def _finite_or_none(v):
    v = float(v)
    return v if math.isfinite(v) else None


def summarize(table: SegmentTable) -> dict:
    """JSON-safe summary over the unflagged segments: counts (and flagged ones by reason),
    mean/median/std of ``h_li - h_ref_m`` and of the uncorrected ``h_mean - h_ref_m`` (NaN →
    None without truth), the standard error of the mean from every other segment (segments
    overlap by half, so alternate ones are independent), and mean correction, gain and
    background."""
    good = table.good
    n = len(table)
    out = {"n_segments": n, "n_good": int(good.sum()), "n_flagged": int(n - good.sum()),
           "flagged_by_reason": {k: int(np.count_nonzero(table.flags & v))
                                 for k, v in FLAG_BITS.items()}}
    alt = good & (np.arange(n) % 2 == 0)
    for key, h in (("h_li", table.h_li), ("h_mean", table.h_mean)):
        d = h - table.h_ref_m
        dg = d[good & np.isfinite(d)]
        da = d[alt & np.isfinite(d)]
        out[f"{key}_minus_ref_mean_m"] = _finite_or_none(dg.mean()) if dg.size else None
        out[f"{key}_minus_ref_median_m"] = _finite_or_none(np.median(dg)) if dg.size else None
        out[f"{key}_minus_ref_std_m"] = _finite_or_none(dg.std(ddof=1)) if dg.size > 1 else None
        out[f"{key}_minus_ref_se_m"] = (_finite_or_none(da.std(ddof=1) / math.sqrt(da.size))
                                            if da.size > 1 else None)
    for key in ("fpb_corr_m", "fpb_med_corr_m", "fpb_gain", "h_li_sigma", "bckgrd"):
        v = getattr(table, key)[good]
        v = v[np.isfinite(v)]
        out[f"mean_{key}"] = _finite_or_none(v.mean()) if v.size else None
    return out


# --------------------------------------------------------------------------- FPB test matrix
