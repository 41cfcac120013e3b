"""A campaign over land (issue 42): the spec's ``[forest]`` over each granule's DEM, and the
statistics of a granule's ATL08 (our classifier's 100 m land segments,
:mod:`lidar_mitsuba.products.atl08`) for its row of the task table."""
from __future__ import annotations

import math
import os

import numpy as np

#: the task table's ATL08 columns (NaN, or "" for the file, without ATL08)
LAND_COLUMNS: dict[str, str] = {
    "atl08": "ATL08 file, relative to granules/ (ATL08/ATL08_...h5; '' when not asked for)",
    "n_land_segments": "ATL08 100 m land segments, all beams",
    "n_terrain": "land segments with a terrain height (h_te_best_fit)",
    "terrain_bias_m": "mean of h_te_best_fit - h_surface_true over those segments [m]",
    "terrain_std_m": "standard deviation of that error [m]",
    "n_canopy": "land segments with a canopy height (h_canopy)",
    "h_canopy_m": "median h_canopy (RH98 above the terrain) of those segments [m]",
}


def forest_over(surface, forest: dict):
    """The spec's ``[forest]`` (a dict of :func:`~lidar_mitsuba.vegetation.forest.forest`
    keywords, ``size_m`` the side of the periodic stand [m] at the DEM's centre, default
    2048) over the granule's
    :class:`~lidar_mitsuba.ground.dem.DEMSurface` ``surface``."""
    from ..vegetation.forest import forest as make_forest
    from ..vegetation.stand import DEM_STAND_M
    kw = dict(forest)
    half = float(kw.pop("size_m", DEM_STAND_M)) / 2
    cx, cy = surface.centre_xy_m()
    return make_forest(ground=surface, bounds_m=((cx - half, cy - half), (cx + half, cy + half)),
                       **kw)


def land_statistics(path: str | os.PathLike) -> dict:
    """:data:`LAND_COLUMNS`' numbers of one of our ATL08 files (every beam): the terrain's
    error against the truth written beside it (``truth/gtXx/land_segments/h_surface_true``)
    and the canopy height."""
    import h5py
    fill = float(np.finfo(np.float32).max)
    err, canopy, n = [], [], 0
    with h5py.File(path, "r") as f:
        for name in sorted(k for k in f if k.startswith("gt")):
            ls = f[f"{name}/land_segments"]
            h = ls["terrain/h_te_best_fit"][()].astype(np.float64)
            truth = f[f"truth/{name}/land_segments/h_surface_true"][()].astype(np.float64)
            c = ls["canopy/h_canopy"][()].astype(np.float64)
            n += h.size
            ok = (h < fill) & np.isfinite(truth)
            err.append(h[ok] - truth[ok])
            canopy.append(c[c < fill])
    e = np.concatenate(err) if err else np.zeros(0)
    c = np.concatenate(canopy) if canopy else np.zeros(0)
    return {"n_land_segments": int(n), "n_terrain": int(e.size),
            "terrain_bias_m": float(e.mean()) if e.size else math.nan,
            "terrain_std_m": float(e.std(ddof=1)) if e.size > 1 else math.nan,
            "n_canopy": int(c.size),
            "h_canopy_m": float(np.median(c)) if c.size else math.nan}
