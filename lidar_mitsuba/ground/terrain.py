"""Synthetic terrain: periodic heightfields, fractal (1/f^p) surfaces and their roughness.

This module implements the scene-synthesis part of Zhang & Kerekes, "First
Principles Simulation of Spaceborne Micropulse Photon-Counting Lidar
Performance on Complex Surfaces" (section III.A):

* frequency synthesis of a fractal surface (eqs. 2-4): white Gaussian noise on an
  N x N grid -> DFT -> 1/f^p filter -> inverse DFT, rescaled to a requested
  total elevation range (relief);
* the RMS height of a profile (eqs. 5-6).

Power spectra and the fit of p (checking that a surface really has the requested
1/f^p spectrum) are in :mod:`lidar_mitsuba.ground.spectra`.

Units and conventions
---------------------
* All lengths (x, y, heights, grid spacing, footprint sigma) are in metres [m].
* Spatial frequencies are in cycles per metre [1/m]; "integer frequency" k means
  k cycles per tile, i.e. f = k / (N * grid_m).
* A heightfield is stored as ``z_m[iy, ix]``: row index iy runs along y, column
  index ix along x; node (iy, ix) sits at x = ix * grid_m, y = iy * grid_m.

Pure numpy / scipy; no renderer import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..constants import ParameterError
from ..machine import check_memory

__all__ = [
    "Heightfield",
    "flat",
    "fractal",
    "rms_height_m",
]

_N_MIN = 8
_N_MAX = 8192
#: peak memory of :func:`fractal` per grid node [bytes]: noise, its half spectrum, the filter,
#: the heights, and the footprint-smoothed grid a run caches
FRACTAL_BYTES_PER_NODE = 48


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
            raise ParameterError("z_m", f"must be a 2-D array (ny, nx) (got shape {z.shape})")
        if z.shape[0] < 2 or z.shape[1] < 2:
            raise ParameterError("z_m", f"must have at least 2 x 2 nodes (got shape {z.shape})")
        if not np.all(np.isfinite(z)):
            raise ParameterError("z_m", "must be finite everywhere")
        g = float(self.grid_m)
        if not (math.isfinite(g) and g > 0.0):
            raise ParameterError("grid_m", f"must be > 0 (got {self.grid_m})")
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
        ix0, ix1, tx = self._cell(x / self.grid_m, self.nx)
        iy0, iy1, ty = self._cell(y / self.grid_m, self.ny)
        z00 = grid[iy0, ix0]
        z01 = grid[iy0, ix1]
        z10 = grid[iy1, ix0]
        z11 = grid[iy1, ix1]
        out = (1.0 - ty) * ((1.0 - tx) * z00 + tx * z01) + ty * ((1.0 - tx) * z10 + tx * z11)
        if bad.any():
            out = np.where(bad, np.nan, out)
        return out

    def _cell(self, f: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The bilinear cell of grid coordinates ``f`` (in nodes) along an axis of ``n``
        nodes: ``(i0, i1, t)``, its two nodes and the fraction from ``i0``; periodic grids
        wrap, the others clamp to the last cell."""
        if self.periodic:
            f = np.mod(f, n)
            i0 = np.floor(f).astype(np.intp)
            t = f - i0
            i0 %= n            # np.mod can return exactly n for tiny negative inputs
            return i0, (i0 + 1) % n, t
        f = np.clip(f, 0.0, n - 1)
        i0 = np.minimum(np.floor(f).astype(np.intp), n - 2)
        return i0, i0 + 1, f - i0

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
        from scipy import ndimage
        s = float(sigma_m)
        if not (math.isfinite(s) and s >= 0.0):
            raise ParameterError("sigma_m", f"must be >= 0 (got {sigma_m})")
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
        Gaussian filter of the grid (:meth:`smoothed_grid`; kernel truncated at
        4 sigma) followed by the same bilinear look-up / wrapping rule as
        :meth:`height_m`. Output shape: broadcast of x_m, y_m.

        When the points touch few grid rows (a track along x crosses two or three),
        only those rows are filtered (:meth:`_smoothed_rows`), with the same bits as
        the whole grid's filter at a fraction of its cost; otherwise the whole grid
        is filtered and cached per sigma.
        """
        s = float(sigma_m)
        if s > 0.0 and math.isfinite(s) and s not in self._cache:
            grid = self._smoothed_rows(s, y_m)
            if grid is not None:
                return self._interp(grid, x_m, y_m)
        return self._interp(self.smoothed_grid(sigma_m=sigma_m), x_m, y_m)

    def _smoothed_rows(self, sigma_m: float, y_m: Any) -> np.ndarray | None:
        """A (ny, nx) array whose rows that :meth:`_interp` reads at ``y_m`` hold
        :meth:`smoothed_grid`'s values, bit for bit (the same two 1-D passes, axis 0
        then axis 1, over the same inputs), the other rows zero (what ``_interp`` reads
        there for points it returns as NaN); ``None`` when the rows' filter windows
        would cover more than the grid (filter it all)."""
        from scipy import ndimage
        y = np.asarray(y_m, dtype=np.float64).ravel()
        y = y[np.isfinite(y)]
        if y.size == 0:
            return None
        ny = self.ny
        iy0, iy1, _ = self._cell(y / self.grid_m, ny)
        rows = np.unique(np.concatenate([iy0, iy1]))
        sd = sigma_m / self.grid_m
        radius = int(4.0 * sd + 0.5)               # gaussian_filter's, truncate = 4
        if rows.size * (2 * radius + 1) >= ny:
            return None
        k = np.arange(-radius, radius + 1)
        window = rows[:, None] + k[None, :]
        window = np.mod(window, ny) if self.periodic else np.clip(window, 0, ny - 1)
        mode = "wrap" if self.periodic else "nearest"
        # pass 1 (axis 0) at the wanted rows only: each row's window of inputs, filtered
        # along the window; the centre is exactly the full filter's value at that row
        across = ndimage.gaussian_filter1d(self.z_m[window], sd, axis=1, mode=mode,
                                           truncate=4.0)[:, radius, :]
        out = np.zeros_like(self.z_m)
        out[rows] = ndimage.gaussian_filter1d(across, sd, axis=1, mode=mode, truncate=4.0)
        return out

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
        raise ParameterError("size_m", f"must be > 0 (got {size_m})")
    if not (math.isfinite(grid) and grid > 0.0):
        raise ParameterError("grid_m", f"must be > 0 (got {grid_m})")
    n = int(round(size / grid))
    if n < _N_MIN or n > _N_MAX:
        raise ParameterError(
            "grid_m", f"size_m / grid_m must give N in [{_N_MIN}, {_N_MAX}] nodes per side "
            f"(got size_m={size_m}, grid_m={grid_m}, N={n})"
        )
    return n


def check_seed(seed) -> None:
    """Refuses (:class:`ParameterError` naming ``seed``) a white-noise seed that is not an
    integer >= 0 or None (``np.random.default_rng``'s: the fractal's and the sea ice's)."""
    if seed is not None and (not isinstance(seed, (int, np.integer)) or isinstance(seed, bool)
                             or seed < 0):
        raise ParameterError("seed", f"must be an integer >= 0 or None (got {seed!r})")


def flat(*, size_m: float = 1024.0, grid_m: float = 1.0, z_m: float = 0.0) -> Heightfield:
    """Flat periodic heightfield at constant height ``z_m`` [m].

    N x N nodes with N = round(size_m / grid_m) (8 <= N <= 8192); the actual tile
    size is N * grid_m [m].
    """
    n = _grid_count(size_m, grid_m)
    h = float(z_m)
    if not math.isfinite(h):
        raise ParameterError("z_m", f"must be finite (got {z_m})")
    z = np.full((n, n), h, dtype=np.float64)
    z.setflags(write=False)
    return Heightfield(z_m=z, grid_m=float(grid_m), periodic=True)


def check_fractal_parameters(*, p: float, size_m: float, grid_m: float, relief_m: float) -> int:
    """Validate the parameters of :func:`fractal` without building it; returns N (nodes per
    side). Raises :class:`ParameterError` naming the parameter."""
    pf = float(p)
    if not (math.isfinite(pf) and 0.0 < pf <= 5.0):
        raise ParameterError("p", f"must be in (0, 5] (got {p})")
    n = _grid_count(size_m, grid_m)
    rel = float(relief_m)
    if not (math.isfinite(rel) and rel >= 0.0):
        raise ParameterError("relief_m", f"must be >= 0 (got {relief_m})")
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

    The 2-D power spectrum then falls as ``|f|^(-2p)`` and a straight profile's
    1-D spectrum as f^-(2p-1); larger p gives a smoother surface.

    Args:
        p: spectral exponent of the 1/f^p amplitude filter, in (0, 5] (paper: 1.5-2.0).
        size_m: side of the square tile [m].
        grid_m: grid spacing [m] (8 <= size_m / grid_m <= 8192 nodes per side).
        relief_m: total elevation range, max - min [m] (>= 0; 0 gives a flat surface).
        seed: seed of the white noise (``np.random.default_rng``); same seed, same surface.

    Returns:
        Heightfield with z_m of shape (N, N), zero mean, periodic=True.
    """
    import scipy.fft          # (here: its import is a tenth of a second a DEM run need not pay)
    n = check_fractal_parameters(p=p, size_m=size_m, grid_m=grid_m, relief_m=relief_m)
    check_memory("grid_m", FRACTAL_BYTES_PER_NODE * n * n,
                 f"a {n} x {n} fractal (size_m / grid_m = {n})",
                 "use a coarser grid_m or a smaller size_m")
    pf, rel = float(p), float(relief_m)
    check_seed(seed)

    rng = np.random.default_rng(seed)
    w = rng.standard_normal((n, n))
    # Real input -> Hermitian spectrum; rfft2 stores the non-negative u half.
    # scipy's pocketfft on every core: the same bits as numpy.fft's, in half the time
    W = scipy.fft.rfft2(w, workers=-1) / (n * n)  # eq. 2
    del w
    v = np.fft.fftfreq(n) * n  # along y (axis 0), signed integers
    u = np.fft.rfftfreq(n) * n  # along x (axis 1), non-negative integers
    k2 = v[:, None] ** 2 + u[None, :] ** 2
    k2[0, 0] = 1.0  # avoid 0**-p; DC is zeroed below
    W *= k2 ** (-0.5 * pf)  # eq. 3
    W[0, 0] = 0.0
    del k2
    h = scipy.fft.irfft2(W, s=(n, n), workers=-1) * (n * n)  # eq. 4 (real by Hermitian symmetry)
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
# Roughness
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
        raise ParameterError("z_m", "must not be empty")
    d = z - z.mean()
    return float(np.sqrt(np.mean(d * d)))
