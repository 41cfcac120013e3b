"""Open water as a lidar target: closed forms for the wind-roughened sea surface and the index
of refraction of water, and the Mitsuba BSDF dict of ``<bsdf type="water">``
(``plugins/water.py``).

The surface is a Beckmann microfacet dielectric whose slope variance is the Cox & Munk (1954)
mean-square slope for the wind speed; its refractive index (phase, for the Fresnel reflectance)
and group index (for the speed of a pulse in the water) come from the Quan & Fry (1995)
empirical formula. At nadir the surface returns the specular glint of its facets that face the
spacecraft: :func:`sigma0_nadir` (radar convention) and :func:`nadir_return_weight` (the
integrators' weight units, a flat Lambertian plate of albedo 0.9 weighing 1).

Pure numpy: this module imports neither Mitsuba nor Dr.Jit (``water_bsdf`` only builds the
dict that ``mi.load_dict`` takes).
"""
from __future__ import annotations

import math

import numpy as np

from lidar_mitsuba_plugins import water_optics as _optics
from lidar_mitsuba_plugins.constants import REFERENCE_ALBEDO
from lidar_mitsuba_plugins.water_optics import (AIR_IOR, COX_MUNK_MSS_CALM,  # noqa: F401
                                                COX_MUNK_MSS_PER_MPS)


def _finite_array(name: str, value) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (got {value!r})")
    return arr


def _result(arr: np.ndarray):
    return float(arr) if arr.ndim == 0 else arr


def cox_munk_mss(wind_speed_mps):
    r"""Total mean-square slope of a clean sea surface [1] for the wind speed ``wind_speed_mps``
    [m/s] at 12.5 m above the sea:

    .. math:: s^2 = \langle z_x^2 + z_y^2 \rangle = 0.003 + 0.00512\,U

    C. Cox and W. Munk, "Measurement of the roughness of the sea surface from photographs of
    the sun's glitter", J. Opt. Soc. Am. 44(11), 838-850 (1954) (clean surface, the sum of the
    up- and cross-wind slope variances). Scalar or array; ``ValueError`` for negative or
    non-finite wind speeds.
    """
    u = _finite_array("wind_speed_mps", wind_speed_mps)
    if np.any(u < 0):
        raise ValueError(f"wind_speed_mps must be >= 0 (got {wind_speed_mps!r})")
    return _result(_optics.cox_munk_mss(u))


def fresnel_normal(n):
    r"""Fresnel reflectance at normal incidence of an interface of relative index ``n``:

    .. math:: F(0) = \left(\frac{n - 1}{n + 1}\right)^2

    (unpolarised; 0.0204 for n = 1.333). Scalar or array."""
    n = _finite_array("n", n)
    if np.any(n <= 0):
        raise ValueError(f"n must be > 0 (got {n!r})")
    return _result(((n - 1.0) / (n + 1.0)) ** 2)


def _quan_fry_args(wavelength_nm, temperature_c, salinity_psu):
    lam = _finite_array("wavelength_nm", wavelength_nm)
    if np.any(lam <= 0):
        raise ValueError(f"wavelength_nm must be > 0 (got {wavelength_nm!r})")
    t = _finite_array("temperature_c", temperature_c)
    s = _finite_array("salinity_psu", salinity_psu)
    if np.any(s < 0):
        raise ValueError(f"salinity_psu must be >= 0 (got {salinity_psu!r})")
    return lam, t, s


def quan_fry_index(wavelength_nm=532.0, *, temperature_c=0.0, salinity_psu=0.0):
    r"""Phase refractive index of water [1] at vacuum wavelength ``wavelength_nm`` [nm],
    temperature ``temperature_c`` [deg C] and salinity ``salinity_psu`` [PSU]:

    .. math::

        n = n_0 + (n_1 + n_2 T + n_3 T^2) S + n_4 T^2 + \frac{n_5 + n_6 S + n_7 T}{\lambda}
            + \frac{n_8}{\lambda^2} + \frac{n_9}{\lambda^3}

    with :math:`n_0 = 1.31405`, :math:`n_1 = 1.779\times10^{-4}`,
    :math:`n_2 = -1.05\times10^{-6}`, :math:`n_3 = 1.6\times10^{-8}`,
    :math:`n_4 = -2.02\times10^{-6}`, :math:`n_5 = 15.868`, :math:`n_6 = 0.01155`,
    :math:`n_7 = -0.00423`, :math:`n_8 = -4382`, :math:`n_9 = 1.1455\times10^{6}`
    (:math:`\lambda` in nm). X. Quan and E. S. Fry, "Empirical equation for the index of
    refraction of seawater", Appl. Opt. 34(18), 3477-3480 (1995); fitted over 400-700 nm,
    0-30 C, 0-35 PSU. (The coefficients are those of ``lidar_mitsuba_plugins.water_optics``,
    checked against n = 1.3330 at 589.3 nm, 20 C.) Scalars or broadcastable arrays."""
    lam, t, s = _quan_fry_args(wavelength_nm, temperature_c, salinity_psu)
    return _result(np.asarray(_optics.quan_fry_index(lam, t, s)))


