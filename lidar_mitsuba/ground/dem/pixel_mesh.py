"""Compiled passes of a DEM-pixel corridor tile (:func:`lidar_mitsuba.ground.dem.tiles.pixel_tile`):
the cells within the corridor and their twist (:func:`corridor_cells`), and the cells split
``k x k`` into a mesh (:func:`split_mesh`), each numpy's expressions of
:func:`~lidar_mitsuba.ground.dem.tiles._corridor_cells` and
:func:`~lidar_mitsuba.ground.dem.tiles._split_cells` element by element, in numpy's order of
operations and of output: the same vertices and faces, bit for bit (``tests/test_granule.py``).
A tile is ~2 000 triangles; numpy's ~60 passes over such small arrays cost more than their
arithmetic (0.31 ms a 4 096-shot tile of a 100 m DEM, on the trace launcher's thread).
"""
from __future__ import annotations

import numba
import numpy as np

from .heights import _bilinear


@numba.njit(cache=True, nogil=True)
def corridor_cells(z, posting_m, wx, origin_x, ox, wy, origin_y, oy, ux, uy, vx, vy, a_lo,
                   a_hi, c_lo, c_hi):
    """The corridor's cells, the first over nodata and the largest twist.

    The cells ``(i, j)`` (between pixel centres (i, j) and (i + 1, j + 1) of the window
    ``z``, first pixel centred at CRS (``wx``, ``wy``) [m]) whose centre, in the frame of the
    first shot (``ox``, ``oy``) less ``origin`` [m], lies within ``a_lo .. a_hi`` along the
    chord (``ux``, ``uy``) and ``c_lo .. c_hi`` across it (``vx``, ``vy``), in row-major order
    (``np.nonzero``'s); the first of them with a non-finite corner (-1: none) and the largest
    ``|z00 + z11 - z10 - z01|`` (0 for none; meaningless when one is not finite)."""
    ny, nx = z.shape
    P = posting_m
    jc = np.empty(nx - 1)
    for q in range(nx - 1):
        jc[q] = (q + 0.5) * P + wx - origin_x - ox
    n = 0
    keep = np.zeros((ny - 1, nx - 1), np.bool_)
    for r in range(ny - 1):
        ic = (r + 0.5) * P + wy - origin_y - oy
        for q in range(nx - 1):
            a = jc[q] * ux + ic * uy
            c = jc[q] * vx + ic * vy
            if a >= a_lo and a <= a_hi and c >= c_lo and c <= c_hi:
                keep[r, q] = True
                n += 1
    i = np.empty(n, np.int64)
    j = np.empty(n, np.int64)
    bad = -1
    twist = 0.0
    m = 0
    for r in range(ny - 1):
        for q in range(nx - 1):
            if not keep[r, q]:
                continue
            i[m], j[m] = r, q
            z00, z10, z01, z11 = z[r, q], z[r, q + 1], z[r + 1, q], z[r + 1, q + 1]
            if bad < 0 and not np.isfinite(z00 + z10 + z01 + z11):
                bad = m
            t = abs(z00 + z11 - z10 - z01)
            if t > twist:
                twist = t
            m += 1
    return i, j, bad, twist


def mask_fits(n_cells: int, k: int, shape: tuple[int, int]) -> bool:
    """Whether the split numbers its nodes by a mask over the window's sub-grid.

    :func:`~lidar_mitsuba.ground.dem.tiles._split_cells`' test; else it sorts, and the tile
    stays numpy's."""
    ny, nx = shape
    return ((ny - 1) * k + 1) * ((nx - 1) * k + 1) <= 8 * n_cells * (k + 1) ** 2


@numba.njit(cache=True, nogil=True)
def split_mesh(i, j, k, z, posting_m, wx, origin_x, ox, wy, origin_y, oy):
    """The corridor's cells split into a mesh, where :func:`mask_fits`.

    The cells ``(i, j)`` of the window ``z`` split ``k x k``: ``(vertices, faces)``, the
    sub-grid nodes in use, ascending, at ``px + wx - origin_x - ox``, ``py + wy - origin_y -
    oy`` [m] and their bilinear height ((n, 3)), and two triangles a sub-cell ((m, 3) int64,
    every cell's ``(a, b, d)`` then every cell's ``(a, d, c)``), as
    :func:`~lidar_mitsuba.ground.dem.tiles._split_cells` and ``pixel_tile``'s columns make
    them."""
    ny, nx = z.shape
    P = posting_m
    width = (nx - 1) * k + 1
    grid = ((ny - 1) * k + 1) * width
    used = np.zeros(grid, np.bool_)
    for c in range(i.size):
        for s in range(k + 1):
            row = (i[c] * k + s) * width
            for t in range(k + 1):
                used[row + j[c] * k + t] = True
    index = np.empty(grid, np.int64)          # each node's number among those in use
    n = 0
    for g in range(grid):
        if used[g]:
            index[g] = n
            n += 1
    px = np.empty(n)
    py = np.empty(n)
    step = P / k
    x_max, y_max = (nx - 1) * P, (ny - 1) * P
    for g in range(grid):
        if used[g]:
            gy, gx = g // width, g % width
            v = index[g]
            px[v] = min(gx * step, x_max)
            py[v] = min(gy * step, y_max)
    h = np.empty(n)
    _bilinear(z, P, px, py, h)
    vertices = np.empty((n, 3))
    for v in range(n):
        vertices[v, 0] = px[v] + wx - origin_x - ox
        vertices[v, 1] = py[v] + wy - origin_y - oy
        vertices[v, 2] = h[v]
    half = i.size * k * k
    faces = np.empty((2 * half, 3), np.int64)
    f = 0
    for c in range(i.size):
        for s in range(k):
            row0 = (i[c] * k + s) * width + j[c] * k
            row1 = row0 + width
            for t in range(k):
                a, b = index[row0 + t], index[row0 + t + 1]
                cc, d = index[row1 + t], index[row1 + t + 1]
                faces[f, 0], faces[f, 1], faces[f, 2] = a, b, d
                faces[half + f, 0], faces[half + f, 1], faces[half + f, 2] = a, d, cc
                f += 1
    return vertices, faces
