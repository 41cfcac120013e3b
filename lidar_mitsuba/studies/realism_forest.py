"""The realism matrix's forest rows (issue 41 with issue 42's forest twin): a real ATL03 and
ATL08 pair over forest is judged against its twin (:mod:`~lidar_mitsuba.studies.forest_twin`:
a conifer stand of the clip's own ATL08 canopy height, cover and DEM slope, its every shot
simulated), not against the flat plate the matrix puts under other products.

Each product's row compares the quantity the twin compares for it, the same estimator on the
real file and on the twin:

* **ATL03**: photons per shot from 1 m below the ground to 15 m above it (the twin's
  :data:`~lidar_mitsuba.studies.forest_twin.LAYERS_M`), all photons less the background the
  file's rate puts there, no classifier: the clip's above NASA's ground, the twin's above its
  true ground (:func:`~lidar_mitsuba.studies.forest_twin.layer_signal`). The matrix's ATL03
  signal elsewhere, ``signal_conf_ph >= 3`` photons per pulse, is 0 on most of the clip's
  segments (its weak beam's canopy under a 1.8 MHz day background): it is kept in the row
  as ``measured["signal_clear"]`` but not compared.
* **ATL08**: ground and canopy photons per shot (``n_te_photons`` and ``n_ca_photons +
  n_toc_photons`` of each 100 m segment over its shots, medians): NASA's ATL08 of the clip
  against our ATL08 classifier on the twin's ATL03.

The background stays the matrix's (:func:`~lidar_mitsuba.night.background_terms`, the same
model the twin writes into its ATL03) over the twin's floor (:func:`floor_albedo`), with the
twin's signal for the leak term. The twin is
clear sky: it is compared over all the clip's segments, whatever the product's cloud flags say.
"""
from __future__ import annotations


from .realism import BACKGROUND_AGREES, SIGNAL_AGREES

SIGNAL_WHAT = {
    "ATL03": "photons per shot -1 to 15 m above the ground, all photons less the background "
             "(no classifier; the clip's above NASA's ground, the twin's above its true one)",
    "ATL08": "ground + canopy photons per shot ((n_te + n_ca + n_toc) / shots, medians; NASA's "
             "ATL08 of the clip, ours of the twin)",
}
"""What each forest row's signal is (module docstring)."""


def surface_name(doc: dict) -> str:
    """The row's surface: the twin's stand and floor."""
    s = doc["stand"]
    return (f"forest twin ({s['trees']} conifers, mean height {s['mean_height_m']:.1f} m, "
            f"cover {100 * s['cover']:.0f} %, LAI {s['lai']:.1f}, `{s['representation']}`, "
            f"{doc.get('floor', 'litter')} floor{_sunlit(doc)}, {doc['shots']} shots)")


def _sunlit(doc: dict) -> str:
    a = doc.get("sunlit_albedo")
    return "" if a is None else f" (sunlit albedo {a:.2f}: its land cover under snow)"


def prediction(doc: dict, product: str) -> dict:
    """The forest row's surface, its signal measured and predicted (module docstring), the
    twin's true signal photons per shot (for the leak term) and what the signal is."""
    if product == "ATL08":
        parts = (doc["nasa"]["ground_per_shot"], doc["nasa"]["canopy_per_shot"])
        real = None if None in parts else sum(parts)   # (a subset dropped a count)
        twin = doc["ours_twin"]["ground_per_shot"] + doc["ours_twin"]["canopy_per_shot"]
    else:
        parts = list(doc["like_with_like"]["real"].values())
        real = None if None in parts else sum(parts)   # (no NASA ground to stand them on)
        twin = sum(doc["like_with_like"]["twin"].values())
    return {"surface": surface_name(doc),
            "signal_measured": None if real is None else float(real),
            "signal_per_shot": float(twin),
            "signal_truth": float(doc["twin_truth"]["signal_per_shot"]),
            "signal_from": "the forest twin: " + SIGNAL_WHAT.get(product, SIGNAL_WHAT["ATL03"]),
            "forest_shots": int(doc["shots"]), "floor_albedo": floor_albedo(doc)}


def floor_albedo(doc: dict) -> float:
    """The sunlit albedo the row's background takes: the twin's own, the same surface as its
    signal, whatever the product's own flags would give (a clip's ``surf_type`` can flag land
    ice over a boreal forest): over snow its land cover's under snow
    (:func:`~lidar_mitsuba.studies.forest_twin.floor_of`), else its floor's optics' ``R +
    T``."""
    if doc.get("sunlit_albedo") is not None:
        return float(doc["sunlit_albedo"])
    from ..vegetation.optics import optics
    return float(optics(doc.get("floor", "litter")).albedo)


def verdict(row: dict) -> tuple[str, str]:
    """``(verdict, reason)`` of a forest row: its signal (:func:`prediction`) within the
    matrix's 0.7-1.4 and its background, where the file has one, within 0.5-2."""
    m, p = row["measured"], row["predicted"]
    sig = _ratio(p["signal_per_shot"], m["signal_forest"])
    bg = _ratio(p["background_hz"], m["background_clear_hz"] if m["background_clear_hz"]
                is not None else m["background_cloudy_hz"])
    row["signal_ratio"], row["background_ratio"] = sig, bg
    bad = [f"{k} x{v:.2f}" for k, v, (lo, hi) in (("background", bg, BACKGROUND_AGREES),
                                                  ("signal", sig, SIGNAL_AGREES))
           if v is not None and not lo <= v <= hi]
    what = p["signal_from"].split(": ", 1)[1]
    cloud = ("; clear-sky twin over all segments (the product flags every one cloudy)"
             if m["cloud_flags"] and m["clear_fraction"] == 0 else "")
    if sig is None and bg is None:
        return "not measured", "neither the twin's signal nor a background rate to compare"
    if bad:
        return "disagrees", ", ".join(bad) + f" (signal: {what}){cloud}"
    if sig is None:                         # (the file lacks what its signal is counted from)
        return "agrees", (f"background x{_fmt(bg)}; signal not measured: the clip's ATL08 "
                          f"lacks what it is counted from (signal: {what}){cloud}")
    return "agrees", (f"background x{_fmt(bg)}, signal x{_fmt(sig)} (signal: {what}){cloud}")


def missing(*, signal_shots: int, paired: bool) -> tuple[str, str]:
    """``(verdict, reason)`` of a land row without its forest twin."""
    if paired and signal_shots <= 0:
        return "not simulated", ("land: the forest twin of the file's ATL03 + ATL08 pair "
                                 "(studies.forest_twin) simulates this surface with "
                                 "--signal-shots above 0; with 0 only the lidar equation over "
                                 "a flat plate of albedo 0.1; beam, energy and sky as given")
    return "surface missing", ("land: the forest twin needs the file's ATL03 + ATL08 pair (its "
                               "stand from ATL08's canopy height, cover and DEM slope, its "
                               "shots from ATL03) and a canopy height on some segment; a flat "
                               "plate of albedo 0.1 stands in; beam, energy and sky as given")


def _ratio(pred, meas) -> float | None:
    if pred is None or meas is None or not meas > 0:
        return None
    return float(pred / meas)


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.2f}"