def quan_fry_group_index(wavelength_nm=532.0, *, temperature_c=0.0, salinity_psu=0.0):
    r"""Group refractive index of water [1] (a pulse travels at :math:`c/n_g`), from
    :func:`quan_fry_index` and its analytic wavelength derivative:

    .. math::

        n_g = n - \lambda\frac{dn}{d\lambda}
            = n + \frac{n_5 + n_6 S + n_7 T}{\lambda} + \frac{2 n_8}{\lambda^2}
              + \frac{3 n_9}{\lambda^3}

    (Quan & Fry 1995, Appl. Opt. 34, 3477). 1.3577 at 532 nm, 0 C, fresh water."""
    lam, t, s = _quan_fry_args(wavelength_nm, temperature_c, salinity_psu)
    return _result(np.asarray(_optics.quan_fry_index(lam, t, s, group=True)))


WATER_INDEX_532 = quan_fry_index(532.0, temperature_c=0.0, salinity_psu=0.0)
"""Phase refractive index of fresh water (meltwater) at 0 C and 532 nm (ATLAS): 1.3360."""
WATER_GROUP_INDEX_532 = quan_fry_group_index(532.0, temperature_c=0.0, salinity_psu=0.0)
"""Group refractive index of fresh water (meltwater) at 0 C and 532 nm (ATLAS): 1.3577."""


def _check_n_mss(n, mss):
    n = _finite_array("n", n)
    if np.any(n <= 0):
        raise ValueError(f"n must be > 0 (got {n!r})")
    mss = _finite_array("mss", mss)
    if np.any(mss <= 0):
        raise ValueError(f"mss must be > 0 (got {mss!r})")
    return n, mss


def sigma0_nadir(n, mss):
    r"""Nadir backscatter cross-section per unit area :math:`\sigma^0` [1] of a rough sea
    surface of relative index ``n`` and total mean-square slope ``mss`` (geometric optics /
    Kirchhoff, isotropic Gaussian slopes):

    .. math:: \sigma^0(0) = \frac{F(0)}{s^2}\quad
              \Big(\sigma^0(\theta) = \frac{F(0)}{s^2\cos^4\theta}
              \exp\!\big(-\tfrac{\tan^2\theta}{s^2}\big)\Big)

    Slopes from Cox & Munk (1954); the specular-point form is D. E. Barrick, "Rough surface
    scattering based on the specular point theory", IEEE Trans. Antennas Propag. 16(4),
    449-454 (1968)."""
    n, mss = _check_n_mss(n, mss)
    return _result(fresnel_normal(n) / mss)


def nadir_return_weight(n, mss):
    r"""The nadir return of the rough water surface in the integrators' weight units, where a
    flat Lambertian plate of albedo 0.9 weighs 1 and a surface weighs
    :math:`\pi f_r(\mathbf{i}, \mathbf{o})\cos\theta_o / 0.9` (monostatic, so at nadir
    :math:`\mathbf{i} = \mathbf{o} = \mathbf{n}`).

    Derivation. Beckmann's slope distribution
    :math:`P(z_x, z_y) = \exp(-(z_x^2 + z_y^2)/\alpha^2)/(\pi\alpha^2)` has
    :math:`\langle z_x^2 + z_y^2\rangle = \alpha^2`, so :math:`\alpha^2 = s^2`, the Cox-Munk
    total mean-square slope. Its normal distribution
    :math:`D(\mathbf{h}) = P(\tan\theta_h)/\cos^4\theta_h` is :math:`1/(\pi\alpha^2)` at
    :math:`\mathbf{h} = \mathbf{n}`. The microfacet (Torrance-Sparrow / Walter et al. 2007)
    reflection term is

    .. math:: f_r = \frac{F(\mathbf{i}\cdot\mathbf{h})\,D(\mathbf{h})\,G(\mathbf{i},\mathbf{o})}
                         {4\cos\theta_i\cos\theta_o},

    and at nadir :math:`\mathbf{h} = \mathbf{n}`, :math:`F = F(0)`, and the Smith shadowing
    :math:`G = 1` (:math:`G_1 \to 1` as :math:`\tan\theta \to 0`). Hence

    .. math::

        w = \frac{\pi f_r \cos\theta_o}{0.9} = \frac{\pi F(0)}{0.9\cdot 4\pi s^2}
          = \frac{F(0)}{4\cdot 0.9\, s^2} = \frac{\sigma^0(0)}{3.6}.

    (Cross-check: :math:`\sigma^0 = 4\pi f_r \cos^2\theta` for a monostatic BRDF gives
    :math:`\sigma^0(0) = F(0)/s^2`, :func:`sigma0_nadir`; the plate has
    :math:`\sigma^0 = 4 \cdot 0.9`.) About 1.9 for calm water (:math:`s^2 = 0.003`), 0.2 at
    5 m/s."""
    n, mss = _check_n_mss(n, mss)
    return _result(fresnel_normal(n) / (4.0 * REFERENCE_ALBEDO * mss))


