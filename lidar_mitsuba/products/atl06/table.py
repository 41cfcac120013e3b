"""The ATL06-like segment table: its columns (:data:`FIELDS`, units and meanings), the flag
bits (:data:`FLAG_BITS`) and the record itself (:class:`SegmentTable`).

The end of the ATL06 data flow: :func:`lidar_mitsuba.products.atl06.fit_segments` fills a
:class:`SegmentTable`, :func:`lidar_mitsuba.products.atl06.write` stores it column by column, and both
segment-fit engines (:mod:`lidar_mitsuba.products.atl06.reference`, :mod:`lidar_mitsuba.products.atl06.kernel`)
set the bits of :data:`FLAG_BITS`. Import these names from :mod:`lidar_mitsuba.products.atl06`.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

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


#: columns of integer type (the rest are float64)
INT_FIELDS = frozenset({"segment_id", "n_fit_photons", "n_seg_pulses", "exit_iteration",
                        "bckgrd_n_photons", "flags", "atl06_quality_summary"})


def default_columns(centres_m: np.ndarray) -> dict[str, np.ndarray]:
    """The columns of :class:`SegmentTable` for segments centred at ``centres_m`` [m]
    (``x_atc``), before any is fitted: ``segment_id`` 1, 2, ..., ``n_fit_photons`` 0, the other
    integer columns -1 and the float columns NaN (what a segment without a fit keeps)."""
    names = [f.name for f in dataclasses.fields(SegmentTable)]
    cols = {k: np.full(centres_m.size, -1 if k in INT_FIELDS else np.nan,
                       np.int64 if k in INT_FIELDS else np.float64) for k in names}
    cols["segment_id"] = np.arange(1, centres_m.size + 1)
    cols["x_atc"] = centres_m
    cols["n_fit_photons"][:] = 0
    return cols
