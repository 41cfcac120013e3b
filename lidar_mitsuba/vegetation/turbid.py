"""The turbid and gap-probability representations of a stand: its crowns as a canopy table for
the ``canopy`` integrator (``plugins/canopy.py``), and the integrator's parameters.

Both representations trace the same table; they differ in the integrator's ``mode``:

* ``turbid``: Monte Carlo through the crowns filled with a turbid medium of leaves
  (extinction ``G Omega LAD``, bi-Lambertian leaves scattering, up to ``max_depth`` vertices);
* ``gap``: per photon the gap probability of its vertical line through the crowns, a canopy
  return at a height drawn from the collision density and the ground's return weighted by
  the gap probability (single scattering; the cost of a ray cast to the ground).

Both carry the monostatic hot spot (the way back is the way in): see ``plugins/canopy.py``
and docs/physics/canopy.md.

A periodic stand (a torus over its bounds) lists, besides its crowns, their images shifted
by the bounds' size wherever a crown lies within ``pad_m`` of an edge, so that the lines of
a track folded into the tile (up to a footprint's 5 sigma and a field of view outside it)
see the crowns across the edge (:func:`~.stand.periodic_copies` lists the copies, as for the
explicit leaves' :func:`~.explicit.trees_near`).
"""
from __future__ import annotations

import hashlib
import os
import pathlib
import tempfile
import threading

import numpy as np

from ..constants import ParameterError, check
from . import ross
from .stand import periodic_copies

#: nodes of the G table handed to the integrator (mu = k / (G_NODES - 1); linear between
#: them: G varies smoothly, < 1e-4 between nodes)
G_NODES = 129
MODES = ("turbid", "gap")


def canopy_table(stand, *, rho: float, tau: float, pad_m: float = 40.0) -> dict:
    """The canopy table (``lidar_mitsuba_plugins.canopy_table``) of ``stand`` (a
    :class:`~lidar_mitsuba.vegetation.stand.Stand`): crowns as absolute heights, with the
    periodic images within ``pad_m`` [m] of the bounds when the stand is periodic; leaves
    of reflectance ``rho`` and transmittance ``tau``; Ross's G on :data:`G_NODES` nodes."""
    check("rho", rho, 0 <= rho <= 1, "must be in [0, 1]")
    check("tau", tau, 0 <= tau <= 1 - rho, "must be in [0, 1 - rho]")
    cx, cy = np.asarray(stand.x_m, float), np.asarray(stand.y_m, float)
    zb = np.asarray(stand.ground_z_m, float) + np.asarray(stand.crown_base_m, float)
    zt = np.asarray(stand.ground_z_m, float) + np.asarray(stand.height_m, float)
    r = np.asarray(stand.crown_radius_m, float)
    if getattr(stand, "periodic", False) and cx.size:
        (x0, y0), (x1, y1) = stand.bounds_m
        lx, ly = x1 - x0, y1 - y0
        idx, qx, qy = [], [], []
        for i, j in periodic_copies(stand.bounds_m, (x0 - pad_m, x1 + pad_m, y0 - pad_m,
                                                     y1 + pad_m), reach_m=float(r.max())):
            dx, dy = i * lx, j * ly
            keep = ((cx + dx + r > x0 - pad_m) & (cx + dx - r < x1 + pad_m)
                    & (cy + dy + r > y0 - pad_m) & (cy + dy - r < y1 + pad_m))
            k = np.arange(cx.size) if i == j == 0 else np.flatnonzero(keep)
            idx.append(k)
            qx.append(cx[k] + dx)
            qy.append(cy[k] + dy)
        idx, cx, cy = np.concatenate(idx), np.concatenate(qx), np.concatenate(qy)
        zb, zt, r = zb[idx], zt[idx], r[idx]
    return crowns_table(stand, cx=cx, cy=cy, zb=zb, zt=zt, r=r, rho=rho, tau=tau)


def crowns_table(stand, *, cx, cy, zb, zt, r, rho: float, tau: float) -> dict:
    """A canopy table of the crowns (cx, cy) [m], bottoms and tops ``zb``, ``zt`` [m]
    (absolute), radii ``r`` [m] (each (n,)), with ``stand``'s shape and foliage and leaves of
    reflectance ``rho`` and transmittance ``tau``; Ross's G on :data:`G_NODES` nodes."""
    mu = np.linspace(0.0, 1.0, G_NODES)
    g = ross.g_function(mu, stand.leaf_angle)
    g[-1] = ross.G_NADIR[stand.leaf_angle]
    return {"cx": cx, "cy": cy, "zb": zb, "zt": zt, "r": r, "shape": stand.crown_shape,
            "leaf_angle": stand.leaf_angle, "g": g,
            "lad": float(stand.leaf_area_density_m2_m3), "clumping": float(stand.clumping),
            "rho": float(rho), "tau": float(tau)}


