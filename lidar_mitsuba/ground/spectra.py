"""Power spectra of terrain and the fit of its fractal exponent p.

Checks that a surface (a :func:`lidar_mitsuba.ground.terrain.fractal` tile, a DEM, an along-track
profile) has a 1/f^p spectrum, and estimates p (the paper's Fig. 3).

* Lengths in metres [m]; spatial frequencies in cycles per metre [1/m].
* Power spectra are periodogram *densities*: two-sided, normalised so that the
  sum of ``psd * df`` over all frequencies equals the mean-square height
  (Parseval). 2-D: [m^2 / (1/m)^2] = [m^4]; 1-D: [m^2 / (1/m)] = [m^3]. Only
  the shape (the log-log slope) matters for :func:`fit_p`.

Pure numpy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..constants import ParameterError

__all__ = ["SpectralFit", "radial_power_spectrum", "profile_power_spectrum", "fit_p"]


def _check_grid_m(grid_m: float) -> float:
    g = float(grid_m)
    if not (math.isfinite(g) and g > 0.0):
        raise ParameterError("grid_m", f"must be > 0 (got {grid_m})")
    return g


def _periodogram_2d(z: np.ndarray, grid_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(|f| [1/m], psd [m^4]) on the full 2-D FFT grid, mean removed."""
    ny, nx = z.shape
    zz = z - z.mean()
    F = np.fft.fft2(zz)
    psd = (np.abs(F) ** 2) * (grid_m * grid_m) / (nx * ny)
    fy = np.fft.fftfreq(ny, d=grid_m)
    fx = np.fft.fftfreq(nx, d=grid_m)
    fr = np.hypot(fy[:, None], fx[None, :])
    return fr, psd


def _radial_bins(fr: np.ndarray, grid_m: float, shape: tuple[int, int], n_bins: int | None):
    """Bin index per FFT cell (-1 = excluded, i.e. DC) and the number of bins."""
    ny, nx = shape
    df = 1.0 / (min(nx, ny) * grid_m)  # the coarser fundamental
    if n_bins is None:
        idx = np.rint(fr / df).astype(np.intp) - 1  # ring k (k >= 1) -> bin k-1
        idx[fr == 0.0] = -1
        nb = int(idx.max()) + 1
    else:
        nb = int(n_bins)
        if nb < 1:
            raise ParameterError("n_bins", f"must be >= 1 (got {n_bins})")
        fpos = fr[fr > 0.0]
        lo, hi = float(fpos.min()), float(fr.max())
        edges = np.geomspace(lo, hi, nb + 1)
        edges[0] = lo * (1 - 1e-12)
        edges[-1] = hi * (1 + 1e-12)
        idx = np.searchsorted(edges, fr, side="right") - 1
        idx[(fr == 0.0) | (idx >= nb)] = -1
    return idx, nb


