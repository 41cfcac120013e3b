"""What surface an ATL06 beam is over, read from the file: ATL06 is made wherever ATL03
flags land ice, and early releases (e.g. 209) over every surface, so its land-ice fit also
runs over open ocean and land, where an ``r_eff`` is not a snow surface's. Pure (numpy).
"""
from __future__ import annotations

import numpy as np

from .real import text

DEM_SURFACES = {"mss": "ocean", "gmted": "land", "global": "land"}
"""ATL06 ``dem/dem_flag``'s meanings (its own ``flag_meanings``: ``none arctic gmted mss
antarctic`` and the like, by release) that name a surface other than an ice sheet: the mean
sea surface (open ocean) and the global land DEMs; ``arctic``, ``gimp``, ``antarctic``,
``rema`` and ``none`` are land ice."""
SEA_LEVEL_M = 1.0
"""A global land DEM whose height (``dem/dem_h``) is within this of the geoid
(``dem/geoid_h``) on most segments is the DEM's sea: open ocean [m] (ESTIMATE: GMTED writes
the sea at 0 m above the geoid; land within 1 m of it is a coastal sliver)."""


def dem_surface(s) -> str:
    """An ATL06 beam's surface (``land ice``, ``land`` or ``ocean``) from the DEM most of its
    segments were checked against (``land_ice_segments/dem/dem_flag`` by its
    ``flag_meanings``, :data:`DEM_SURFACES`; a global land DEM at the geoid:
    :data:`SEA_LEVEL_M`); ``land ice`` where the file does not say."""
    if "dem" not in s or "dem_flag" not in s["dem"]:
        return "land ice"
    dem = s["dem"]
    d = dem["dem_flag"]
    meanings = text(d.attrs.get("flag_meanings", "")).split()
    values = np.asarray(d.attrs.get("flag_values", np.arange(len(meanings)))).ravel()
    flags = np.asarray(d[()]).ravel()
    if not flags.size or len(meanings) != values.size:
        return "land ice"
    vals, counts = np.unique(flags, return_counts=True)
    word = dict(zip(values.tolist(), meanings)).get(int(vals[np.argmax(counts)]), "")
    surface = DEM_SURFACES.get(word.lower(), "land ice")
    if surface == "land" and "dem_h" in dem and "geoid_h" in dem:
        dh = np.asarray(dem["dem_h"][()], float) - np.asarray(dem["geoid_h"][()], float)
        dh = dh[np.isfinite(dh) & (np.abs(dh) < 1e30)]
        if dh.size and np.median(np.abs(dh)) < SEA_LEVEL_M:
            return "ocean"
    return surface


def dem_said(s) -> bool:
    """Whether an ATL06 beam's ``land_ice_segments`` says its DEM: ``dem/dem_flag`` with its
    own ``flag_meanings`` (a subset can drop the group, a conversion the attributes; then
    :func:`dem_surface` takes land ice)."""
    if "dem" not in s or "dem_flag" not in s["dem"]:
        return False
    d = s["dem"]["dem_flag"]
    meanings = text(d.attrs.get("flag_meanings", "")).split()
    values = np.asarray(d.attrs.get("flag_values", np.arange(len(meanings)))).ravel()
    return bool(meanings) and len(meanings) == values.size