def stand_crowns(forest, *, pad_m: float) -> dict:
    """The crowns of a forest over a DEM, once for every corridor tile (cached on the
    forest): a canopy table (:func:`crowns_table`) of the stand's square, in its own
    coordinates (the bounds' lower corner at 0), with the periodic images within ``pad_m``
    [m] of the square as crowns of their own, ``zb``, ``zt`` the crown's bottom and top
    above the ground it stands on (a tile's :func:`tile_crowns` gives the ground), in the
    order of a Z curve over the stand (:func:`_z_order`), and ``key`` (uint32: the stand's
    index of the crown's tree ``k`` and its image ``(i, j)`` in periods, ``k << 8 |
    (i + 8) << 4 | (j + 8)``: one gather a crown in the kernel), ``trees`` (the stand's
    count), ``period_m`` ((x, y) [m], None when the stand is not periodic),
    ``top_m`` (the tallest tree [m]) and ``grid``, the crowns binned into cells of
    :data:`~lidar_mitsuba_plugins.canopy_table.CELL_M`
    (:func:`~lidar_mitsuba_plugins.canopy_table.grid`). The ``canopy`` integrator takes it
    with ``set_stand`` and each tile's ground with ``set_tile``: no tile gathers or bins
    crowns of its own.

    Also kept per process beyond the forest (:data:`_STANDS`): a forest of the same crowns
    (a campaign's next granule, its forest made again from the spec) gets the same table,
    the same object, without building it again. Read it, never change it."""
    key = ("stand_crowns", float(pad_m))
    if key in forest._cache:
        return forest._cache[key]
    s = forest.stand
    (x0, y0), (x1, y1) = s.bounds_m
    square = (s.x_m - x0, s.y_m - y0, x1 - x0, y1 - y0)    # what the table is made of
    whole = _stand_key(forest, square, pad_m)
    with _STANDS_LOCK:
        out = _STANDS.get(whole)
    if out is None:
        out = _build_stand_crowns(forest, square, pad_m=float(pad_m))
        with _STANDS_LOCK:
            while len(_STANDS) >= _STANDS_MAX:
                _STANDS.pop(next(iter(_STANDS)))      # the oldest
            _STANDS[whole] = out
    forest._cache[key] = out
    return out


#: stands' crowns (:func:`stand_crowns`) kept per process, beyond their forest: a campaign's
#: worker makes the spec's forest again for every granule (and moves it into the granule's
#: frame), and the crowns' table and grid (~1 s of CPU, ~65 MB, for the 2048 m conifer
#: stand's 400 000 crowns and images) depend only on the crowns in their square's own
#: coordinates, the leaves and the pad (:func:`_stand_key`: equal to the bit wherever the
#: frame is, as long as the subtractions that move the stand are exact; where one is not, the
#: key differs and the table is built again, as before). At most :data:`_STANDS_MAX`, the
#: oldest dropped (as the DEMs a worker holds, :data:`lidar_mitsuba.ground.dem._WHOLE_MAX`)
_STANDS: dict = {}
_STANDS_MAX = 2
_STANDS_LOCK = threading.Lock()


def _stand_key(forest, square: tuple, pad_m: float) -> tuple:
    """Everything :func:`stand_crowns`' table is made of: ``pad_m``, the stand's crowns in
    its square's coordinates (``square``: stems ``x``, ``y`` [m] from the square's lower
    corner, its sides ``lx``, ``ly`` [m]), their radii, bases and heights (a digest; the
    ground under them is not in the table), its periodicity, crown shape and foliage, and
    the leaves' optics."""
    s = forest.stand
    x, y, lx, ly = square
    digest = hashlib.blake2b(digest_size=20)
    for a in (x, y, s.crown_radius_m, s.crown_base_m, s.height_m):
        a = np.ascontiguousarray(a)
        digest.update(f"{a.dtype.str}{a.shape}".encode())
        digest.update(a.data)
    return (float(pad_m), float(lx), float(ly), bool(s.periodic), s.crown_shape,
            s.leaf_angle, float(s.leaf_area_density_m2_m3), float(s.clumping),
            float(forest.leaf.reflectance), float(forest.leaf.transmittance),
            digest.hexdigest())