def radial_power_spectrum(
    z_m: Any, *, grid_m: float = 1.0, n_bins: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Radially averaged 2-D periodogram of a heightfield.

    Parameters
    ----------
    z_m : array (ny, nx) [m]
        Heights; the mean is removed first.
    grid_m : float
        Grid spacing [m].
    n_bins : int or None
        None (default): integer-radius annuli, bin k collects the FFT cells with
        round(``|f|`` / df) == k, df = 1 / (min(nx, ny) * grid_m), k = 1, 2, ...
        (the corners beyond the Nyquist circle are kept: partial annuli).
        An int: that many log-spaced annuli between the lowest nonzero ``|f|`` and
        the largest ``|f|``.

    Returns
    -------
    f_per_m : (nb,) mean ``|f|`` [1/m] of the cells in each non-empty bin
    psd : (nb,) mean periodogram density ``|FFT|^2`` dx dy / (nx ny) [m^4] in the bin
    counts : (nb,) number of FFT cells in the bin (int)

    DC is excluded; empty bins are dropped.
    """
    z = np.asarray(z_m, dtype=np.float64)
    if z.ndim != 2:
        raise ParameterError("z_m", f"must be 2-D (got shape {z.shape})")
    g = _check_grid_m(grid_m)
    fr, psd = _periodogram_2d(z, g)
    idx, nb = _radial_bins(fr, g, z.shape, n_bins)
    keep = idx >= 0
    i = idx[keep]
    counts = np.bincount(i, minlength=nb)
    fsum = np.bincount(i, weights=fr[keep], minlength=nb)
    psum = np.bincount(i, weights=psd[keep], minlength=nb)
    ok = counts > 0
    return fsum[ok] / counts[ok], psum[ok] / counts[ok], counts[ok].astype(np.int64)


def _periodogram_1d(z: np.ndarray, grid_m: float, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-profile periodograms along ``axis`` (moved last), positive f only.

    Returns f (m,) [1/m] and psd (..., m) [m^3], one row per profile.
    """
    zz = np.moveaxis(z, axis, -1)
    n = zz.shape[-1]
    if n < 4:
        raise ParameterError("z_m", f"profiles need at least 4 samples (got {n})")
    zz = zz - zz.mean(axis=-1, keepdims=True)
    F = np.fft.rfft(zz, axis=-1)
    psd = (np.abs(F) ** 2) * grid_m / n
    f = np.fft.rfftfreq(n, d=grid_m)
    return f[1:], psd[..., 1:]


def profile_power_spectrum(
    z_m: Any, *, grid_m: float = 1.0, axis: int = -1
) -> tuple[np.ndarray, np.ndarray]:
    """1-D periodogram of a height profile (mean removed), positive frequencies.

    Parameters
    ----------
    z_m : array (n,) [m], or (ny, nx) [m]
        A profile with sample spacing ``grid_m``. A 2-D array is treated as a
        stack of profiles along ``axis`` (default -1: the rows, i.e. along x); each
        has its own mean removed and the periodograms are averaged over profiles.
    grid_m : float
        Sample spacing [m].

    Returns
    -------
    f_per_m : (m,) frequencies k / (n grid_m), k = 1 .. n//2 [1/m]
    psd : (m,) two-sided periodogram density ``|FFT|^2`` dx / n [m^3]
    """
    z = np.asarray(z_m, dtype=np.float64)
    if z.ndim not in (1, 2):
        raise ParameterError("z_m", f"must be 1-D or 2-D (got shape {z.shape})")
    g = _check_grid_m(grid_m)
    f, psd = _periodogram_1d(z, g, axis if z.ndim == 2 else -1)
    if psd.ndim == 2:
        psd = psd.mean(axis=0)
    return f, psd


# --------------------------------------------------------------------------- #
# Spectral exponent fit
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class SpectralFit:
    """Result of :func:`fit_p`.

    p, p_se : fractal exponent of the 1/f^p amplitude filter and its standard error
    slope, slope_se : log10-log10 slope of the power spectrum and its standard error
    f_min_per_m, f_max_per_m : lowest / highest frequency [1/m] actually used in the fit
    """

    p: float
    p_se: float
    slope: float
    slope_se: float
    f_min_per_m: float
    f_max_per_m: float


def _wls_line(
    x: np.ndarray, y: np.ndarray, w: np.ndarray, *, robust: bool = False
) -> tuple[float, float]:
    """Weighted least-squares slope of y(x) and its standard error from residuals.

    robust=False: classical se^2 = [sum w r^2 / (n-2)] / Sxx, Sxx = sum w (x-xbar)^2
    (valid when var(y_i) ~ 1/w_i). robust=True: heteroscedasticity-consistent
    (HC1 sandwich) se^2 = n/(n-2) * sum w^2 (x-xbar)^2 r^2 / Sxx^2.
    """
    if x.size < 3:
        raise ValueError(f"fit range holds only {x.size} frequencies; need >= 3")
    sw = w.sum()
    xm = (w * x).sum() / sw
    ym = (w * y).sum() / sw
    sxx = (w * (x - xm) ** 2).sum()
    if sxx <= 0.0:
        raise ValueError("fit range holds a single distinct frequency")
    b = (w * (x - xm) * (y - ym)).sum() / sxx
    a = ym - b * xm
    r = y - (a + b * x)
    n = x.size
    if robust:
        var = n / (n - 2) * (w * w * (x - xm) ** 2 * r * r).sum() / sxx**2
    else:
        var = (w * r * r).sum() / (n - 2) / sxx
    return float(b), float(math.sqrt(var))


def fit_p(
    z_m: Any,
    *,
    grid_m: float = 1.0,
    f_min_per_m: float | None = None,
    f_max_per_m: float | None = None,
    axis: int | None = None,
) -> SpectralFit:
    """Estimate the fractal exponent p of a surface or profile from its spectrum.

    Model (for a surface made by :func:`fractal` with exponent p):

    * 2-D input, ``axis=None``: the radially averaged power spectrum falls as
      ``|f|^(-2p)`` -> p = -slope / 2.
    * 1-D input (one profile), or 2-D input with ``axis`` = 0 or 1 (every
      profile along that axis; axis=1 / -1 = rows, along x): a straight profile
      through an isotropic 1/f^p surface has a 1-D spectrum ~ f^-(2p-1)
      -> p = (1 - slope) / 2. Using all profiles of a grid averages away most of
      the periodogram noise of a single profile.

    Estimator: log-periodogram regression. For each FFT cell the periodogram of
    a Gaussian field is exponentially distributed about its expectation S(f),
    so E[log10 P] = log10 S(f) - gamma/ln 10, a constant offset that does not
    bias the slope. The fit is therefore a straight line through the *mean of
    log10 P* against the *mean of log10 |f|*:

    * 2-D: per integer-radius annulus (as in :func:`radial_power_spectrum`),
      weighted by the number of cells in the annulus (its variance is ~1/count);
    * 1-D: per frequency, averaged over the profiles if several, equal weights.

    The slope's standard error comes from the weighted residuals,
    se^2 = [sum w r^2 / (n - 2)] / sum w (x - xbar)^2 (single profile, 2-D);
    for several averaged profiles, whose mean log-periodogram is much noisier at
    low f (profiles of one surface are correlated there), the
    heteroscedasticity-consistent (HC1 sandwich) form is used instead.
    p_se = slope_se / 2.

    Default frequency range (both limits inclusive):

    * f_min = 3 / (n grid_m), n the number of samples per side/profile: skips
      the two lowest frequencies (k = 1, 2 cycles per tile), which hold very few
      independent cells (and, for real data, detrending leakage);
    * f_max = 0.25 / grid_m, half the Nyquist frequency: keeps clear of the top
      of the band where, for sampled real terrain, aliasing and instrument
      smoothing bend the spectrum. For a 2-D field made by :func:`fractal` the
      spectrum is an exact power law up to Nyquist; for a profile the discrete
      sum over the cross-track frequencies (truncated at Nyquist) steepens the
      1-D spectrum slightly near the top, a known bias in p of +0.015 (p=1.5),
      +0.008 (p=1.8), +0.005 (p=2.0) with this range at n = 1024, far below the
      noise of a single profile (p_se ~ 0.04).

    Returns a :class:`SpectralFit` whose f_min_per_m / f_max_per_m are the
    lowest / highest frequencies actually used.
    """
    z = np.asarray(z_m, dtype=np.float64)
    g = _check_grid_m(grid_m)
    if z.ndim not in (1, 2):
        raise ParameterError("z_m", f"must be 1-D or 2-D (got shape {z.shape})")
    if z.ndim == 1 and axis is not None:
        raise ParameterError("axis", "must be None for a 1-D profile")
    if not np.all(np.isfinite(z)):
        raise ParameterError("z_m", "must be finite")

    one_d = z.ndim == 1 or axis is not None
    if one_d:
        ax = -1 if z.ndim == 1 else int(axis)  # type: ignore[arg-type]
        if z.ndim == 2 and ax not in (0, 1, -1, -2):
            raise ParameterError("axis", f"must be 0, 1 or None (got {axis})")
        n = z.shape[ax]
    else:
        n = min(z.shape)
    lo, hi = _fit_range(n, g, f_min_per_m, f_max_per_m)
    if one_d:
        return _fit_profiles(z, g, ax, lo, hi)
    return _fit_radial(z, g, lo, hi)


def _fit_range(n: int, g: float, f_min_per_m: float | None, f_max_per_m: float | None
               ) -> tuple[float, float]:
    """:func:`fit_p`'s frequency range [1/m] for ``n`` samples per side/profile at ``g`` [m]:
    the given limits, checked, or the defaults ``3 / (n g)`` and ``0.25 / g``."""
    lo = 3.0 / (n * g) if f_min_per_m is None else float(f_min_per_m)
    hi = 0.25 / g if f_max_per_m is None else float(f_max_per_m)
    if not (math.isfinite(lo) and lo > 0.0):
        raise ParameterError("f_min_per_m", f"must be > 0 (got {f_min_per_m})")
    if not (math.isfinite(hi) and hi > lo):
        raise ParameterError("f_max_per_m", f"must be > f_min_per_m (got {f_max_per_m})")
    return lo, hi


def _inclusive(lo: float, hi: float) -> tuple[float, float]:
    """``(lo, hi)`` widened by a relative 1e-9, so that limits given as k/(n grid) include k."""
    tol = 1e-9
    return lo * (1 - tol), hi * (1 + tol)


def _fit_profiles(z: np.ndarray, g: float, ax: int, lo: float, hi: float) -> SpectralFit:
    """:func:`fit_p` of the profiles of ``z`` along ``ax`` (one for 1-D ``z``): the mean
    log-periodogram per frequency in ``[lo, hi]`` [1/m], equal weights, ``p = (1 - slope) /
    2``."""
    lo_t, hi_t = _inclusive(lo, hi)
    f, psd = _periodogram_1d(z, g, ax)
    psd2 = np.atleast_2d(psd)
    sel = (f >= lo_t) & (f <= hi_t)
    f = f[sel]
    psd2 = psd2[:, sel]
    if np.any(psd2 <= 0.0):
        raise ValueError("z_m has zero power at some fitted frequency (flat or degenerate profile)")
    x = np.log10(f)
    y = np.log10(psd2).mean(axis=0)
    w = np.ones_like(x)
    fmin, fmax = float(f.min()) if f.size else lo, float(f.max()) if f.size else hi
    # Several profiles: their average log-periodogram is far noisier at low f
    # (profiles of one surface are strongly correlated there) than at high f,
    # so use the heteroscedasticity-consistent standard error.
    slope, se = _wls_line(x, y, w, robust=psd2.shape[0] > 1)
    return SpectralFit(
        p=(1.0 - slope) / 2.0,
        p_se=se / 2.0,
        slope=slope,
        slope_se=se,
        f_min_per_m=fmin,
        f_max_per_m=fmax,
    )


def _fit_radial(z: np.ndarray, g: float, lo: float, hi: float) -> SpectralFit:
    """:func:`fit_p` of a surface ``z``: the mean log-periodogram per integer-radius annulus
    whose centre lies in ``[lo, hi]`` [1/m], weighted by its cell count, ``p = -slope / 2``."""
    lo_t, hi_t = _inclusive(lo, hi)
    fr, psd = _periodogram_2d(z, g)
    idx, nb = _radial_bins(fr, g, z.shape, None)
    # Ring k (bin k-1) holds the cells with round(|f|/df) == k; the range test
    # is applied to the ring centre k*df, the fit uses the cells' mean log10|f|.
    df = 1.0 / (min(z.shape) * g)
    centre = (np.arange(nb) + 1.0) * df
    keep = idx >= 0
    i = idx[keep]
    frk = fr[keep]
    pk = psd[keep]
    if np.any(pk <= 0.0):
        raise ValueError("z_m has zero power in some FFT cell (flat or degenerate surface)")
    counts = np.bincount(i, minlength=nb).astype(np.float64)
    ok = counts > 0
    fmean = np.zeros(nb)
    fmean[ok] = np.bincount(i, weights=frk, minlength=nb)[ok] / counts[ok]
    lx = np.zeros(nb)
    ly = np.zeros(nb)
    lx[ok] = np.bincount(i, weights=np.log10(frk), minlength=nb)[ok] / counts[ok]
    ly[ok] = np.bincount(i, weights=np.log10(pk), minlength=nb)[ok] / counts[ok]
    sel = ok & (centre >= lo_t) & (centre <= hi_t)
    slope, se = _wls_line(lx[sel], ly[sel], counts[sel])
    return SpectralFit(
        p=-slope / 2.0,
        p_se=se / 2.0,
        slope=slope,
        slope_se=se,
        f_min_per_m=float(fmean[sel].min()),
        f_max_per_m=float(fmean[sel].max()),
    )
