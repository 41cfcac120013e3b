"""Corridor tiles of a DEM: the mesh under one chunk of shots, on the DEM's own pixels
(:func:`pixel_tile`) or on a grid along the chunk's chord (:func:`grid_tile`). Pure numpy.

In the data flow of :mod:`lidar_mitsuba.ground.dem`: :meth:`~lidar_mitsuba.ground.dem.DEMSurface.corridor_tile`
picks one of these for every chunk that :class:`lidar_mitsuba.ground.dem.CorridorTiles` hands the stream,
and loads the mesh into a Mitsuba scene. Vertices are in a local frame whose origin is the
chunk's first shot (float32 holds millimetres there), heights absolute [m]; a tile that would
reach nodata or the DEM's edge is refused (:func:`nodata_error`).
"""
from __future__ import annotations

import math

import numpy as np

from .heights import bilinear_nan
from ...constants import ParameterError
from ...machine import check_memory
from ..surface import MESH_BYTES_PER_VERTEX, grid_faces


def chord_frame(x: np.ndarray, y: np.ndarray):
    """``((ox, oy), (ux, uy), along, across)``: the first point, the unit vector of the chord
    to the last, and every point's coordinates [m] along it and to its left."""
    ox, oy = float(x[0]), float(y[0])
    dx, dy = x[-1] - ox, y[-1] - oy
    length = math.hypot(dx, dy)
    ux, uy = (dx / length, dy / length) if length > 0 else (1.0, 0.0)
    return (ox, oy), (ux, uy), (x - ox) * ux + (y - oy) * uy, (x - ox) * -uy + (y - oy) * ux


def nodata_error(dem, reach_m: float, x_crs: float, y_crs: float) -> ParameterError:
    """The error for a corridor tile that reaches nodata or the DEM's edge at the CRS point
    (``x_crs``, ``y_crs``) [m]."""
    return ParameterError(
        "track", f"the track's corridor ({reach_m:g} m about its shots) crosses the DEM's "
        f"nodata or edge at x {x_crs:.1f} m, y {y_crs:.1f} m ({dem.crs.to_string()}); "
        f"move the track")


def grid_tile(x: np.ndarray, y: np.ndarray, *, reach_m: float, grid_m: float, height_m,
              dem, origin_m: tuple[float, float]
              ) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """The corridor mesh on a grid of ``grid_m`` [m] aligned with the chord from the first to
    the last shot (``x``, ``y`` [m], frame coordinates), covering every shot ``reach_m`` [m]
    about it. ``height_m(x, y, block=)`` gives the surface's heights [m] (NaN over nodata);
    ``dem`` and ``origin_m`` (the frame's origin in its CRS) name a nodata point.

    Returns:
        ``(vertices, faces, (ox, oy))``: (n, 3) [m] relative to the first shot ``(ox, oy)``
        (heights absolute), (m, 3) triangles with normals up.
    """
    (ox, oy), (ux, uy), along, across = chord_frame(x, y)
    vx, vy = -uy, ux
    g = grid_m
    a = np.arange(math.floor((along.min() - reach_m) / g),
                  math.ceil((along.max() + reach_m) / g) + 1) * g
    c = np.arange(math.floor((across.min() - reach_m) / g),
                  math.ceil((across.max() + reach_m) / g) + 1) * g
    check_memory("mesh_grid_m", MESH_BYTES_PER_VERTEX * a.size * c.size,
                 f"a corridor tile of {a.size} x {c.size} nodes", "use a coarser grid")
    A, Cc = np.meshgrid(a, c)                     # (nc, na), rows across
    lx = A * ux + Cc * vx
    ly = A * uy + Cc * vy
    z = height_m(ox + lx, oy + ly, block=lx.size)       # one window per tile
    if not np.isfinite(z).all():
        bad = np.flatnonzero(~np.isfinite(z.ravel()))[0]
        raise nodata_error(dem, reach_m, ox + lx.flat[bad] + origin_m[0],
                           oy + ly.flat[bad] + origin_m[1])
    vertices = np.column_stack([lx.ravel(), ly.ravel(), z.ravel()])
    faces = grid_faces(*A.shape)     # (u, v) is right-handed like (x, y): normals up
    return vertices, faces, (ox, oy)


