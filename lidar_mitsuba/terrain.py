"""Synthetic terrain: periodic heightfields, fractal (1/f^p) surfaces, roughness and spectra.

This module implements the scene-synthesis part of Zhang & Kerekes, "First
Principles Simulation of Spaceborne Micropulse Photon-Counting Lidar
Performance on Complex Surfaces" (section III.A):

* frequency synthesis of a fractal surface (eqs. 2-4): white Gaussian noise on an
  N x N grid -> DFT -> 1/f^p filter -> inverse DFT, rescaled to a requested
  total elevation range (relief);
* the RMS height of a profile (eqs. 5-6);
* periodogram tools and a spectral-exponent estimator (:func:`fit_p`) to check
  that a surface really has the requested 1/f^p spectrum.

Units and conventions
---------------------
* All lengths (x, y, heights, grid spacing, footprint sigma) are in metres [m].
* Spatial frequencies are in cycles per metre [1/m]; "integer frequency" k means
  k cycles per tile, i.e. f = k / (N * grid_m).
* A heightfield is stored as ``z_m[iy, ix]``: row index iy runs along y, column
  index ix along x; node (iy, ix) sits at x = ix * grid_m, y = iy * grid_m.
* Power spectra are periodogram *densities*: two-sided, normalised so that the
  sum of ``psd * df`` over all frequencies equals the mean-square height
  (Parseval). 2-D: [m^2 / (1/m)^2] = [m^4]; 1-D: [m^2 / (1/m)] = [m^3]. Only
  the shape (the log-log slope) matters for :func:`fit_p`.

Pure numpy / scipy; no renderer import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import ndimage

__all__ = [
    "Heightfield",
    "SpectralFit",
    "flat",
    "fractal",
    "rms_height_m",
    "radial_power_spectrum",
    "profile_power_spectrum",
    "fit_p",
]

_N_MIN = 8
_N_MAX = 8192


# --------------------------------------------------------------------------- #
# Heightfield
# --------------------------------------------------------------------------- #
@dataclass(frozen=True, eq=False)
class Heightfield:
    """Periodic heightfield on a regular grid.

    ``z_m[iy, ix]`` is the height [m] at x = ix*grid_m, y = iy*grid_m.

    Attributes
    ----------
    z_m : np.ndarray, shape (ny, nx), float64
        Heights [m]. Stored as a read-only array (copied on construction unless
        it already is a read-only float64 array), so cached derived grids stay
        valid.
    grid_m : float
        Grid spacing [m], the same along x and y.
    periodic : bool
        True: the surface tiles with period (size_x_m, size_y_m) (fractal
        surfaces from :func:`fractal` are periodic by construction; look-ups wrap
        around). False: the surface covers x in [0, (nx-1)*grid_m] and y in
        [0, (ny-1)*grid_m]; look-ups outside are clamped to the border.
    """

    z_m: np.ndarray
    grid_m: float
    periodic: bool = True
    _cache: dict = field(init=False, repr=False, compare=False, default_factory=dict)

    def __post_init__(self) -> None:
        z = self.z_m
        if not (isinstance(z, np.ndarray) and z.dtype == np.float64 and not z.flags.writeable):
            z = np.array(z, dtype=np.float64, copy=True)
            z.setflags(write=False)
        if z.ndim != 2:
            raise ValueError(f"z_m must be a 2-D array (ny, nx) (got shape {z.shape})")
        if z.shape[0] < 2 or z.shape[1] < 2:
            raise ValueError(f"z_m must have at least 2 x 2 nodes (got shape {z.shape})")
        if not np.all(np.isfinite(z)):
            raise ValueError("z_m must be finite everywhere")
        g = float(self.grid_m)
        if not (math.isfinite(g) and g > 0.0):
            raise ValueError(f"grid_m must be > 0 (got {self.grid_m})")
        object.__setattr__(self, "z_m", z)
        object.__setattr__(self, "grid_m", g)
        object.__setattr__(self, "periodic", bool(self.periodic))

    # ---- simple properties ------------------------------------------------ #
    @property
    def nx(self) -> int:
        """Number of nodes along x (columns)."""
        return int(self.z_m.shape[1])

    @property
    def ny(self) -> int:
        """Number of nodes along y (rows)."""
        return int(self.z_m.shape[0])

    @property
    def size_x_m(self) -> float:
        """Tile length along x [m] = nx * grid_m (the period when periodic)."""
        return self.nx * self.grid_m

    @property
    def size_y_m(self) -> float:
        """Tile length along y [m] = ny * grid_m (the period when periodic)."""
        return self.ny * self.grid_m

    @property
    def relief_m(self) -> float:
        """Total elevation range max(z) - min(z) [m]."""
        return float(self.z_m.max() - self.z_m.min())

    # ---- look-ups --------------------------------------------------------- #
    def _interp(self, grid: np.ndarray, x_m: Any, y_m: Any) -> np.ndarray:
        """Bilinear interpolation of a (ny, nx) grid at (x_m, y_m) [m]."""
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        x, y = np.broadcast_arrays(x, y)
        bad = ~(np.isfinite(x) & np.isfinite(y))
        if bad.any():
            x = np.where(bad, 0.0, x)
            y = np.where(bad, 0.0, y)
        fx = x / self.grid_m
        fy = y / self.grid_m
        nx, ny = self.nx, self.ny
        if self.periodic:
            fx = np.mod(fx, nx)
            fy = np.mod(fy, ny)
            ix0 = np.floor(fx).astype(np.intp)
            iy0 = np.floor(fy).astype(np.intp)
            tx = fx - ix0
            ty = fy - iy0
            # np.mod can return exactly n for tiny negative inputs: fold back.
            ix0 %= nx
            iy0 %= ny
            ix1 = (ix0 + 1) % nx
            iy1 = (iy0 + 1) % ny
        else:
            fx = np.clip(fx, 0.0, nx - 1)
            fy = np.clip(fy, 0.0, ny - 1)
            ix0 = np.minimum(np.floor(fx).astype(np.intp), nx - 2)
            iy0 = np.minimum(np.floor(fy).astype(np.intp), ny - 2)
            tx = fx - ix0
            ty = fy - iy0
            ix1 = ix0 + 1
            iy1 = iy0 + 1
        z00 = grid[iy0, ix0]
        z01 = grid[iy0, ix1]
        z10 = grid[iy1, ix0]
        z11 = grid[iy1, ix1]
        out = (1.0 - ty) * ((1.0 - tx) * z00 + tx * z01) + ty * ((1.0 - tx) * z10 + tx * z11)
        if bad.any():
            out = np.where(bad, np.nan, out)
        return out

    def height_m(self, x_m: Any, y_m: Any) -> np.ndarray:
        """Surface height [m] at points (x_m, y_m) [m] by bilinear interpolation.

        ``x_m`` and ``y_m`` are array-likes of any broadcast-compatible shapes; the
        result has the broadcast shape. Periodic heightfields wrap (x is taken
        modulo size_x_m, y modulo size_y_m); non-periodic ones clamp the point to
        the grid [0, (nx-1)*grid_m] x [0, (ny-1)*grid_m]. Exact at grid nodes.
        Non-finite coordinates give NaN.
        """
        return self._interp(self.z_m, x_m, y_m)

    def smoothed_grid(self, *, sigma_m: float) -> np.ndarray:
        """The grid convolved with an isotropic Gaussian of std ``sigma_m`` [m].

        Shape (ny, nx), read-only, cached per sigma. Uses
        ``scipy.ndimage.gaussian_filter(z, sigma_m / grid_m, truncate=4.0)`` with
        mode 'wrap' (periodic) or 'nearest' (non-periodic). sigma_m == 0 returns
        the raw grid.
        """
        s = float(sigma_m)
        if not (math.isfinite(s) and s >= 0.0):
            raise ValueError(f"sigma_m must be >= 0 (got {sigma_m})")
        if s == 0.0:
            return self.z_m
        cached = self._cache.get(s)
        if cached is None:
            cached = ndimage.gaussian_filter(
                self.z_m,
                s / self.grid_m,
                mode="wrap" if self.periodic else "nearest",
                truncate=4.0,
            )
            cached.setflags(write=False)
            if len(self._cache) >= 8:  # keep the cache small
                self._cache.pop(next(iter(self._cache)))
            self._cache[s] = cached
        return cached

    def reference_elevation_m(self, x_m: Any, y_m: Any, *, sigma_m: float) -> np.ndarray:
        """Gaussian-footprint-weighted mean surface height [m] around each point.

        The weight of the surface at horizontal distance r from (x_m, y_m) is
        exp(-r^2 / (2 sigma_m^2)), normalised to unit sum (sigma_m [m] is the
        1-sigma radius of the footprint's irradiance profile). Implemented as a
        Gaussian filter of the grid (cached per sigma, see :meth:`smoothed_grid`;
        kernel truncated at 4 sigma) followed by the same bilinear look-up /
        wrapping rule as :meth:`height_m`. Output shape: broadcast of x_m, y_m.
        """
        return self._interp(self.smoothed_grid(sigma_m=sigma_m), x_m, y_m)

    def profile(self, *, y_m: float, x_m: Any) -> np.ndarray:
        """Heights [m] along the line y = y_m at abscissae x_m [m] (shape of x_m)."""
        x = np.asarray(x_m, dtype=np.float64)
        return self.height_m(x, np.full_like(x, float(y_m)))


# --------------------------------------------------------------------------- #
# Constructors
# --------------------------------------------------------------------------- #
def _grid_count(size_m: float, grid_m: float) -> int:
    size = float(size_m)
    grid = float(grid_m)
    if not (math.isfinite(size) and size > 0.0):
        raise ValueError(f"size_m must be > 0 (got {size_m})")
    if not (math.isfinite(grid) and grid > 0.0):
        raise ValueError(f"grid_m must be > 0 (got {grid_m})")
    n = int(round(size / grid))
    if n < _N_MIN or n > _N_MAX:
        raise ValueError(
            f"size_m / grid_m must give N in [{_N_MIN}, {_N_MAX}] nodes per side "
            f"(got size_m={size_m}, grid_m={grid_m}, N={n})"
        )
    return n


def flat(*, size_m: float = 1024.0, grid_m: float = 1.0, z_m: float = 0.0) -> Heightfield:
    """Flat periodic heightfield at constant height ``z_m`` [m].

    N x N nodes with N = round(size_m / grid_m) (8 <= N <= 8192); the actual tile
    size is N * grid_m [m].
    """
    n = _grid_count(size_m, grid_m)
    h = float(z_m)
    if not math.isfinite(h):
        raise ValueError(f"z_m must be finite (got {z_m})")
    z = np.full((n, n), h, dtype=np.float64)
    z.setflags(write=False)
    return Heightfield(z_m=z, grid_m=float(grid_m), periodic=True)


def check_fractal_parameters(*, p: float, size_m: float, grid_m: float, relief_m: float) -> int:
    """Validate the parameters of :func:`fractal` without building it; returns N (nodes per
    side). Raises ``ValueError`` whose message starts with the parameter's name."""
    pf = float(p)
    if not (math.isfinite(pf) and 0.0 < pf <= 5.0):
        raise ValueError(f"p must be in (0, 5] (got {p})")
    n = _grid_count(size_m, grid_m)
    rel = float(relief_m)
    if not (math.isfinite(rel) and rel >= 0.0):
        raise ValueError(f"relief_m must be >= 0 (got {relief_m})")
    return n


def fractal(
    *,
    p: float = 1.8,
    size_m: float = 1024.0,
    grid_m: float = 1.0,
    relief_m: float = 10.0,
    seed: int | None = 0,
) -> Heightfield:
    """Fractal surface by frequency synthesis (paper eqs. 2-4), periodic.

    Steps on an N x N grid, N = round(size_m / grid_m):

    1. w = standard normal white noise, ``np.random.default_rng(seed)``;
    2. W = DFT(w) / N^2                                            (eq. 2);
    3. H(u, v) = W(u, v) / (u^2 + v^2)^(p/2), u, v the signed integer
       frequencies (cycles per tile), H(0, 0) = 0                  (eq. 3);
    4. h = inverse DFT(H) * N^2                                    (eq. 4);
    5. subtract the mean and scale so that max(h) - min(h) == relief_m.

    The 2-D power spectrum then falls as |f|^(-2p) and a straight profile's
    1-D spectrum as f^-(2p-1); larger p gives a smoother surface.

    Parameters
    ----------
    p : float
        Spectral exponent of the amplitude filter, 0 < p <= 5 (paper: 1.5-2.0).
    size_m, grid_m : float
        Tile side and grid spacing [m]; 8 <= N <= 8192.
    relief_m : float
        Total elevation range [m] (>= 0; 0 gives a flat surface at 0 m).
    seed : int or None
        Seed for ``np.random.default_rng``; same seed -> identical surface.

    Returns
    -------
    Heightfield with z_m of shape (N, N), zero mean, periodic=True.
    """
    n = check_fractal_parameters(p=p, size_m=size_m, grid_m=grid_m, relief_m=relief_m)
    pf, rel = float(p), float(relief_m)
    if seed is not None and not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed must be an int or None (got {seed!r})")

    rng = np.random.default_rng(seed)
    w = rng.standard_normal((n, n))
    # Real input -> Hermitian spectrum; rfft2 stores the non-negative u half.
    W = np.fft.rfft2(w) / (n * n)  # eq. 2
    del w
    v = np.fft.fftfreq(n) * n  # along y (axis 0), signed integers
    u = np.fft.rfftfreq(n) * n  # along x (axis 1), non-negative integers
    k2 = v[:, None] ** 2 + u[None, :] ** 2
    k2[0, 0] = 1.0  # avoid 0**-p; DC is zeroed below
    W *= k2 ** (-0.5 * pf)  # eq. 3
    W[0, 0] = 0.0
    del k2
    h = np.fft.irfft2(W, s=(n, n)) * (n * n)  # eq. 4 (real by Hermitian symmetry)
    del W
    h -= h.mean()
    rng_h = float(h.max() - h.min())
    if rel == 0.0 or rng_h == 0.0:
        h[...] = 0.0
    else:
        h *= rel / rng_h
    h.setflags(write=False)
    return Heightfield(z_m=h, grid_m=float(grid_m), periodic=True)


# --------------------------------------------------------------------------- #
# Roughness and spectra
# --------------------------------------------------------------------------- #
def rms_height_m(z_m: Any) -> float:
    """RMS height sigma [m] of a profile (paper eqs. 5-6).

    sigma = sqrt((sum z_i^2 - N zbar^2) / N), zbar = mean(z), over all N values
    of ``z_m`` (a 1-D profile, or any array, flattened). Evaluated in the
    algebraically identical two-pass form sqrt(mean((z - zbar)^2)) to avoid
    cancellation; equals ``np.std(z_m)`` (ddof=0).
    """
    z = np.asarray(z_m, dtype=np.float64).ravel()
    if z.size == 0:
        raise ValueError("z_m must not be empty")
    d = z - z.mean()
    return float(np.sqrt(np.mean(d * d)))


def _check_grid_m(grid_m: float) -> float:
    g = float(grid_m)
    if not (math.isfinite(g) and g > 0.0):
        raise ValueError(f"grid_m must be > 0 (got {grid_m})")
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
            raise ValueError(f"n_bins must be >= 1 (got {n_bins})")
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
        round(|f| / df) == k, df = 1 / (min(nx, ny) * grid_m), k = 1, 2, ...
        (the corners beyond the Nyquist circle are kept: partial annuli).
        An int: that many log-spaced annuli between the lowest nonzero |f| and
        the largest |f|.

    Returns
    -------
    f_per_m : (nb,) mean |f| [1/m] of the cells in each non-empty bin
    psd : (nb,) mean periodogram density |FFT|^2 dx dy / (nx ny) [m^4] in the bin
    counts : (nb,) number of FFT cells in the bin (int)

    DC is excluded; empty bins are dropped.
    """
    z = np.asarray(z_m, dtype=np.float64)
    if z.ndim != 2:
        raise ValueError(f"z_m must be 2-D (got shape {z.shape})")
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
        raise ValueError(f"z_m profiles need at least 4 samples (got {n})")
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
    psd : (m,) two-sided periodogram density |FFT|^2 dx / n [m^3]
    """
    z = np.asarray(z_m, dtype=np.float64)
    if z.ndim not in (1, 2):
        raise ValueError(f"z_m must be 1-D or 2-D (got shape {z.shape})")
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

    p, p_stderr : fractal exponent of the 1/f^p amplitude filter and its standard error
    slope, slope_stderr : log10-log10 slope of the power spectrum and its standard error
    f_min_per_m, f_max_per_m : lowest / highest frequency [1/m] actually used in the fit
    """

    p: float
    p_stderr: float
    slope: float
    slope_stderr: float
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
      |f|^(-2p) -> p = -slope / 2.
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
    p_stderr = slope_stderr / 2.

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
      noise of a single profile (p_stderr ~ 0.04).

    Returns a :class:`SpectralFit` whose f_min_per_m / f_max_per_m are the
    lowest / highest frequencies actually used.
    """
    z = np.asarray(z_m, dtype=np.float64)
    g = _check_grid_m(grid_m)
    if z.ndim not in (1, 2):
        raise ValueError(f"z_m must be 1-D or 2-D (got shape {z.shape})")
    if z.ndim == 1 and axis is not None:
        raise ValueError("axis must be None for a 1-D profile")
    if not np.all(np.isfinite(z)):
        raise ValueError("z_m must be finite")

    one_d = z.ndim == 1 or axis is not None
    if one_d:
        ax = -1 if z.ndim == 1 else int(axis)  # type: ignore[arg-type]
        if z.ndim == 2 and ax not in (0, 1, -1, -2):
            raise ValueError(f"axis must be 0, 1 or None (got {axis})")
        n = z.shape[ax]
    else:
        n = min(z.shape)
    lo = 3.0 / (n * g) if f_min_per_m is None else float(f_min_per_m)
    hi = 0.25 / g if f_max_per_m is None else float(f_max_per_m)
    if not (math.isfinite(lo) and lo > 0.0):
        raise ValueError(f"f_min_per_m must be > 0 (got {f_min_per_m})")
    if not (math.isfinite(hi) and hi > lo):
        raise ValueError(f"f_max_per_m must be > f_min_per_m (got {f_max_per_m})")
    tol = 1e-9  # relative slack so that limits given as k/(n grid) include k
    lo_t, hi_t = lo * (1 - tol), hi * (1 + tol)

    if one_d:
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
            p_stderr=se / 2.0,
            slope=slope,
            slope_stderr=se,
            f_min_per_m=fmin,
            f_max_per_m=fmax,
        )

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
        p_stderr=se / 2.0,
        slope=slope,
        slope_stderr=se,
        f_min_per_m=float(fmean[sel].min()),
        f_max_per_m=float(fmean[sel].max()),
    )
