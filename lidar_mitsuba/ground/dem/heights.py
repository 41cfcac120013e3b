"""Heights of a DEM at points, from its windows: bilinear look-ups (:func:`heights_at`) and the
exact Gaussian-footprint mean of the bilinear surface (:func:`footprint_mean`). numpy and scipy,
and one numba kernel that sums the footprint stencils as numpy would (:func:`_stencil_sums`).

In the data flow of :mod:`lidar_mitsuba.ground.dem`: :meth:`~lidar_mitsuba.ground.dem.DEM.windows` reads one
DEM window per block of points, these functions turn each window into the heights
:class:`~lidar_mitsuba.ground.dem.DEMSurface` gives (``height_m``, ``fold``'s footprint probes,
``reference_elevation_m``), and :mod:`lidar_mitsuba.ground.dem.tiles` meshes the corridor with
:func:`bilinear_nan`. Coordinates here are the DEM's CRS [m], heights its vertical datum [m].
"""
from __future__ import annotations

import math

import numba
import numpy as np
from scipy.special import ndtr

from ...machine import host_pool
from ...numeric import pairwise_sum

#: the largest footprint weight of missing DEM pixels a reference elevation spreads over the rest
MISSING_WEIGHT_MAX = 1e-4


def bilinear_nan(z: np.ndarray, g: float, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear look-up of the grid ``z`` (node (i, j) at (j g, i g)) [m] at (x, y) [m]; NaN
    off the grid and wherever a node with a non-zero weight is NaN (so a point on the last
    row or column of valid pixels is defined). One compiled pass over the points
    (:func:`_bilinear`, numpy's expression point by point: the same bits)."""
    x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
    out = np.empty(x.shape)
    _bilinear(np.asarray(z, np.float64), float(g), x.ravel(), y.ravel(), out.reshape(-1))
    return out


@numba.njit(cache=True, nogil=True)
def _bilinear(z, g, x, y, out):
    """:func:`bilinear_nan` into ``out`` ((n,) each), in numpy's order of operations:
    ``f = x / g``, off the grid NaN; ``i = min(int(f), n - 2)``, ``t = f - i``; the four
    nodes' ``w z`` (0 where their weight ``w`` is 0: an edge's nodata) added to 0 in the
    order (i, j), (i, j + 1), (i + 1, j), (i + 1, j + 1)."""
    ny, nx = z.shape
    for k in range(x.size):
        fx, fy = x[k] / g, y[k] / g
        if not (fx >= 0 and fy >= 0 and fx <= nx - 1 and fy <= ny - 1):
            out[k] = np.nan
            continue
        ix, iy = min(np.intp(fx), nx - 2), min(np.intp(fy), ny - 2)
        tx, ty = fx - ix, fy - iy
        acc = 0.0
        w = (1 - tx) * (1 - ty)
        acc += w * z[iy, ix] if w > 0 else 0.0
        w = tx * (1 - ty)
        acc += w * z[iy, ix + 1] if w > 0 else 0.0
        w = (1 - tx) * ty
        acc += w * z[iy + 1, ix] if w > 0 else 0.0
        w = tx * ty
        acc += w * z[iy + 1, ix + 1] if w > 0 else 0.0
        out[k] = acc


def heights_at(dem, x_crs: np.ndarray, y_crs: np.ndarray, offsets_m, block: int
               ) -> np.ndarray:
    """The DEM's bilinear heights [m] at every point (``x_crs``, ``y_crs``, CRS [m], of one
    shape) shifted by each ``(dx, dy)`` [m] of ``offsets_m``: shape ``(len(offsets_m),) +
    x_crs.shape``; NaN over nodata or off the DEM. One window read per ``block`` points
    covers all the shifts."""
    offs = np.asarray(offsets_m, np.float64).reshape(-1, 2)
    out = np.full((len(offs), x_crs.size), np.nan)
    g = dem.posting_m
    for s, z, px, py in _shifted_windows(dem, x_crs, y_crs, offs, block):
        for k, (dx, dy) in enumerate(offs):
            out[k, s] = bilinear_nan(z, g, px + dx, py + dy)
    return out.reshape((len(offs),) + x_crs.shape)


def finite_at(dem, x_crs: np.ndarray, y_crs: np.ndarray, offsets_m, block: int) -> np.ndarray:
    """Whether :func:`heights_at` would give a finite height at every shift: (n,) bool for the
    (n,) points. A window without nodata needs no look-up: a bilinear height there is finite
    exactly where the shifted point is on the window's grid."""
    offs = np.asarray(offsets_m, np.float64).reshape(-1, 2)
    ok = np.zeros(x_crs.size, bool)
    g = dem.posting_m
    for s, z, px, py in _shifted_windows(dem, x_crs, y_crs, offs, block):
        ny, nx = z.shape
        if np.isfinite(z).all():        # bilinear_nan's test of the grid, alone
            ok[s] = _on_grid(px, py, offs, float(g), nx, ny)
            continue
        good = np.ones(px.size, bool)
        for dx, dy in offs:
            good &= np.isfinite(bilinear_nan(z, g, px + dx, py + dy))
        ok[s] = good
    return ok


@numba.njit(cache=True, nogil=True)
def _on_grid(px, py, offsets_m, g, nx, ny):
    """(n,) bool: whether every point (``px``, ``py``) [m] shifted by each of ``offsets_m``
    ((k, 2) [m]) lies on an ``nx`` x ``ny`` grid of posting ``g`` [m] (:func:`bilinear_nan`'s
    test: ``f = (p + d) / g`` within ``[0, n - 1]`` on both axes)."""
    good = np.ones(px.size, np.bool_)
    for i in range(px.size):
        for k in range(offsets_m.shape[0]):
            fx, fy = (px[i] + offsets_m[k, 0]) / g, (py[i] + offsets_m[k, 1]) / g
            if not (fx >= 0 and fy >= 0 and fx <= nx - 1 and fy <= ny - 1):
                good[i] = False
                break
    return good


@numba.njit(cache=True, nogil=True)
def block_extents(x, y, block):
    """For each block of ``block`` consecutive points of the (n,) ``x``, ``y`` [m]: whether it
    has a point with both coordinates finite, and the least and greatest ``x`` and ``y`` of
    those points (what ``xs[ok].min()`` and its kin give: a minimum is exact), (n_blocks,)
    each; one pass instead of numpy's eight a block."""
    n_blocks = (x.size + block - 1) // block
    found = np.zeros(n_blocks, np.bool_)
    x_lo, x_hi = np.zeros(n_blocks), np.zeros(n_blocks)
    y_lo, y_hi = np.zeros(n_blocks), np.zeros(n_blocks)
    for k in range(n_blocks):
        for i in range(k * block, min(x.size, (k + 1) * block)):
            xi, yi = x[i], y[i]
            if not (np.isfinite(xi) and np.isfinite(yi)):
                continue
            if not found[k]:
                found[k] = True
                x_lo[k] = x_hi[k] = xi
                y_lo[k] = y_hi[k] = yi
            else:
                x_lo[k], x_hi[k] = min(x_lo[k], xi), max(x_hi[k], xi)
                y_lo[k], y_hi[k] = min(y_lo[k], yi), max(y_hi[k], yi)
    return found, x_lo, x_hi, y_lo, y_hi


def _shifted_windows(dem, x_crs, y_crs, offs: np.ndarray, block: int):
    """Yield ``(slice, z, px, py)`` per block of ``block`` points (flattened): the DEM window
    read once for every shift of ``offs`` ((k, 2) [m]), and the block's points relative to
    its first pixel centre [m]; blocks without a finite point are skipped."""
    pad = float(np.abs(offs).max(initial=0.0))
    xf, yf = x_crs.ravel(), y_crs.ravel()
    for s, z, (ox, oy) in dem.windows(xf, yf, pad_m=pad, block=block):
        if z is not None:
            yield s, z, xf[s] - ox, yf[s] - oy


def footprint_mean(dem, x_crs: np.ndarray, y_crs: np.ndarray, *, sigma_m: float, block: int
                   ) -> np.ndarray:
    """The mean of the DEM's bilinear surface over a Gaussian footprint (sigma ``sigma_m``
    [m]) at each point (``x_crs``, ``y_crs``, CRS [m], of one shape), exact; same shape [m].

    The bilinear interpolant is ``sum_ij z_ij h_i(x) h_j(y)`` with hat functions of the
    posting ``P``, and a hat is a sum of three ramps, whose Gaussian mean is ``R(d) = d
    Phi(d / s) + s phi(d / s)``; so each pixel weighs ``a_j(x) b_i(y)``, ``a_j(x) = (R(d + P) -
    2 R(d) + R(d - P)) / P`` with ``d = x - x_j`` (:func:`_axis_weights`). Pixels farther than
    ``P + 5 sigma`` on either axis are left out (weight below 3e-7). Near nodata or the DEM's
    edge the missing pixels' weight, when at most :data:`MISSING_WEIGHT_MAX` (the footprint's
    tail beyond ~3.7 sigma), is spread over the present ones (an error of that weight times
    the height change across the footprint); beyond it the mean is NaN.

    The windows (one per ``block`` points) are read here, one after another; their sums
    (numpy, which lets go of the GIL) run on the host's threads, each block into its own
    points."""
    xf, yf = x_crs.ravel(), y_crs.ravel()
    out = np.full(xf.size, np.nan)
    reach, _ = _stencil(dem.posting_m, sigma_m)
    pool = host_pool()
    jobs = [pool.submit(_window_mean, out, s, xf[s], yf[s], z, ox, oy,
                        posting_m=dem.posting_m, sigma_m=sigma_m)
            for s, z, (ox, oy) in dem.windows(xf, yf, pad_m=reach, block=block)
            if z is not None]
    for job in jobs:
        job.result()
    return out.reshape(x_crs.shape)


def _stencil(posting_m: float, sigma_m: float) -> tuple[float, int]:
    """(reach [m], pixels per axis) of the footprint-mean stencil: pixels within ``P + 5
    sigma`` of a point."""
    reach = posting_m + 5.0 * sigma_m
    return reach, 2 * math.ceil(reach / posting_m) + 2


def _axis_weights(p: np.ndarray, *, posting_m: float, sigma_m: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """For (m,) positions ``p`` [m] along one axis of a window (from its first pixel centre):
    the index of each one's first stencil pixel (m,) and the Gaussian mean of the n pixels'
    hat functions there (m, n). NaN positions get weights of position 0 (their means are
    set NaN by the caller).

    The ramps' means ``R(d) = sigma (u Phi(u) + phi(u))``, ``u = d / sigma``, at ``d + P``,
    ``d``, ``d - P`` (neighbours share them) are the numpy expression's bits, computed with
    ``ndtr`` and ``exp`` only where ``-`` :data:`RAMP_LIMIT_U` ``< u <``
    :data:`RAMP_UPPER_U` (:func:`_ramp_arguments`, :func:`_hat_means`): beyond them the
    expression is exactly ``sigma u`` above (``u * 1.0 + phi(u)`` rounds to ``u``) and ``0.0``
    (``-0.0 + 0.0``) below. With a posting of many footprint sigmas most
    ramps are far (a 100 m posting and sigma 2.5 m: 2 of each 8), and these two functions
    over all of them were most of the footprint means' time."""
    P = posting_m
    reach, n = _stencil(P, sigma_m)
    p = np.where(np.isfinite(p), p, 0.0)
    first = np.floor((p - reach) / P).astype(np.int64)
    if sigma_m > 0:
        u, near = _ramp_arguments(p, first, float(P), float(sigma_m), n, RAMP_LIMIT_U,
                                  RAMP_UPPER_U)
        v = u.ravel()[near]
        rv = sigma_m * (v * ndtr(v) + np.exp(-0.5 * v * v) / math.sqrt(2.0 * math.pi))
        return first, _hat_means(u, near, rv, float(P), float(sigma_m))
    d = p[:, None] - (first[:, None] + np.arange(n)) * P
    return first, np.maximum(0.0, 1.0 - np.abs(d) / P)


#: ``abs(u)`` from which a ramp's Gaussian mean ``sigma (u Phi(u) + phi(u))`` is its limit to
#: the bit (0 below, ``sigma u`` above): scipy's ``ndtr`` is exactly 0 or 1 once
#: ``u^2 / 2`` passes its ``erfc``'s underflow bound (cephes ``MAXLOG`` = 709.78:
#: ``abs(u) > 37.7``), and ``exp(-u^2 / 2)`` is exactly 0 below exp's smallest subnormal
#: (``u^2 / 2 > 745.2``: ``abs(u) > 38.6``); 40 clears both (``tests/test_host_kernels.py``
#: checks the bits across it)
RAMP_LIMIT_U = 40.0
#: ``u`` above which the ramp's mean is ``sigma u`` to the bit: scipy's ``ndtr(u) = 1 -
#: erfc(u / sqrt 2) / 2`` is exactly 1.0 from ``u = 8.2924`` on (a sweep of 2e7 points over
#: [6, 40]: the last ``u`` with ``ndtr(u) < 1`` and the last whose expression differs from
#: ``sigma u``, at every sigma, are both 8.2924), and there ``phi(u) < 4.4e-16``, under half
#: an ulp of ``u`` (``2^-50 = 8.9e-16``), so ``u * 1.0 + phi(u)`` is ``u``; 9 leaves a margin
#: (``tests/test_host_kernels.py`` checks the bits across it). On the positive side this
#: skips ~40 % of the ``ndtr`` and ``exp`` evaluations (a 100 m posting, sigma 2.5 m)
RAMP_UPPER_U = 9.0


@numba.njit(cache=True, nogil=True)
def _ramp_arguments(p, first, posting_m, sigma_m, n, limit, upper):
    """``u[k, i] = (p[k] - (first[k] + i - 1) P) / sigma`` for the (m,) positions ``p`` [m]
    and their first stencil pixels ``first``, ``i`` in ``0 .. n + 1`` (numpy's operations in
    numpy's order: (m, n + 2)), and the flat indices of those with ``-limit < u < upper``."""
    m = p.size
    u = np.empty((m, n + 2))
    near = np.empty(m * (n + 2), np.int64)
    c = 0
    for k in range(m):
        for i in range(n + 2):
            x = (p[k] - float(first[k] + (i - 1)) * posting_m) / sigma_m
            u[k, i] = x
            if -limit < x < upper:
                near[c] = k * (n + 2) + i
                c += 1
    return u, near[:c]


@numba.njit(cache=True, nogil=True)
def _hat_means(u, near, r_near, posting_m, sigma_m):
    """(m, n) Gaussian means of the hat functions, ``(R(u_i) - 2 R(u_i+1) + R(u_i+2)) / P``
    as numpy evaluates it, from the ramps' arguments ``u`` ((m, n + 2)), the flat indices
    ``near`` of those whose mean ``r_near`` was evaluated, and ``sigma max(u, 0)`` for the
    others."""
    m, n2 = u.shape
    r = np.empty(n2)
    out = np.empty((m, n2 - 2))
    q = 0
    for k in range(m):
        for i in range(n2):
            if q < near.size and near[q] == k * n2 + i:
                r[i] = r_near[q]
                q += 1
            else:
                r[i] = sigma_m * (u[k, i] if u[k, i] > 0.0 else 0.0)
        for j in range(n2 - 2):
            out[k, j] = (r[j] - 2.0 * r[j + 1] + r[j + 2]) / posting_m
    return out


def _window_mean(out: np.ndarray, s: slice, xs: np.ndarray, ys: np.ndarray, z: np.ndarray,
                 ox: float, oy: float, *, posting_m: float, sigma_m: float) -> None:
    """The footprint means of the points ``xs``, ``ys`` (CRS [m]) from the DEM window ``z``
    whose first pixel is centred at (``ox``, ``oy``), into ``out[s]``: per point, the sums of
    its stencil's weights over the pixels present, and of those weights times the heights
    (:func:`_stencil_sums`), then their ratio."""
    j0, a = _axis_weights(xs - ox, posting_m=posting_m, sigma_m=sigma_m)
    i0, b = _axis_weights(ys - oy, posting_m=posting_m, sigma_m=sigma_m)
    present, total = np.empty(xs.size), np.empty(xs.size)
    _stencil_sums(np.ascontiguousarray(z, np.float64), i0, j0, np.ascontiguousarray(a),
                  np.ascontiguousarray(b), present, total)
    bad = (1.0 - present > MISSING_WEIGHT_MAX) | ~(np.isfinite(xs) & np.isfinite(ys))
    out[s] = np.where(bad, np.nan, total / np.where(bad, 1.0, present))


@numba.njit(cache=True, nogil=True)
def _stencil_sums(z, i0, j0, a, b, present, total):
    """For each point ``k`` of (m,) first stencil rows ``i0`` and columns ``j0`` and (m, n)
    axis weights ``b`` (rows) and ``a`` (columns): ``present[k]``, the sum over its n x n
    pixels ``(i0[k] + i, j0[k] + j)`` on the window ``z`` with a finite height of the weights
    ``b[k, i] a[k, j]``, and ``total[k]``, of those weights times the heights (0 for the
    others). Each sum runs over the (n, n) array in row-major order as numpy's
    ``np.sum(..., axis=(1, 2))`` does (:func:`lidar_mitsuba.numeric.pairwise_sum`): the numpy
    expression's bits, in one pass and no (m, n, n) temporaries."""
    ny, nx = z.shape
    m, n = a.shape
    wv = np.empty(n * n)
    tv = np.empty(n * n)
    for k in range(m):
        for i in range(n):
            ii = i0[k] + i
            for j in range(n):
                jj = j0[k] + j
                q = i * n + j
                w = b[k, i] * a[k, j]
                if 0 <= ii < ny and 0 <= jj < nx and np.isfinite(z[ii, jj]):
                    wv[q] = w
                    tv[q] = w * z[ii, jj]
                else:
                    wv[q] = 0.0
                    tv[q] = 0.0
        present[k] = pairwise_sum(wv, 0, n * n)
        total[k] = pairwise_sum(tv, 0, n * n)