def pixel_tile(dem, x: np.ndarray, y: np.ndarray, *, reach_m: float,
               origin_m: tuple[float, float], tolerance_m: float
               ) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """The corridor mesh on the DEM's own pixels (no roughness): every DEM cell (the square
    between four pixel centres) that comes within ``reach_m`` [m] of the band of the shots
    (``x``, ``y`` [m], frame coordinates; ``origin_m`` the frame's origin in the DEM's CRS),
    its nodes at the pixel centres with the file's heights, split into ``k x k`` sub-cells
    whose nodes lie on the bilinear surface. A bilinear cell of twist ``t = z00 + z11 - z10 -
    z01`` deviates from two triangles by at most ``|t| / 4`` (at its centre), a sub-cell by
    ``|t| / (4 k^2)``: the tile's ``k`` is the smallest with every cell within
    ``tolerance_m`` [m]. On a smooth 100 m DEM this is ~2 000 triangles per 2.9 km tile where
    a 1 m grid has ~160 000. The cells, their twist and the split mesh come from two compiled
    passes (:mod:`lidar_mitsuba.ground.dem.pixel_mesh`: numpy's expressions of
    :func:`_corridor_cells` and :func:`_split_cells`, the same bits), numpy's where the
    window's sub-grid is too large for a mask (a diagonal track).

    Returns:
        ``(vertices, faces, (ox, oy))``: (n, 3) [m] relative to the first shot ``(ox, oy)``
        (heights absolute), (m, 3) triangles with normals up.
    """
    from . import pixel_mesh
    z, (wx, wy), (ox, oy), frame = _corridor_frame(dem, x, y, reach_m=reach_m,
                                                   origin_m=origin_m)
    P = dem.posting_m
    # (wx, origin, ox) apart: numpy's "(q + 0.5) P + wx - origin - ox" runs left to right
    offsets = (float(wx), float(origin_m[0]), float(ox), float(wy), float(origin_m[1]),
               float(oy))
    i, j, bad, twist = pixel_mesh.corridor_cells(np.ascontiguousarray(z, np.float64),
                                                 float(P), *offsets, *frame)
    if bad >= 0:
        raise nodata_error(dem, reach_m, wx + (j[bad] + 0.5) * P, wy + (i[bad] + 0.5) * P)
    k = max(1, math.ceil(math.sqrt(twist / (4.0 * tolerance_m))))
    check_memory("mesh_grid_m", MESH_BYTES_PER_VERTEX * i.size * (k + 1) ** 2,
                 f"a DEM-pixel tile of {i.size} cells split {k} x {k}",
                 "give mesh_grid_m (a grid along the track)")
    if pixel_mesh.mask_fits(i.size, k, z.shape):
        return (*pixel_mesh.split_mesh(i, j, k, np.ascontiguousarray(z, np.float64), float(P),
                                       *offsets), (ox, oy))
    px, py, faces = _split_cells(i, j, k, z.shape, P)
    vertices = np.column_stack([px + wx - origin_m[0] - ox, py + wy - origin_m[1] - oy,
                                bilinear_nan(z, P, px, py)])
    return vertices, faces, (ox, oy)


def _corridor_frame(dem, x: np.ndarray, y: np.ndarray, *, reach_m: float,
                    origin_m: tuple[float, float]):
    """The DEM window under the corridor (the band of the shots ``reach_m`` [m] about their
    chord): ``(z, (wx, wy), (ox, oy), (ux, uy, vx, vy, a0 - h, a1 + h, c0 - h, c1 + h))``,
    ``z`` the window (:meth:`~lidar_mitsuba.ground.dem.DEM.read_window`) whose first pixel is
    centred at CRS (wx, wy) [m], (ox, oy) the first shot, (ux, uy) the chord's direction and
    (vx, vy) its left, and the band's bounds along and across it widened by ``h``, a cell's
    centre to its corners [m]."""
    (ox, oy), (ux, uy), along, across = chord_frame(x, y)
    vx, vy = -uy, ux
    P = dem.posting_m
    half = P / math.sqrt(2.0)                   # a cell's centre to its corners
    a0, a1 = along.min() - reach_m, along.max() + reach_m
    c0, c1 = across.min() - reach_m, across.max() + reach_m
    corners = [(ox + a * ux + c * vx, oy + a * uy + c * vy)
               for a in (a0, a1) for c in (c0, c1)]
    cx, cy = np.array(corners).T + np.array(origin_m)[:, None]
    z, (wx, wy) = dem.read_window(cx.min(), cx.max(), cy.min(), cy.max())
    return z, (wx, wy), (ox, oy), (float(ux), float(uy), float(vx), float(vy),
                                   float(a0 - half), float(a1 + half), float(c0 - half),
                                   float(c1 + half))


