"""Rough sea ice at the footprint scale: a Gaussian random surface of published rms height and
correlation length (``SurfaceSpec(kind="sea_ice")``, ``--surface sea_ice``).

What ATLAS sees of sea ice within a 20 m ATL03 segment is the ice's (and its snow's) relief at
scales of ~1 to ~30 m: its photons come from all over each ~11 m footprint, and the segment's
median removes only the relief longer than the segment. The fractal of
:func:`~lidar_mitsuba.ground.terrain.fractal` puts nearly all its variance at the tile's longest
wavelengths (a 1/f^1.8 spectrum), so a published rms carried by it leaves only a few cm inside a
segment. Airborne laser surveys of Arctic sea ice give the two numbers that fix the relief at
the segment's scale instead: the rms height and the correlation length.

The surface is an isotropic stationary Gaussian random field with the exponential
autocorrelation

.. math:: C(r) = \\sigma^2 \\, e^{-r / L},

synthesised on a periodic N x N grid by filtering white noise with the square root of its 2-D
power spectrum (the Fourier transform of ``C``, a function of the spatial frequency f [1/m]):

.. math:: S(f) = \\frac{2 \\pi L^2 \\sigma^2}{\\left(1 + (2 \\pi f L)^2\\right)^{3/2}},

then its mean removed and scaled so that its rms over the tile is exactly ``sigma`` (a unit
conversion to the published statistic, not a fit). A point's height about the mean of a
straight segment of length ``S`` then has the expected mean square

.. math:: \\sigma_S^2 = \\sigma^2 \\left(1 - \\bar\\rho(S)\\right), \\qquad
          \\bar\\rho(S) = 2 \\left(\\frac{L}{S}\\right)^2 \\left(\\frac{S}{L} - 1 + e^{-S/L}\\right)

(the mean correlation of two points of the segment; :func:`segment_rms_m`), the part of the
relief a segment's reference keeps in its photons' residuals.

Sources (:data:`PRESETS`): the rms height of Arctic sea ice from an airborne laser scanner,
Beckers et al. 2015 (Ann. Glaciol. 56(69), "Sea-ice surface roughness estimates from airborne
laser scanner and laser altimeter observations in Fram Strait and north of Svalbard": the
standard deviation of relative surface elevation, mean 0.16 m in Fram Strait, 0.09 m north of
Svalbard in the Nansen Basin, spring 2010); the correlation length from Operation IceBridge's
Airborne Topographic Mapper over the Arctic Ocean, 94 spring flights 2009-2019, Remote Sens.
2022, 14(13), 3011 (doi:10.3390/rs14133011): mean correlation lengths 20-30 m on 1.5 km
along-track segments. The same paper finds the elevation distribution positively skewed
(an exponentially modified Gaussian fits it better than a Gaussian); its parameters were not
readable here. The skew comes instead from the sparse features the same surveys count:
pressure-ridge sails and other obstacles (:mod:`~lidar_mitsuba.ground.sea_ice_ridges`, a
preset's ``ridges``). With ridges the published rms is the whole surface's: the Gaussian
carries ``sigma_G^2 = sigma^2 - kappa_2`` (``kappa_2`` the ridges' variance, closed form), so
the total keeps the published rms in expectation and the ridges move part of it into sparse
positive relief (height skewness ``kappa_3 / sigma^3``).

Pure numpy / scipy; no renderer import.
"""
from __future__ import annotations

import math

import numpy as np

from ..constants import ParameterError
from ..machine import check_memory
from . import sea_ice_ridges
from .terrain import FRACTAL_BYTES_PER_NODE, Heightfield, _grid_count, check_seed

