"""The land-ice team's first-photon-bias test matrix (lidar_mitsuba.studies.fpb_matrix):
flat surfaces through roughness x signal x channels x dead-time model, detected by
lidar_mitsuba.detector.pmt and fitted by lidar_mitsuba.products.atl06 (moved here from test_atl06.py).

Tolerances. Every Monte Carlo estimate is compared with its truth within Z = 4.5 standard
errors (two-sided p ~ 7e-6 each), the standard error taken from the sample: sd / sqrt(n) of
the segment heights over alternate (disjoint, hence independent) unflagged segments, since
segments overlap by half; Poisson errors for background counts. All seeds are fixed, so the
file is deterministic; the tolerances say how likely a different seed would be to fail.
"""
import math

import pytest

from lidar_mitsuba.studies import fpb_matrix

Z = 4.5


def check_matrix(rows, *, per_cell_5pct: bool):
    """The claims: (a) where the uncorrected bias exceeds 1 cm, the corrected bias is at most
    a fifth of it, plus Z standard errors of the corrected bias (from alternate segments: the
    mean of h_li is noisy, mostly from background photons in the window, and a cell whose
    uncorrected bias only just exceeds 1 cm is tested weakly); (b) each cell's pooled
    background estimate is within Z Poisson errors of the truth, and pooled over all cells
    within 5 % (asserted to be > 10 Poisson sigma); with ``per_cell_5pct`` also per cell,
    after asserting that each cell's sample makes 5 % more than 4 standard errors."""
    print("\n" + fpb_matrix.format_matrix(rows))
    tested = 0
    for r in rows:
        assert r["n_good"] >= 0.7 * r["n_segments"], r
        u, c, se = r["bias_uncorr_m"], r["bias_corr_m"], r["bias_corr_se_m"]
        if abs(u) > 0.01:
            tested += 1
            assert abs(c) <= abs(u) / 5 + Z * se, r
        est, true, se_bg = r["bckgrd_est_mhz"], r["bckgrd_true_mhz"], r["bckgrd_se_mhz"]
        assert abs(est - true) < Z * se_bg, r
        if per_cell_5pct:
            assert 0.05 * true > 4 * se_bg, r            # the sample is big enough
            assert abs(est / true - 1) < 0.05, r
    assert tested >= len(rows) // 3                      # the claim was exercised
    n_bg = sum(r["bckgrd_n_photons"] for r in rows)
    pooled = sum(r["bckgrd_est_mhz"] * r["bckgrd_n_photons"] for r in rows) / n_bg
    true = rows[0]["bckgrd_true_mhz"]
    assert 0.05 * true > 10 * true / math.sqrt(n_bg)
    assert abs(pooled / true - 1) < 0.05


def test_fpb_matrix_fast():
    """A corner of the matrix (smooth and 3 pulse widths rough; 3 and 12 photons; 4 and 16
    channels; both dead-time models), 150 segments a cell: the claims still hold."""
    rows = fpb_matrix.fpb_test_matrix(roughness_pulse_widths=(0, 3), signal_photons=(3, 12),
                                 segments=150, seed=1)
    check_matrix(rows, per_cell_5pct=False)
    big = [r for r in rows if r["signal_photons"] == 12 and r["channels"] == 4]
    assert all(r["bias_uncorr_m"] > 0.04 for r in big)      # a real bias (5-13 cm) ...
    assert all(abs(r["bias_corr_m"]) <= r["bias_uncorr_m"] / 10 + Z * r["bias_corr_se_m"]
               for r in big)                                # ... shrinks more than tenfold


@pytest.mark.slow
def test_fpb_matrix_full():
    """The whole matrix: roughness 0, 1, 3, 6, 12 pulse widths; 1, 3, 6, 12 photons; 4 and
    16 channels; both models; 400 segments a cell at 5 MHz. The segments are fitted by the
    compiled engine (12 s CPU against the reference's 38 s for the 80 cells; the two agree to
    1e-9 relative, tests/test_atl06.py: here every row's numbers to 5e-12); the fast test above
    runs the reference."""
    rows = fpb_matrix.fpb_test_matrix(segments=400, seed=2, fit_options={"engine": "compiled"})
    check_matrix(rows, per_cell_5pct=True)
