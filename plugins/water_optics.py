"""Water's optics at the surface, the closed forms the ``water`` BSDF's defaults come from and
``lidar_mitsuba.ground.water`` checks and extends (validation, arrays, the derived closed
forms). Variant-independent: imports nothing but the standard library; the arithmetic works
on floats and on NumPy arrays alike.
"""
from __future__ import annotations

AIR_IOR = 1.000277
"""Refractive index of air at the surface (Mitsuba's ``air``): ``ext_ior`` of the water BSDF."""

COX_MUNK_MSS_CALM = 0.003
"""Cox & Munk (1954) clean-surface total mean-square slope at zero wind [1]."""
COX_MUNK_MSS_PER_MPS = 0.00512
"""Cox & Munk (1954) clean-surface growth of the total mean-square slope with the wind speed
at 12.5 m height [1 / (m/s)]."""

# Quan & Fry (1995) coefficients: recalled, then found identical in five independent
# transcriptions in other projects' code (the paper itself was not read); tests/test_water.py
# checks them against the textbook index of pure water at the sodium D line and 20 C (1.3330,
# within 5e-4) and for normal dispersion (n rising toward blue).
QF_N0 = 1.31405
QF_N1 = 1.779e-4      # S
QF_N2 = -1.05e-6      # S T
QF_N3 = 1.6e-8        # S T^2
QF_N4 = -2.02e-6      # T^2
QF_N5 = 15.868        # 1 / lambda [nm]
QF_N6 = 0.01155       # S / lambda
QF_N7 = -0.00423      # T / lambda
QF_N8 = -4382.0       # 1 / lambda^2 [nm^2]
QF_N9 = 1.1455e6      # 1 / lambda^3 [nm^3]


def cox_munk_mss(wind_speed_mps):
    """Cox & Munk (1954) clean-surface total mean-square slope, s^2 = 0.003 + 0.00512 U
    (U [m/s] at 12.5 m)."""
    return COX_MUNK_MSS_CALM + COX_MUNK_MSS_PER_MPS * wind_speed_mps


def quan_fry_index(wavelength_nm=532.0, temperature_c=0.0, salinity_psu=0.0,
                   group: bool = False):
    """Quan & Fry (1995) phase index of water at ``wavelength_nm`` [nm], ``temperature_c``
    [deg C] and ``salinity_psu`` [PSU] (``group``: the group index n - lambda dn/dlambda, from
    the formula's analytic derivative)."""
    lam, t, s = wavelength_nm, temperature_c, salinity_psu
    a = QF_N5 + QF_N6 * s + QF_N7 * t
    n = (QF_N0 + (QF_N1 + QF_N2 * t + QF_N3 * t * t) * s + QF_N4 * t * t
         + a / lam + QF_N8 / lam ** 2 + QF_N9 / lam ** 3)
    if group:
        n = n + a / lam + 2 * QF_N8 / lam ** 2 + 3 * QF_N9 / lam ** 3
    return n