#: Published sea-ice roughness for :func:`rough_sea_ice` (``rms_m``, ``corr_length_m``, the
#: obstacles ``ridges`` of :data:`~lidar_mitsuba.ground.sea_ice_ridges.RIDGES` or ``none``) and
#: where each number comes from. The correlation length of both is the middle of the published
#: 20-30 m range. The Fram Strait ice carries the Arctic laser profiles' typical obstacles
#: (their variance is ~2/3 of its published rms^2, the rest the Gaussian's); the Nansen Basin's
#: published rms (0.09 m) is below those obstacles' own (0.129 m), so it has none: no regional
#: obstacle statistics for it were readable here.
PRESETS = {
    "fram_strait": {
        "rms_m": 0.16, "corr_length_m": 25.0, "ridges": "arctic_obstacles",
        "source": "rms: Beckers et al. 2015, Ann. Glaciol. 56(69): mean surface roughness "
                  "(sd of relative surface elevation, airborne laser scanner) of the ice in "
                  "Fram Strait, 0.16 m, the older, more deformed ice the transpolar drift "
                  "carries out of the central Arctic (spring 2010); correlation length: "
                  "Remote Sens. 2022, 14(13), 3011 (IceBridge ATM, Arctic, spring 2009-2019): "
                  "mean 20-30 m, 25 m taken"},
    "nansen_basin": {
        "rms_m": 0.09, "corr_length_m": 25.0, "ridges": sea_ice_ridges.NONE,
        "source": "rms: Beckers et al. 2015: 0.09 m north of Svalbard (Nansen Basin, younger "
                  "ice); correlation length as fram_strait"},
}
DEFAULT_PRESET = "fram_strait"
"""The preset ``--surface sea_ice`` takes by default: the central Arctic's multiyear pack as
the published Fram Strait ice samples it (the ice near the pole drifts out through Fram
Strait); ``nansen_basin`` is the younger, smoother published value."""

CENTRAL_ARCTIC_LAT_DEG = 80.0
"""Sea ice at or north of this latitude [deg] is the central Arctic pack (ESTIMATE: the
Arctic basin north of Fram Strait's ~79-80 N and of most of the marginal seas' shelves, where
the older ice that survives the summer circulates before the transpolar drift carries it out
through Fram Strait; the multiyear ice of the Beaufort Sea and the Canadian archipelago
further south is not placed here). Not a fitted value: no real file lies near it (the shipped
ATL03 subset at 87.3 N, the ATL07 files in Baffin Bay at 69 N)."""


def site_preset(*, lat_deg: float) -> tuple[str | None, str]:
    """Which published roughness preset (:data:`PRESETS`) sea ice at ``lat_deg`` [deg] gets,
    and why: the central Arctic pack (:data:`CENTRAL_ARCTIC_LAT_DEG` and north) is the older,
    deformed ice whose roughness Beckers et al. 2015 measured where it leaves the Arctic, in
    Fram Strait (:data:`DEFAULT_PRESET`, with the Arctic laser profiles' ridge sails); any
    other sea ice (the marginal seas, Baffin Bay, the Southern Ocean: mostly seasonal
    first-year ice) gets ``None``, flat snow: no published first-year roughness at the
    footprint scale was readable here (docs/physics/sea-ice-surface.md). Chosen by the ice's
    age and region, never by a comparison with a real file."""
    if math.isfinite(lat_deg) and lat_deg >= CENTRAL_ARCTIC_LAT_DEG:
        return DEFAULT_PRESET, (
            f"central Arctic pack ({lat_deg:.1f} N, at or north of "
            f"{CENTRAL_ARCTIC_LAT_DEG:g} N): older, deformed ice, whose published roughness "
            "is Fram Strait's, where it drifts out (Beckers et al. 2015; ridge sails: "
            "Castellani et al. 2014)")
    return None, (f"sea ice at {lat_deg:.1f} deg, outside the central Arctic pack (north of "
                  f"{CENTRAL_ARCTIC_LAT_DEG:g} N): seasonal first-year ice, for which no "
                  "published roughness preset exists here; flat snow")


ACF = "exponential"
"""The autocorrelation's form: ESTIMATE (the usual model of a random rough surface, and the
one whose e-folding length is the correlation length the ATM study quotes; its definition of
the length was not readable here)."""


def check_parameters(*, rms_m: float, corr_length_m: float, size_m: float,
                     grid_m: float, ridges: str = sea_ice_ridges.NONE) -> int:
    """Validate :func:`rough_sea_ice`'s parameters without building it; returns N (nodes per
    side). Raises :class:`ParameterError` naming the parameter."""
    n = _grid_count(size_m, grid_m)
    if not (math.isfinite(rms_m) and 0.0 <= rms_m <= 10.0):
        raise ParameterError("surface_rms_m", f"must be in [0, 10] (got {rms_m})")
    if not (math.isfinite(corr_length_m) and corr_length_m > 0.0):
        raise ParameterError("surface_corr_m", f"must be > 0 (got {corr_length_m})")
    if corr_length_m < 2.0 * grid_m or corr_length_m > size_m / 8.0:
        raise ParameterError("surface_corr_m", f"must lie between 2 grid steps "
                             f"({2 * grid_m:g} m) and an eighth of the tile ({size_m / 8:g} m) "
                             f"(got {corr_length_m:g})")
    sea_ice_ridges.check(sea_ice_ridges.parameters(ridges), rms_m=rms_m, size_m=size_m)
    return n


