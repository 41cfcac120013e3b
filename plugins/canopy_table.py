"""The layout of a canopy table (the ``canopy`` integrator's stand), and the uniform grids that
hand each photon the crowns it can meet. Numpy only (imports without Mitsuba).

A table holds the crowns and the foliage of one stand:

* ``cx``, ``cy`` (n,): crown axis [m]; ``zb``, ``zt`` (n,): crown bottom and top [m]
  (absolute heights); ``r`` (n,): widest crown radius [m]. A periodic stand lists the
  images of the crowns near its edges as crowns of their own (the pipeline does it).
* ``shape``: ``cone`` (apex at ``zt``, radius ``r`` at ``zb``), ``ellipsoid`` (semi-axes
  ``r, r, (zt - zb)/2``) or ``cylinder``.
* ``leaf_angle``: the leaf normals' inclination distribution (``spherical``, ``planophile``,
  ``erectophile``, ``uniform``); ``g`` (M,): Ross's G at ``mu = k / (M - 1)``; ``lad``
  one-sided leaf area density [m^2/m^3]; ``clumping`` Omega; ``rho``, ``tau`` the leaves'
  reflectance and transmittance.

:func:`grid` bins the crowns into cells: a cell lists every crown whose disc, widened by
``pad_m``, overlaps it (compressed rows: ``offsets`` (cells + 1,), ``trees``).
"""
from __future__ import annotations

import math

import numpy as np

SHAPES = ("cone", "ellipsoid", "cylinder")
LEAF_ANGLES = ("spherical", "planophile", "erectophile", "uniform")
ARRAYS = ("cx", "cy", "zb", "zt", "r")
SCALARS = ("lad", "clumping", "rho", "tau")
#: cell of the crowns' grid [m] (ESTIMATE: a speed choice; any size is exact): the ``canopy``
#: integrator's, and a stand's grid built outside it (``lidar_mitsuba.vegetation.turbid``)
CELL_M = 1.0
#: crowns binned at once by :func:`grid` (bounds its memory: a block's boxes of cells)
GRID_BLOCK = 8192


def check(table: dict) -> dict:
    """The table with float32 crown arrays and float scalars; ValueError where it does not
    hold together."""
    out = {k: np.ascontiguousarray(table[k], np.float32).ravel() for k in ARRAYS}
    n = out["cx"].size
    if any(out[k].size != n for k in ARRAYS):
        raise ValueError("canopy table: cx, cy, zb, zt and r must have one length")
    if n and not (np.all(np.isfinite(np.stack([out[k] for k in ARRAYS])))
                  and np.all(out["r"] > 0) and np.all(out["zt"] > out["zb"])):
        raise ValueError("canopy table: crowns need finite values, r > 0 and zt > zb")
    for k in SCALARS:
        out[k] = float(table[k])
    out["shape"], out["leaf_angle"] = str(table["shape"]), str(table["leaf_angle"])
    if out["shape"] not in SHAPES or out["leaf_angle"] not in LEAF_ANGLES:
        raise ValueError(f"canopy table: shape must be one of {SHAPES} and leaf_angle one of "
                         f"{LEAF_ANGLES} (got {out['shape']!r}, {out['leaf_angle']!r})")
    g = np.ascontiguousarray(table["g"], np.float32).ravel()
    if g.size < 2 or not np.all((g > 0) & (g <= 1.0)):
        raise ValueError("canopy table: g needs >= 2 values in (0, 1]")
    out["g"] = g
    if not (out["lad"] >= 0 and 0 < out["clumping"] <= 1 and out["rho"] >= 0
            and out["tau"] >= 0 and out["rho"] + out["tau"] <= 1):
        raise ValueError("canopy table: lad >= 0, clumping in (0, 1], rho, tau >= 0, "
                         "rho + tau <= 1")
    return out