def _corridor_cells(dem, x: np.ndarray, y: np.ndarray, *, reach_m: float,
                    origin_m: tuple[float, float]):
    """The DEM window under the corridor (:func:`_corridor_frame`) and its cells within
    reach, in numpy (what :func:`lidar_mitsuba.ground.dem.pixel_mesh.corridor_cells`
    computes, and its tests' reference): ``(z, (wx, wy), i, j, (ox, oy))``, cell ``(i[k],
    j[k])`` the square between pixel centres (i, j) and (i + 1, j + 1)."""
    z, (wx, wy), (ox, oy), (ux, uy, vx, vy, a_lo, a_hi, c_lo, c_hi) = _corridor_frame(
        dem, x, y, reach_m=reach_m, origin_m=origin_m)
    P = dem.posting_m
    ny, nx = z.shape
    # cells (i, j) between pixel centres (i, j) .. (i + 1, j + 1), centres in the local frame
    jc = (np.arange(nx - 1) + 0.5) * P + wx - origin_m[0] - ox
    ic = (np.arange(ny - 1) + 0.5) * P + wy - origin_m[1] - oy
    A = jc[None, :] * ux + ic[:, None] * uy
    C = jc[None, :] * vx + ic[:, None] * vy
    keep = (A >= a_lo) & (A <= a_hi) & (C >= c_lo) & (C <= c_hi)
    i, j = np.nonzero(keep)
    return z, (wx, wy), i, j, (ox, oy)


def _split_cells(i: np.ndarray, j: np.ndarray, k: int, shape: tuple[int, int], P: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cells ``(i, j)`` of a window of ``shape`` pixels (posting ``P`` [m]) split ``k x k``:
    the sub-grid nodes they use, each once, at ``(px, py)`` [m] from the window's first pixel
    centre, and two triangles per sub-cell (indices into the nodes, normals up)."""
    ny, nx = shape
    s = np.arange(k + 1)
    row = (i[:, None, None] * k + s[None, :, None]) * ((nx - 1) * k + 1)
    key = (row + j[:, None, None] * k + s[None, None, :]).reshape(i.size, -1)
    grid = ((ny - 1) * k + 1) * ((nx - 1) * k + 1)
    if grid <= 8 * key.size:
        # np.unique's result (the nodes in use, ascending, and each key's index among them)
        # from a mask over the window's sub-grid instead of a sort: 2.5x faster on a tile
        # along a 20 m DEM; a window mostly outside the corridor (a diagonal track) sorts
        used = np.zeros(grid, bool)
        used[key] = True
        nodes = np.flatnonzero(used)
        inverse = (np.cumsum(used) - 1)[key]
    else:
        nodes, inverse = np.unique(key, return_inverse=True)
    inverse = inverse.reshape(i.size, k + 1, k + 1)
    gy, gx = np.divmod(nodes, (nx - 1) * k + 1)
    # from the window's first pixel centre (the last node must not round off the grid)
    px = np.minimum(gx * (P / k), (nx - 1) * P)
    py = np.minimum(gy * (P / k), (ny - 1) * P)
    a = inverse[:, :-1, :-1].ravel()             # (x, y), (x+, y), (x, y+), (x+, y+)
    b = inverse[:, :-1, 1:].ravel()
    c = inverse[:, 1:, :-1].ravel()
    d = inverse[:, 1:, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    return px, py, faces