def _build_stand_crowns(forest, square: tuple, *, pad_m: float) -> dict:
    """:func:`stand_crowns`' table, built from the stand's crowns in its ``square``'s
    coordinates (:func:`_stand_key`)."""
    from lidar_mitsuba_plugins import canopy_table as ct
    s = forest.stand
    x, y, lx, ly = square
    r = np.asarray(s.crown_radius_m, float)
    m = int(np.ceil((pad_m + r.max(initial=0.0)) / min(lx, ly))) if s.periodic else 0
    if s.n_trees >= 1 << 24 or m > 7:
        raise ParameterError("forest", f"a stand of {s.n_trees} trees and images {m} "
                             f"periods out: at most 2^24 trees and 7 periods (the canopy "
                             f"integrator's key)")
    parts = []
    for i, j in periodic_copies(((0.0, 0.0), (lx, ly)), (-pad_m, lx + pad_m, -pad_m, ly + pad_m),
                                reach_m=float(r.max(initial=0.0)), periodic=s.periodic):
        ex, ey = x + i * lx, y + j * ly
        k = np.flatnonzero((ex + r > -pad_m) & (ex - r < lx + pad_m)
                           & (ey + r > -pad_m) & (ey - r < ly + pad_m))
        parts.append((k, ex[k], ey[k], np.full(k.size, i), np.full(k.size, j)))
    idx, cx, cy, ix, iy = (np.concatenate(p) for p in zip(*parts))
    order = _z_order(cx, cy)          # neighbours in the stand, neighbours in memory
    idx, cx, cy, ix, iy = idx[order], cx[order], cy[order], ix[order], iy[order]
    out = crowns_table(s, cx=cx, cy=cy, zb=s.crown_base_m[idx], zt=s.height_m[idx], r=r[idx],
                       rho=forest.leaf.reflectance, tau=forest.leaf.transmittance)
    out.update(key=((idx << 8) | ((ix + 8) << 4) | (iy + 8)).astype(np.uint32),
               trees=int(s.n_trees),
               period_m=(lx, ly) if s.periodic else None,
               top_m=float(s.height_m.max(initial=0.0)),
               grid=ct.grid(cx, cy, r[idx], cell_m=ct.CELL_M, pad_m=0.0))
    return out


def _z_order(x_m: np.ndarray, y_m: np.ndarray, *, block_m: float = 4.0) -> np.ndarray:
    """The order of the points (x, y) [m] along a Z (Morton) curve over blocks of
    ``block_m``: points near each other mostly close in the order (a tile's crowns are
    read from a few stretches of the stand's arrays, not from all over them)."""
    code = np.zeros(np.asarray(x_m).shape, np.uint64)
    for k, v in enumerate((x_m, y_m)):
        q = np.floor((np.asarray(v, float) - np.min(v, initial=0.0)) / block_m)
        q = np.clip(q, 0, 2 ** 21 - 1).astype(np.uint64)
        for bit in range(21):
            code |= ((q >> np.uint64(bit)) & np.uint64(1)) << np.uint64(2 * bit + k)
    return np.argsort(code, kind="stable")


def tile_crowns(forest, *, x_m, y_m, reach_m: float, origin_m) -> dict:
    """What one corridor tile of a forest over a DEM hands the ``canopy`` integrator
    (``set_tile``) beside the stand's crowns (:func:`stand_crowns`): the ground under the
    images of the trees whose crowns reach within ``reach_m`` [m] of the band of the tile's
    shots (``x_m``, ``y_m`` (n,) [m, the forest's frame]: the band about their chord, as the
    DEM's corridor, where every photon of theirs stays), each standing on the ground where
    it is (:func:`.explicit.ground_under`); the tile's coordinates are the frame's less
    ``origin_m`` (x, y) [m]. A dict: ``shift_m`` (x, y) [m], from the tile's coordinates to
    the stand's less a whole number of periods (``image0``, from the images of the ground
    table); ``images`` (mx, my) periods covered; ``trees`` the stand's count; ``ground_z_m``
    (my * mx * trees,) [m] float32, the ground under tree ``k`` in image (i, j) at
    ``(j * mx + i) * trees + k`` (NaN for a crown not in the band: no photon of the tile
    meets it); ``top_m`` the highest crown top [m] (-1e30 when none)."""
    from ..ground.dem.tiles import chord_frame
    from .explicit import ground_under, trees_near
    s = forest.stand
    x, y, r = np.asarray(x_m, np.float64), np.asarray(y_m, np.float64), float(reach_m)
    idx, cx, cy = trees_near(s, (float(x.min()) - r, float(x.max()) + r,
                                 float(y.min()) - r, float(y.max()) + r))
    (ox, oy), (ux, uy), along, across = chord_frame(x, y)
    a = (cx - ox) * ux + (cy - oy) * uy
    c = (cx - ox) * -uy + (cy - oy) * ux
    rc = s.crown_radius_m[idx] + r
    keep = ((a >= along.min() - rc) & (a <= along.max() + rc)
            & (c >= across.min() - rc) & (c <= across.max() + rc))
    idx, cx, cy = idx[keep], cx[keep], cy[keep]
    z = ground_under(forest, idx, cx, cy)
    (x0, y0), (x1, y1) = s.bounds_m
    shift = np.array([float(origin_m[0]) - x0, float(origin_m[1]) - y0])
    tile_image, image = np.zeros(2), np.zeros((2, idx.size))
    if s.periodic:
        period = np.array([x1 - x0, y1 - y0])
        tile_image = np.floor(shift / period)
        shift = shift - tile_image * period
        image = np.rint((np.stack([cx, cy]) - np.stack([s.x_m[idx], s.y_m[idx]]))
                        / period[:, None])
    lo = image.min(axis=1) if idx.size else tile_image
    n_img = (image.max(axis=1) - lo + 1).astype(int) if idx.size else np.ones(2, int)
    ground = np.full(int(n_img[0] * n_img[1]) * s.n_trees, np.nan, np.float32)
    slot = ((image[1] - lo[1]) * n_img[0] + image[0] - lo[0]).astype(np.int64)
    ground[slot * s.n_trees + idx] = z
    return {"shift_m": (float(shift[0]), float(shift[1])),
            "image0": tuple(int(v) for v in tile_image - lo), "images": tuple(map(int, n_img)),
            "trees": int(s.n_trees), "ground_z_m": ground,
            "top_m": float(z.max() + s.height_m[idx].max()) + 1e-2 if idx.size else -1e30}