def grid(cx: np.ndarray, cy: np.ndarray, r: np.ndarray, *, cell_m: float, pad_m: float):
    """Crowns per cell of a uniform grid: ``(x0, y0, nx, ny, offsets, trees)``, cell ``(i, j)``
    covering ``[x0 + i cell, x0 + (i + 1) cell) x [y0 + j cell, ...)``, its crowns
    ``trees[offsets[j nx + i]:offsets[j nx + i + 1]]`` (uint32): those whose disc of radius
    ``r + pad_m`` overlaps the cell (exact disc-rectangle test)."""
    cx, cy, r = (np.asarray(a, np.float64).ravel() for a in (cx, cy, r))
    if cx.size == 0:
        return 0.0, 0.0, 1, 1, np.zeros(2, np.uint32), np.zeros(1, np.uint32)
    reach = r + pad_m
    x0 = math.floor(float((cx - reach).min()) / cell_m) * cell_m
    y0 = math.floor(float((cy - reach).min()) / cell_m) * cell_m
    nx = int(math.floor(float((cx + reach).max() - x0) / cell_m)) + 1
    ny = int(math.floor(float((cy + reach).max() - y0) / cell_m)) + 1
    cells, trees = [], []
    for k0 in range(0, cx.size, GRID_BLOCK):        # a block of crowns at a time
        c, t = _cells_hit(cx[k0:k0 + GRID_BLOCK], cy[k0:k0 + GRID_BLOCK],
                          reach[k0:k0 + GRID_BLOCK], x0=x0, y0=y0, nx=nx, cell_m=cell_m)
        cells.append(c)
        trees.append(t + k0)
    cells, trees = np.concatenate(cells), np.concatenate(trees)
    counts = np.bincount(cells, minlength=nx * ny)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.uint32)
    # by cell, then crown: one sort of the unique keys cell * n + crown (a plain sort of
    # int64 is ~3x faster than a stable argsort and its gather; the same order)
    keys = np.sort(cells * np.int64(cx.size) + trees)
    return float(x0), float(y0), nx, ny, offsets, (keys % cx.size).astype(np.uint32)


def _cells_hit(cx, cy, reach, *, x0: float, y0: float, nx: int, cell_m: float):
    """``(cells, trees)``: every (cell, crown) pair whose disc of radius ``reach`` overlaps
    the cell (exact: the cell's nearest point to the axis within ``reach``), crown by crown
    (a crown's cells row by row): each crown's box of cells on one padded grid."""
    i0 = ((cx - reach - x0) // cell_m).astype(np.int64)
    i1 = ((cx + reach - x0) // cell_m).astype(np.int64)
    j0 = ((cy - reach - y0) // cell_m).astype(np.int64)
    j1 = ((cy + reach - y0) // cell_m).astype(np.int64)
    if cx.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    di = np.arange(int((i1 - i0).max()) + 1)
    dj = np.arange(int((j1 - j0).max()) + 1)
    i = i0[:, None, None] + di[None, None, :]             # (n, 1, W)
    j = j0[:, None, None] + dj[None, :, None]             # (n, H, 1)
    # the nearest point of each cell to the axis
    dx = np.clip(cx[:, None, None], x0 + i * cell_m, x0 + (i + 1) * cell_m) - cx[:, None, None]
    dy = np.clip(cy[:, None, None], y0 + j * cell_m, y0 + (j + 1) * cell_m) - cy[:, None, None]
    hit = ((dx ** 2 + dy ** 2 <= reach[:, None, None] ** 2)
           & (i <= i1[:, None, None]) & (j <= j1[:, None, None]))
    k, jj, ii = np.nonzero(hit)
    return (j0[k] + jj) * nx + (i0[k] + ii), k


def save(path, table: dict) -> None:
    """Write a table (:func:`check`) to ``path`` (``.npz``)."""
    np.savez(path, **check(table))


def load(path) -> dict:
    """Read a table written by :func:`save`."""
    with np.load(path) as f:
        return check({k: f[k] for k in f.files})
