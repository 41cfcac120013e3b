"""Land under snow as ATL08 flags it: whether a segment has snow on the ground, and the albedo
the sun sees of its land-cover class when it has.

ATL08's ``land_segments/segment_snowcover`` is the daily snow and ice cover ATL09 copies in
(NOAA's IMS, 4 km cells): 0 ice-free water, 1 snow-free land, 2 snow, 3 ice (the ATL08 data
dictionary). ``segment_landcover`` is the land-cover class under the segment: Copernicus
Global Land Service's 100 m classes (codes 20-126, 200) from release 005, MODIS's IGBP classes
(codes 1-17) before.

**The sunlit albedo under snow** (:data:`SNOW_COVERED_ALBEDO`) is the published white-sky
albedo of the class with snow on the ground: Moody, King, Schaaf, Hall & Platnick 2007,
"Northern Hemisphere five-year average (2000-2004) spectral albedos of surfaces in the
presence of snow: statistics computed from Terra MODIS land products", Remote Sens. Environ.
111, 337-345 (its abstract's figures at 0.47 um: evergreen needleleaf forest 0.36, against
0.03 snow-free in winter; mixed forest 0.39; croplands 0.76, against 0.04; barren 0.87;
permanent snow 0.95). A snow-covered forest's albedo is the snow seen between and under the
crowns, far below the snow's own: it is what the solar background of a forest in snow sees,
where the twin's snow floor alone (~0.97) would count the snow as if no tree shaded it.

ESTIMATES, each said where it is used:

* the 0.47 um figures stand for 532 nm: snow's albedo falls by ~1 % between them (pure snow,
  Wiscombe & Warren 1980) and a winter conifer canopy brightens a little in the green, both
  small beside the classes' spread;
* classes the abstract does not give take the nearest it does (:data:`STAND_IN`): forests
  other than evergreen needleleaf and shrubs the mixed forest's 0.39 (some winter canopy over
  the snow), low vegetation, wetlands, moss and built-up land the croplands' 0.76 (little to
  none): the abstract's own reading, "ecosystems with some winter canopy have lower albedos
  than ecosystems with little to no winter canopy".
"""
from __future__ import annotations

import numpy as np

SNOW_COVERED_ALBEDO = {
    "evergreen needleleaf forest": 0.36,
    "mixed forest": 0.39,
    "cropland": 0.76,
    "barren": 0.87,
    "permanent snow": 0.95,
}
"""White-sky albedo at 0.47 um of each class with snow on the ground (Moody et al. 2007's
abstract; module docstring)."""

STAND_IN = {
    "other forest": "mixed forest",
    "shrubs": "mixed forest",
    "herbaceous": "cropland",
    "herbaceous wetland": "cropland",
    "moss and lichen": "cropland",
    "urban": "cropland",
}
"""Classes without a figure of their own, and the class whose figure they take (ESTIMATE:
module docstring)."""

COPERNICUS = {
    20: "shrubs", 30: "herbaceous", 40: "cropland", 50: "urban", 60: "barren",
    70: "permanent snow", 80: "water", 90: "herbaceous wetland", 100: "moss and lichen",
    111: "evergreen needleleaf forest", 121: "evergreen needleleaf forest",
    115: "mixed forest", 125: "mixed forest", 200: "water",
    **{c: "other forest" for c in (112, 113, 114, 116, 122, 123, 124, 126)},
}
"""Copernicus Global Land Service's discrete classes (ATL08 from release 005) by the class
names used here (111/121 closed/open evergreen needle leaf, 115/125 mixed, the other
forests' closed and open codes; 0 unknown)."""

IGBP = {
    1: "evergreen needleleaf forest", 2: "other forest", 3: "other forest",
    4: "other forest", 5: "mixed forest", 6: "shrubs", 7: "shrubs", 8: "shrubs", 9: "shrubs",
    10: "herbaceous", 11: "herbaceous wetland", 12: "cropland", 13: "urban", 14: "cropland",
    15: "permanent snow", 16: "barren", 17: "water",
}
"""MODIS's IGBP classes (ATL08 before release 005): savannas with the shrubs (some woody
cover), the cropland mosaic with the croplands."""

SNOW_FLAGS = (2, 3)
"""``segment_snowcover`` values that mean snow or ice on the ground."""


def land_class(code) -> str | None:
    """The class name of a ``segment_landcover`` code (Copernicus from 20 up, IGBP below;
    ``None`` for 0, unknown codes and fill)."""
    c = int(code)
    return COPERNICUS.get(c) if c >= 20 else IGBP.get(c)


def snow_covered_albedo(code) -> tuple[float, str, str] | None:
    """``(albedo, class, source)``: the sunlit albedo of land-cover ``code``'s class with snow
    on the ground (:data:`SNOW_COVERED_ALBEDO`, through :data:`STAND_IN` for a class without
    its own figure, said in ``source``); ``None`` for water and unknown classes."""
    name = land_class(code)
    if name is None or name == "water":
        return None
    if name in SNOW_COVERED_ALBEDO:
        return SNOW_COVERED_ALBEDO[name], name, f"Moody et al. 2007: {name}"
    stand = STAND_IN[name]
    return (SNOW_COVERED_ALBEDO[stand], name,
            f"Moody et al. 2007: {stand}, standing in for {name} (ESTIMATE)")


def snow_on_ground(snowcover, landcover) -> dict:
    """What a beam's segments say of snow: ``snow_fraction`` (of the segments whose
    ``segment_snowcover`` is 0-3, those at 2 or 3; ``None`` where none is), and over the
    snowy segments whose class has a figure the mean sunlit ``albedo`` and the ``sources``
    behind it (``None`` without such segments). ``snowcover`` and ``landcover``: (n,) per
    segment (``landcover`` may be ``None``: no albedo)."""
    s = np.asarray(snowcover).ravel()
    ok = (s >= 0) & (s <= 3)
    out = {"snow_fraction": None, "albedo": None, "sources": []}
    if not ok.any():
        return out
    snowy = ok & np.isin(s, SNOW_FLAGS)
    out["snow_fraction"] = float(snowy.sum() / ok.sum())
    if landcover is None or not snowy.any():
        return out
    land = np.asarray(landcover).ravel()
    if land.size != s.size:
        return out
    found = [snow_covered_albedo(c) for c in land[snowy]]
    found = [f for f in found if f is not None]
    if found:
        out["albedo"] = float(np.mean([f[0] for f in found]))
        out["sources"] = sorted({f[2] for f in found})
    return out