def table_file(table: dict) -> pathlib.Path:
    """Write ``table`` once to the cache (``LIDAR_MITSUBA_CACHE`` or the temporary folder),
    named by its content's hash, and return the path (an XML scene or a dict names it)."""
    from lidar_mitsuba_plugins import canopy_table as ct
    checked = ct.check(table)
    h = hashlib.sha256()
    for k in sorted(checked):
        h.update(k.encode())
        h.update(np.asarray(checked[k]).tobytes() if isinstance(checked[k], np.ndarray)
                 else repr(checked[k]).encode())
    folder = pathlib.Path(os.environ.get("LIDAR_MITSUBA_CACHE")
                          or pathlib.Path(tempfile.gettempdir()) / "lidar_mitsuba-cache")
    # (not "lidar_mitsuba": a folder of the package's name in the temporary directory
    # shadows the package for `python -m lidar_mitsuba.cli` run from there)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"canopy_{h.hexdigest()[:20]}.npz"
    if not path.exists():
        tmp = path.with_suffix(f".{os.getpid()}.npz")
        ct.save(tmp, checked)
        os.replace(tmp, path)
    return path


def integrator_dict(stand, *, mode: str, base: dict, rho: float, tau: float,
                    hot_spot: bool = True, max_depth: int | None = None,
                    table: bool = True) -> dict:
    """The ``canopy`` integrator's Mitsuba dict for ``stand`` in representation ``mode``
    (:data:`MODES`), over ``base`` (the instrument's ``pathlength`` parameters:
    ``Instrument.integrator_dict()``). ``max_depth``: ``turbid``'s vertices per path
    (default the plugin's, 3); ``gap`` has two records per photon. ``table`` False: the
    dict names no table (a DEM's corridor tiles: the stand's crowns, :func:`stand_crowns`, and
    each tile's ground, :func:`tile_crowns`, are set on the integrator)."""
    if mode not in MODES:
        raise ParameterError("representation", f"must be one of explicit, {', '.join(MODES)}"
                                               f" (got {mode!r})")
    pad = float(base.get("fov_radius_m", 20.65)) + 20.0
    d = {k: v for k, v in base.items() if k != "max_depth"}
    d.update(type="canopy", mode=mode, hot_spot=bool(hot_spot))
    if table:
        d["filename"] = str(table_file(canopy_table(stand, rho=rho, tau=tau, pad_m=pad)))
    if mode == "turbid" and max_depth is not None:
        d["max_depth"] = int(max_depth)
    return d


def no_shapes(forest, *, bounds_xy_m, shift_m) -> tuple[dict, int]:
    """The turbid and gap representations' Mitsuba shapes: none (the crowns are the
    ``canopy`` integrator's table, :func:`forest_integrator`); the scene is the ground's."""
    return {}, 0


def forest_integrator(forest, base: dict) -> dict:
    """The integrator a :class:`~lidar_mitsuba.vegetation.forest.ForestSurface` in the
    ``turbid`` or ``gap`` representation is traced with: ``canopy`` over ``base`` (the
    material's ``pathlength`` dict, whose ``max_depth`` the turbid medium keeps), the leaves'
    optics the forest's. Over one scene in the stand's coordinates (a plane or a
    heightfield) the table is the whole stand's; over a DEM's corridor tiles the forest's
    tiling sets the stand's crowns once (:func:`stand_crowns`) and each tile's ground
    (:func:`tile_crowns`)."""
    return integrator_dict(forest.stand, mode=forest.representation, base=base,
                           rho=forest.leaf.reflectance, tau=forest.leaf.transmittance,
                           max_depth=base.get("max_depth"),
                           table=not hasattr(forest.ground, "corridor_tile"))
