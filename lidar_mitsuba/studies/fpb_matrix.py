"""The land-ice team's first-photon-bias test matrix, without rendering.

Flat surfaces seen through every combination of surface roughness (in pulse widths), signal
level, channel count and dead-time model, with solar background; each cell is detected by
:func:`lidar_mitsuba.detector.pmt.detect` and fitted by :func:`lidar_mitsuba.products.atl06.fit_segments`, so
the table shows how well the first-photon-bias correction recovers the true height (0).
"""
from __future__ import annotations

import math

import numpy as np

from ..detector import pmt
from ..products.atl06 import FLAG_BITS, HALF_C, SegmentTable, fit_segments
from ..products.first_photon_bias import corrected_background_mhz
from ..constants import C_M_PER_NS
from ..instrument import Instrument
from ..detector.records import Returns


def fpb_test_matrix(*, roughness_pulse_widths=(0, 1, 3, 6, 12), signal_photons=(1, 3, 6, 12),
                    channels=(4, 16), paralyzable=(False, True), background_mhz: float = 5.0,
                    segments: int = 400, dead_time_ns: float = 3.0, pulse_fwhm_ns: float = 1.0,
                    range_gate_m: float = 30.0, paths_per_shot: int = 64, seed: int = 0,
                    fit_options: dict | None = None) -> list[dict]:
    """The land-ice team's first-photon-bias test matrix, without rendering.

    Each cell: a flat surface at h = 0 along ``(segments + 1) * 20 / 0.7`` shots at 0.7 m
    (``segments`` 40 m segments); each shot's photons return at Gaussian
    times with ``sigma_total = sqrt(sigma_pulse^2 + sigma_rough^2)``, where the *pulse width*
    is the pulse sigma as a height, ``c sigma_t / 2`` (6.37 cm for 1 ns FWHM), and
    ``sigma_rough = roughness * pulse width``. ``signal_photons`` are detection-eligible photons
    per shot (fill factor = PDE = 1), split over ``channels``; ``background_mhz`` is uniform in
    a ``range_gate_m`` gate centred on the surface. Detection by :func:`pmt.detect`.

    Returns one dict per cell: settings; ``n_segments``, ``n_good``; ``bias_uncorr_m`` (mean of
    ``h_mean`` over unflagged segments: truth is 0), ``bias_corr_m`` (mean ``h_li``),
    ``bias_med_corr_m`` (mean ``h_mean + fpb_med_corr_m``) with standard errors ``*_se_m``
    from alternate (independent) unflagged segments; ``mean_gain``; ``bckgrd_est_mhz``
    (pooled: sum of counts over sum of exposures of alternate segments, dead-time corrected)
    with its Poisson ``bckgrd_se_mhz`` and the truth ``bckgrd_true_mhz``.
    """
    rows = []
    spacing = 0.7
    n_shots = int(math.ceil((segments + 1) * 20.0 / spacing)) + 1
    cell = 0
    for par in paralyzable:
        for nch in channels:
            for sp in signal_photons:
                for rough in roughness_pulse_widths:
                    cell += 1
                    inst = Instrument(beam="strong", channels=int(nch), signal_photons=float(sp),
                                      fill_factor=1.0, pde=1.0, dead_time_ns=dead_time_ns,
                                      paralyzable=bool(par), background_mhz=background_mhz,
                                      range_gate_m=range_gate_m, pulse_fwhm_ns=pulse_fwhm_ns,
                                      shot_spacing_m=spacing)
                    rng = np.random.default_rng([seed, cell, 0xA706])
                    sig_t = inst.pulse_sigma_ns * math.sqrt(1.0 + float(rough) ** 2)
                    t0 = 2.0 * inst.altitude_m / C_M_PER_NS
                    k = int(paths_per_shot)
                    returns = Returns.at_times(
                        t0 + sig_t * rng.standard_normal(n_shots * k), paths_per_shot=k)
                    det = pmt.detect(returns, inst, rng, gate_center_ns=np.full(n_shots, t0))
                    h = inst.altitude_m - HALF_C * det.time_ns
                    along = np.arange(n_shots) * spacing
                    tab = fit_segments(photon_along_m=along[det.shot], h_m=h, shot=det.shot,
                                       channel=det.channel, n_shots=n_shots, shot_along_m=along,
                                       n_channels=inst.channels, dead_time_ns=dead_time_ns,
                                       paralyzable=bool(par), pulse_sigma_ns=inst.pulse_sigma_ns,
                                       range_gate_m=range_gate_m, z_ref_m=np.zeros(n_shots),
                                       gate_center_h_m=np.zeros(n_shots),
                                       **(fit_options or {}))
                    rows.append(_matrix_row(tab, inst, rough, background_mhz))
    return rows