def rough_sea_ice(*, rms_m: float, corr_length_m: float, size_m: float = 512.0,
                  grid_m: float = 0.5, seed: int | None = 0,
                  ridges: str = sea_ice_ridges.NONE) -> Heightfield:
    """A periodic Gaussian random surface [m] of exponential autocorrelation (the module's
    spectral synthesis), zero mean; without ridges its rms is exactly ``rms_m`` over the tile,
    with ``ridges`` the Gaussian's is ``sqrt(rms_m^2 - kappa_2)`` and the ridge sails of
    :mod:`~lidar_mitsuba.ground.sea_ice_ridges` (variance ``kappa_2``) are added to it (total
    rms ``rms_m`` in expectation).

    Args:
        rms_m: rms height [m] over the tile.
        corr_length_m: e-folding length of the autocorrelation [m].
        size_m: side of the square tile [m] (>= 8 correlation lengths, so the tile holds the
            relief's statistics).
        grid_m: grid spacing [m].
        seed: seed of the white noise (``np.random.default_rng``; the ridges draw from the
            same generator after it, so a surface without ridges is as before to the bit).
        ridges: obstacle statistics by name (:data:`~lidar_mitsuba.ground.sea_ice_ridges.RIDGES`)
            or ``none``.

    Returns:
        Heightfield of shape (N, N), N = round(size_m / grid_m), periodic.
    """
    import scipy.fft
    n = check_parameters(rms_m=rms_m, corr_length_m=corr_length_m, size_m=size_m,
                         grid_m=grid_m, ridges=ridges)
    ridge = sea_ice_ridges.parameters(ridges)
    check_memory("grid_m", FRACTAL_BYTES_PER_NODE * n * n,
                 f"a {n} x {n} sea-ice surface (size_m / grid_m = {n})",
                 "use a coarser grid_m or a smaller size_m")
    check_seed(seed)
    rng = np.random.default_rng(seed)
    w = scipy.fft.rfft2(rng.standard_normal((n, n)), workers=-1)
    fy = np.fft.fftfreq(n, d=grid_m)[:, None]            # [1/m]
    fx = np.fft.rfftfreq(n, d=grid_m)[None, :]
    arg = 1.0 + (2.0 * np.pi * corr_length_m) ** 2 * (fx * fx + fy * fy)
    w *= arg ** -0.75                                     # sqrt(S(f)), S up to a constant
    w[0, 0] = 0.0
    h = scipy.fft.irfft2(w, s=(n, n), workers=-1)
    h -= h.mean()
    rms = float(np.sqrt(np.mean(h * h)))
    gauss_rms = rms_m if ridge is None else math.sqrt(rms_m ** 2
                                                      - sea_ice_ridges.cumulants(**ridge)[1])
    h *= (gauss_rms / rms) if rms > 0 else 0.0
    if ridge is not None:
        h += sea_ice_ridges.ridge_field(n=n, grid_m=grid_m, rng=rng, **ridge)
        h -= h.mean()
    h.setflags(write=False)
    return Heightfield(z_m=h, grid_m=float(grid_m), periodic=True)


def mean_correlation(segment_m, corr_length_m: float):
    """The mean correlation of two points of a straight segment of length ``segment_m`` [m]
    under ``exp(-r / corr_length_m)``: ``2 (L/S)^2 (S/L - 1 + exp(-S/L))`` (1 at S = 0)."""
    x = np.asarray(segment_m, np.float64) / float(corr_length_m)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 2.0 * (x - 1.0 + np.exp(-x)) / (x * x)
    return np.where(x < 1e-6, 1.0 - x / 3.0, out)


def segment_rms_m(*, rms_m: float, corr_length_m: float, segment_m: float = 20.0):
    """The expected rms height [m] of the surface along a straight segment of ``segment_m``
    [m] about the segment's mean: ``rms_m sqrt(1 - rho_bar)`` (:func:`mean_correlation`)."""
    return rms_m * np.sqrt(1.0 - mean_correlation(segment_m, corr_length_m))