def _positive_finite(name: str, value, *, minimum: float = 0.0, inclusive: bool = False):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"water: {name} must be a number (got {value!r})") from None
    ok = math.isfinite(v) and (v >= minimum if inclusive else v > minimum)
    if not ok:
        raise ValueError(f"water: {name} must be {'>=' if inclusive else '>'} {minimum:g} "
                         f"and finite (got {value!r})")
    return v


def water_bsdf(*, wind_speed_mps=None, mss=None, ior=None, group_index=None) -> dict:
    """A Mitsuba BSDF dict for ``mi.load_dict``: ``{"type": "water", ...}`` (``plugins/water.py``).

    >>> import lidar_mitsuba as lm
    >>> lm.water_bsdf(wind_speed_mps=5)["type"]
    'water'

    Args:
        wind_speed_mps: wind speed at 12.5 m [m/s] (>= 0): the surface's mean-square slope is
            :func:`cox_munk_mss` of it. Default 0 (calm: s^2 = 0.003) unless ``mss`` is given.
        mss: total mean-square slope (> 0) instead of the wind speed.
        ior: phase refractive index of the water (> 1; default the plugin's,
            :data:`WATER_INDEX_532`).
        group_index: group refractive index (>= 1; default the plugin's,
            :data:`WATER_GROUP_INDEX_532`).

    Raises ``ValueError`` naming the argument for a bad value or for both ``wind_speed_mps``
    and ``mss``.
    """
    out: dict = {"type": "water"}
    if wind_speed_mps is not None and mss is not None:
        raise ValueError(f"water: give wind_speed_mps or mss, not both "
                         f"(got {wind_speed_mps!r} and {mss!r})")
    if mss is not None:
        out["mss"] = _positive_finite("mss", mss)
    else:
        out["wind_speed_mps"] = _positive_finite(
            "wind_speed_mps", 0.0 if wind_speed_mps is None else wind_speed_mps, inclusive=True)
    if ior is not None:
        out["int_ior"] = _positive_finite("ior", ior, minimum=1.0)
    if group_index is not None:
        out["group_index"] = _positive_finite("group_index", group_index, minimum=1.0,
                                              inclusive=True)
    return out


# --------------------------------------------------------------------------- light in water
PURE_WATER_ABSORPTION_532_PER_M = 0.0444
"""Absorption of pure water at 532 nm [1/m]: Pope & Fry (1997), Appl. Opt. 36, 8710, linear
between their 530.0 nm (0.0434) and 532.5 nm (0.0447) entries (read in a transcription of
their table, not in the paper)."""

PURE_WATER_SCATTERING_532_PER_M = 0.0017
"""Scattering of pure water at ~530 nm [1/m]: Morel (1974), as tabulated by Smith & Baker
(1981), Appl. Opt. 20, 177 (read in a transcription)."""

PARRISH_SEAWATER_INDEX = 1.34116
"""The refractive index ICESat-2 bathymetry corrects with (Parrish et al. 2019, Remote Sens.
11, 1634: their published correction code; 1.33469 for fresh water): a phase index, used for
the speed of light in water too."""


def refraction_correction(apparent_depth_m, *, ref_elev_deg=90.0, n_air=1.00029,
                          n_water=PARRISH_SEAWATER_INDEX):
    """Parrish et al. (2019)'s refraction correction of a bathymetric photon: the true depth
    [m] below the water surface of a photon ``apparent_depth_m`` below it (surface height
    minus photon height, uncorrected), seen at reference elevation ``ref_elev_deg`` (90 at
    nadir). Snell's law bends the ray (theta_2 = asin(n_air sin theta_1 / n_water)) and the
    slower light shortens the slant range (R = S n_air / n_water); the vertical part of the
    displacement P between the uncorrected and corrected points is taken off:

        S = D / cos theta_1,  R = S n_air / n_water,
        P = sqrt(R^2 + S^2 - 2 R S cos(theta_1 - theta_2)),
        beta = pi/2 - theta_1 - asin(R sin(theta_1 - theta_2) / P),  dZ = P sin(beta).

    At nadir the true depth is ``D n_air / n_water``. Parrish et al. use one (phase) index
    for both; a pulse travels at the group velocity, so an apparent depth timed at c / n_g
    (what the simulator does, and the photons ATLAS times) comes back ``n_g / n_water`` too
    deep (1.2 % for fresh water at 532 nm against 1.34116): pass ``n_water`` = the group
    index to undo the timing exactly at nadir."""
    d = np.asarray(apparent_depth_m, dtype=float)
    th1 = math.radians(90.0 - float(ref_elev_deg))
    th2 = math.asin(n_air * math.sin(th1) / n_water)
    s = d / math.cos(th1)
    r = s * n_air / n_water
    p = np.sqrt(np.maximum(r * r + s * s - 2 * r * s * math.cos(th1 - th2), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        alpha = np.where(p > 0, np.arcsin(np.clip(r * math.sin(th1 - th2)
                                                  / np.where(p > 0, p, 1), -1, 1)), 0.0)
    dz = p * np.sin(math.pi / 2 - th1 - alpha)
    return _result(d - dz)