def _matrix_row(tab: SegmentTable, inst, rough, background_mhz) -> dict:
    good = tab.good
    alt = good & (np.arange(len(tab)) % 2 == 0)
    row = {"paralyzable": bool(inst.paralyzable), "channels": int(inst.channels),
           "signal_photons": float(inst.signal_photons), "roughness_pulse_widths": float(rough),
           "sigma_rough_m": float(rough) * inst.ranging_sigma_m,
           "background_mhz": float(background_mhz), "n_segments": len(tab),
           "n_good": int(good.sum()), "flagged_by_reason": {
               k: int(np.count_nonzero(tab.flags & v)) for k, v in FLAG_BITS.items()
               if np.any(tab.flags & v)}}
    for key, v in (("bias_uncorr", tab.h_mean), ("bias_corr", tab.h_li),
                   ("bias_med_corr", tab.h_mean + tab.fpb_med_corr_m)):
        d = v - tab.h_ref_m
        row[f"{key}_m"] = float(np.mean(d[good])) if good.any() else float("nan")
        row[f"{key}_se_m"] = (float(np.std(d[alt], ddof=1) / math.sqrt(alt.sum()))
                              if alt.sum() > 1 else float("nan"))
    row["mean_gain"] = float(np.mean(tab.fpb_gain[good])) if good.any() else float("nan")
    row["mean_h_li_sigma_m"] = float(np.mean(tab.h_li_sigma[good])) if good.any() else float("nan")
    # pooled background over alternate segments that have an estimate (flagged or not: the
    # background estimate does not depend on the FPB correction)
    use = (np.arange(len(tab)) % 2 == 0) & (tab.bckgrd_exposure_ns > 0)
    n_bg = float(tab.bckgrd_n_photons[use].sum())
    expo = float(tab.bckgrd_exposure_ns[use].sum())
    obs = n_bg / expo * 1e3 if expo > 0 else float("nan")
    est = corrected_background_mhz(obs, n_channels=inst.channels,
                                   dead_time_ns=inst.effective_dead_time_ns,
                                   paralyzable=inst.paralyzable)
    row["bckgrd_n_photons"] = int(n_bg)
    row["bckgrd_est_mhz"] = est
    row["bckgrd_se_mhz"] = est / math.sqrt(n_bg) if n_bg > 0 else float("nan")
    row["bckgrd_true_mhz"] = float(background_mhz) * inst.fill_factor * inst.pde
    return row


def format_matrix(rows: list[dict]) -> str:
    """Plain-text table of :func:`fpb_test_matrix` rows (biases in cm)."""
    head = (f"{'model':<8}{'ch':>4}{'sig':>5}{'rough':>6}{'good':>9}{'uncorr':>9}{'corr':>8}"
            f"{'± se':>7}{'med':>8}{'gain':>7}{'bg est/true':>13}")
    lines = [head]
    for r in rows:
        lines.append(
            f"{'para' if r['paralyzable'] else 'nonpara':<8}{r['channels']:>4}"
            f"{r['signal_photons']:>5g}{r['roughness_pulse_widths']:>6g}"
            f"{r['n_good']:>5}/{r['n_segments']:<3}{100 * r['bias_uncorr_m']:>9.2f}"
            f"{100 * r['bias_corr_m']:>8.2f}{100 * r['bias_corr_se_m']:>7.2f}"
            f"{100 * r['bias_med_corr_m']:>8.2f}{r['mean_gain']:>7.2f}"
            f"{r['bckgrd_est_mhz'] / r['bckgrd_true_mhz']:>13.3f}")
    return "\n".join(lines)
