"""The twin of the real forest clip (issue 42): the Medicine Bow ATL03 + ATL08 pair simulated
again from what is known of the site, without fitting the photons.

**Inputs** (read before any comparison, as a DEM is an input; :func:`site_inputs`):

* the canopy height: the clip's own ATL08 ``h_canopy`` (RH98 of the canopy photons above the
  ground), its median over the segments; the stand's mean tree height is set so that the
  98th percentile of its tree heights is that value (heights normal with the conifer
  preset's coefficient of variation ``cv``: ``h_mean = h_canopy / (1 + 2.054 cv)``);
* the canopy cover: ATL08's ``segment_cover`` (percent; the fractional tree cover of an
  external map the product copies in, Copernicus Global Land Service from release 005,
  MODIS VCF before: recalled from the ATL08 data dictionary, the clip carries no
  attributes), median;
  ``segment_landcover`` (Copernicus classes 111 closed / 121 open evergreen needle-leaf
  forest) says the stand is a conifer one;
* the terrain slope: ATL08's ``dem_h`` (the reference DEM under each segment) fitted against
  the along-track distance: the along-track slope of the DEM, the ground a plane with it;
* the floor: ATL08's ``segment_snowcover`` (NOAA's IMS): snow where it says snow or ice on
  more than half the segments, the sun then seeing the forest with its land cover's
  published albedo under snow (:func:`floor_of`, :mod:`~lidar_mitsuba.vegetation.snow_cover`);
  litter otherwise;
* the sun, the spacecraft range, the beam (weak: the file's ``atlas_beam_type``;
  ``sc_orient`` 0, backward, makes the left beams strong) and its energy (the file's
  ``tx_pulse_energy``): the twin's (:mod:`lidar_mitsuba.twin`), as the realism matrix uses.

**The stand**: the package's conifer preset (:data:`~lidar_mitsuba.vegetation.stand.PRESETS`:
narrow cones, crown radius 1/10 of the height over half of it, as lodgepole pine; spherical
needle angles; clumping 0.6, He et al. 2012's evergreen needle-leaf mean) with LAI
:data:`SITE_LAI` (see there). Medicine Bow's forests at 2 450 m are lodgepole pine with
spruce-fir higher up; the clip's 7-10 m canopy is young lodgepole.

**Representation**: ``gap`` (:mod:`lidar_mitsuba.vegetation.turbid`, the ``canopy``
integrator's gap mode): an 11 m footprint holds on the order of a hundred of these crowns,
so what the photons see is the gap probability of the lines through them and the height at
which each line first meets a needle, with the monostatic hot spot; needles scatter little
at 532 nm (single-scattering albedo R + T = 0.14), so light scattered twice in the crowns is
a few percent of the canopy return, the error the gap layer makes (the turbid representation
traces it, at several times the cost; explicit needles would need millions of facets per
footprint for the same answer).

**Compared** (what the inputs do not give away; :func:`compare`): first like with like,
signal photons per shot in layers above the ground (:data:`LAYERS_M`) from *all* the photons
less the background the file's rate puts there, the real ones above NASA's ground
(:func:`nasa_ground_dh`), the twin's above its true ground (:func:`layer_signal`): no
classifier between the two; then ground and canopy photons
per shot (NASA's ``n_te_photons`` and ``n_ca_photons + n_toc_photons`` per 100 m segment over
its shots, and our ATL08 classifier run on the real and on the twin's ATL03 alike), the
photon heights above the ground through the canopy (per shot, in height bins), and the
background rate. Run: ``python -m lidar_mitsuba.studies.forest_twin``; ``validate --real``
runs it for every ATL03/ATL08 forest pair it is given.
"""
from __future__ import annotations

import math
import pathlib
import tempfile

import numpy as np

from .atl08_real import ATL03, ATL08, F4_FILL
from .realism import BACKGROUND_AGREES

SITE_LAI = 3.0
"""Leaf area index of the stand (one-sided; half the needles' total area). ESTIMATE: the
conifer preset's value (a lower-quartile figure of Asner et al. 2003's evergreen needle-leaf
biome, 5.5 on average); lodgepole pine stands of the central Rocky Mountains carry a
projected LAI of about 2-4 (Kaufmann, Edminster & Troendle 1982, USDA For. Serv. Res. Pap.
RM-238, recalled, not checked), young ones at the lower end."""

HEIGHT_BINS_M = (-1.0, 1.0, 3.0, 5.0, 7.0, 9.0, 11.0, 15.0)
"""Edges [m above the ground] of the height distribution compared: the ground's band
(+-1 m) and the canopy in 2 m layers up to 11 m, then the top."""

AGREES = (0.7, 1.4)
"""A twin / real ratio within this range agrees (the realism matrix's signal criterion,
:data:`~lidar_mitsuba.studies.realism.SIGNAL_AGREES`)."""

Z_98 = 2.054
"""The standard normal's 98th percentile (RH98 of normal tree heights is mean (1 + z cv))."""

LAYERS_M = (("ground", -1.0, 1.0), ("understorey", 1.0, 2.0), ("canopy", 2.0, 15.0))
"""Layers [m above the ground] of the like-with-like comparison (:func:`layer_signal`): the
ground's band (+-1 m: ATLAS's pulse and the slope's spread across a footprint on the clip's
slopes of up to 17 %, ~0.5 m), the first metre above it, and the canopy from 2 m up to 15 m
(twice the clip's canopy height, inside the twin's +-15 m range gate)."""


def _along_m(lat_deg, lon_deg) -> np.ndarray:
    """Along-track distance [m] of points from the first one (geodesic on WGS84)."""
    from pyproj import Geod
    g = Geod(ellps="WGS84")
    lat, lon = np.asarray(lat_deg, float), np.asarray(lon_deg, float)
    _, _, d = g.inv(np.full(lat.size, lon[0]), np.full(lat.size, lat[0]), lon, lat)
    return np.asarray(d, float)


def site_inputs(atl08_path=ATL08, beam: str = "gt1r") -> dict:
    """What the twin takes from the clip's ATL08 (module docstring): ``h_canopy_m``,
    ``cover`` (fraction), ``landcover`` (Copernicus classes), ``slope`` (dz/d along, DEM),
    ``track_azimuth_deg`` (from north, clockwise), ``strength``, the segments' count."""
    import h5py
    from pyproj import Geod
    with h5py.File(atl08_path) as f:
        ls = f[f"{beam}/land_segments"]
        h = ls["canopy/h_canopy"][()].astype(float)
        cover = ls["canopy/segment_cover"][()].astype(float)
        dem = ls["dem_h"][()].astype(float) if "dem_h" in ls else np.full(h.shape, np.nan)
        lat, lon = ls["latitude"][()], ls["longitude"][()]
        land = ls["segment_landcover"][()] if "segment_landcover" in ls else None
        snow = ls["segment_snowcover"][()] if "segment_snowcover" in ls else None
        strength = f[beam].attrs.get("atlas_beam_type", [b"?"])
        orient = int(f["orbit_info/sc_orient"][0]) if "orbit_info/sc_orient" in f else None
    strength = np.atleast_1d(strength)[0]
    strength = strength.decode() if isinstance(strength, bytes) else str(strength)
    ok_h = h < F4_FILL
    ok_c = (cover >= 0) & (cover <= 100)
    along = _along_m(lat, lon)
    ok_d = np.abs(dem) < 1e4
    slope = float(np.polyfit(along[ok_d], dem[ok_d], 1)[0]) if ok_d.sum() >= 2 else 0.0
    az = Geod(ellps="WGS84").inv(lon[0], lat[0], lon[-1], lat[-1])[0]
    from ..vegetation.snow_cover import snow_on_ground
    snow = (snow_on_ground(snow, land) if snow is not None
            else {"snow_fraction": None, "albedo": None, "sources": []})
    return {"h_canopy_m": float(np.median(h[ok_h])), "cover": float(np.median(cover[ok_c])) / 100,
            "landcover": [] if land is None else sorted({int(v) for v in land}), "slope": slope,
            "track_azimuth_deg": float(az), "strength": strength, "sc_orient": orient,
            "segments": int(h.size), "snow": snow,
            "slope_from": "dem_h" if ok_d.sum() >= 2 else "none: no dem_h on two segments, flat"}


def floor_of(inputs: dict) -> tuple[str, float | None, str]:
    """``(floor, sunlit_albedo, why)``: the twin's forest floor from the clip's own snow flag
    (ATL08's ``segment_snowcover``, :mod:`~lidar_mitsuba.vegetation.snow_cover`): snow where
    more than half of the beam's flagged segments say snow or ice, with the sunlit albedo of
    its land-cover class under snow (Moody et al. 2007: the snow between and under the
    crowns, which the floor's own albedo would count as unshaded); litter otherwise, whose
    albedo the sun takes as it is (``None``: the floor's own)."""
    snow = inputs.get("snow") or {}
    frac = snow.get("snow_fraction")
    if frac is None:
        return "litter", None, "litter floor (the clip gives no segment_snowcover)"
    if frac > 0.5 and snow.get("albedo") is not None:
        return ("snow", float(snow["albedo"]),
                f"snow floor (segment_snowcover: snow or ice on {100 * frac:.0f} % of the "
                f"segments); sunlit albedo {snow['albedo']:.2f} ("
                + "; ".join(snow["sources"]) + ")")
    if frac > 0.5:                 # no class with a figure: the twin's own conifer stand's
        from ..vegetation.forest import default_sunlit_albedo
        a = default_sunlit_albedo("conifer")
        return ("snow", a, f"snow floor (segment_snowcover: snow or ice on {100 * frac:.0f} % "
                f"of the segments); sunlit albedo {a:.2f} (Moody et al. 2007: evergreen "
                "needleleaf forest, the twin's conifer stand: the snowy segments' land cover "
                "gives no figure of its own, or the clip has no segment_landcover)")
    return "litter", None, (f"litter floor (segment_snowcover: snow-free on "
                            f"{100 * (1 - frac):.0f} % of the segments)")


def twin_forest(inputs: dict, *, tile_m: float = 256.0, seed: int = 1,
                representation: str = "gap", floor: str = "auto"):
    """The twin's :class:`~lidar_mitsuba.vegetation.forest.ForestSurface`: the conifer
    preset's stand of the clip's height and cover (module docstring) over a plane of the
    DEM's along-track slope, a ``tile_m`` periodic tile (the track folds into it: 256 m
    gives footprints 20 m apart across the tile at each wrap of this track). ``floor``: the
    forest floor's optics (:func:`~lidar_mitsuba.vegetation.optics.optics`: ``litter`` or
    ``snow``), ``auto`` the clip's own (:func:`floor_of`: snow where its ``segment_snowcover``
    says so, with the sunlit albedo of its land cover under snow)."""
    from ..ground.surface import Plane
    from ..vegetation.forest import forest
    from ..vegetation.optics import optics
    from ..vegetation.stand import PRESETS
    cv = PRESETS["conifer"].height_cv
    sunlit = None
    if floor == "auto":
        floor, sunlit, _ = floor_of(inputs)
    slope = inputs["slope"]
    # Plane azimuth: from +x (east) counter-clockwise; the track heads track_azimuth_deg
    # clockwise from north; the ground rises along it when slope > 0
    heading = 90.0 - inputs["track_azimuth_deg"] + (0.0 if slope >= 0 else 180.0)
    ground = Plane(slope_deg=math.degrees(math.atan(abs(slope))), azimuth_deg=heading % 360,
                   size_m=tile_m)
    return forest(species="conifer", ground=ground, representation=representation,
                  height_m=inputs["h_canopy_m"] / (1 + Z_98 * cv),
                  cover=min(inputs["cover"], 0.99), lai=SITE_LAI, seed=seed,
                  floor=optics(floor), sunlit_albedo=sunlit)


# ------------------------------------------------------------------------------ measuring
def atl08_counts(beam08, shots_per_m: float) -> dict:
    """Ground and canopy photons per shot of an :class:`~lidar_mitsuba.products.atl08.Atl08Beam`
    (ours, of any ATL03): per 100 m segment ``n_te / shots`` and ``(n_ca + n_toc) / shots``
    with ``shots = shots_per_m * 100 m``, their medians; the height distribution of its
    signal photons above its ground (photons per shot in :data:`HEIGHT_BINS_M`), and the
    canopy height ``h_canopy`` and terrain ``h_te_best_fit`` medians."""
    s = beam08.segments
    shots = 100.0 * shots_per_m
    n_te = s["land_segments/terrain/n_te_photons"].astype(float)
    n_ca = (s["land_segments/canopy/n_ca_photons"].astype(float)
            + s["land_segments/canopy/n_toc_photons"].astype(float))
    c = beam08.classification
    rel = c.h_rel_m[c.classes > 0]
    n_shots_all = shots * max(len(beam08), 1)
    hist = np.histogram(rel[np.isfinite(rel)], bins=HEIGHT_BINS_M)[0] / n_shots_all
    h_can = s["land_segments/canopy/h_canopy"].astype(float)
    return {"ground_per_shot": float(np.median(n_te / shots)),
            "canopy_per_shot": float(np.median(n_ca / shots)),
            "height_per_shot": hist.tolist(),
            "h_canopy_m": _median_valid(h_can), "segments": len(beam08)}


def layer_signal(dh_m, *, shots: float, background_per_m_shot: float,
                 layers=LAYERS_M) -> dict:
    """Signal photons per shot in each layer of ``layers`` (name, bottom, top [m above the
    ground]) from *all* the photons' heights ``dh_m`` above a ground (no classifier): the
    count over ``shots`` less the background's expectation, ``background_per_m_shot`` (the
    rate times 2/c) times the layer's thickness. The same estimator for a real file (heights
    above NASA's ground) and for the twin (above its true ground): like with like."""
    dh = np.asarray(dh_m, float)
    dh = dh[np.isfinite(dh)]
    n = max(float(shots), 1.0)
    return {name: float(np.sum((dh >= lo) & (dh < hi)) / n - background_per_m_shot * (hi - lo))
            for name, lo, hi in layers}


def nasa_ground_dh(atl03_path, atl08_path, beam: str) -> dict:
    """Every ATL03 photon's height above NASA's ground (``dh_m``; NaN outside the span of the
    classed photons): the ground under each photon NASA classed is ``h_ph - ph_h`` (ATL08's
    ``ph_h`` is the height above its interpolated ground), joined along track by lines; and
    ``shots`` (the span's shots), ``background_per_m_shot`` (the median ``bckgrd_rate`` times
    2/c). Photons are matched as :mod:`.atl08_real` does (``ph_segment_id``,
    ``classed_pc_indx``, checked on ``delta_time``)."""
    import h5py
    from ..constants import C_M_PER_NS
    from ..products.atl08 import read_atl03_beam
    d = read_atl03_beam(atl03_path, beam)
    names = ("ph_segment_id", "classed_pc_indx", "delta_time", "ph_h")
    with h5py.File(atl08_path) as f:
        sp = f.get(f"{beam}/signal_photons")
        if sp is None or any(k not in sp for k in names):
            return None                    # (a subset dropped them: nothing to join)
        sid, indx, t8, ph_h = (sp[k][()] for k in names)
    pos = np.minimum(np.searchsorted(d["seg_id"], sid), d["seg_id"].size - 1)
    ph = d["beg0"][pos] + indx.astype(np.int64) - 1
    ok = (d["seg_id"][pos] == sid) & (ph >= 0) & (ph < d["h_m"].size) & (ph_h < F4_FILL)
    ok[ok] &= np.abs(d["delta_time_s"][ph[ok]] - t8[ok]) < 1e-6
    if ok.sum() < 2:
        return None                        # (no photon of NASA's matched: no ground)
    gx, gz = d["x_m"][ph[ok]], d["h_m"][ph[ok]] - ph_h[ok].astype(float)
    order = np.argsort(gx)
    gx, gz = gx[order], gz[order]
    x = d["x_m"]
    inside = np.isfinite(x) & (x >= gx[0]) & (x <= gx[-1])
    dh = np.where(inside, d["h_m"] - np.interp(np.where(inside, x, gx[0]), gx, gz), np.nan)
    rate = float(np.median(d["bckgrd_hz"])) if d["bckgrd_hz"] is not None else 0.0
    return {"dh_m": dh, "shots": float(d["shots_per_m"] * (gx[-1] - gx[0])),
            "background_per_m_shot": rate * 2.0 / (C_M_PER_NS * 1e9), "mapped": int(ok.sum())}


def _median_valid(a) -> float | None:
    a = np.asarray(a, float)
    a = a[np.isfinite(a) & (a < F4_FILL)]
    return float(np.median(a)) if a.size else None


def nasa_counts(atl08_path, beam: str, shots_per_m: float) -> dict:
    """NASA's ATL08 of the clip, the same quantities as :func:`atl08_counts` (heights above
    the ground: its ``signal_photons/ph_h`` of the classed photons)."""
    import h5py
    from ..products.real import _num      # (None where a subset dropped it: not measured)
    with h5py.File(atl08_path) as f:
        ls, sp = f[f"{beam}/land_segments"], f.get(f"{beam}/signal_photons") or {}
        n_te = _num(ls, "terrain/n_te_photons")
        n_ca, n_toc = _num(ls, "canopy/n_ca_photons"), _num(ls, "canopy/n_toc_photons")
        h_can = _num(ls, "canopy/h_canopy")
        flag, ph_h = _num(sp, "classed_pc_flag"), _num(sp, "ph_h")
    shots = 100.0 * shots_per_m

    def per_shot(n):
        n = None if n is None else n[(n >= 0) & (n < 1e7)]       # (fill: not a count)
        return float(np.median(n / shots)) if n is not None and n.size else None
    segments = None if n_te is None else int(n_te.size)
    hist = None
    if flag is not None and ph_h is not None and flag.size == ph_h.size and segments:
        rel = ph_h[(flag >= 1) & (flag <= 3) & (ph_h < F4_FILL)]     # (a fill flag: none)
        hist = (np.histogram(rel, bins=HEIGHT_BINS_M)[0] / (shots * segments)).tolist()
    return {"ground_per_shot": per_shot(n_te),
            "canopy_per_shot": None if n_ca is None or n_toc is None else per_shot(n_ca + n_toc),
            "height_per_shot": hist, "h_canopy_m": None if h_can is None else _median_valid(h_can),
            "segments": segments}


def background_hz(atl03_path, beam: str) -> float | None:
    """The median ``bckgrd_atlas/bckgrd_rate`` [Hz] of an ATL03 beam's clip, as the realism
    matrix reads it (:mod:`lidar_mitsuba.products.real`: the 50-shot row at or after each
    geolocation segment's time, the photons' times where a file has no segments): a clip keeps
    its granule's whole background table (the Medicine Bow and Saskatchewan clips of one
    granule both hold its 102 093 rows), whose median is not the clip's. The twin's file
    holds the model's rate there. ``None`` where a subset dropped the rates or their times,
    or they are fill."""
    import h5py
    with h5py.File(atl03_path) as f:
        g = f[beam]
        if "bckgrd_atlas/bckgrd_rate" not in g or "bckgrd_atlas/delta_time" not in g:
            return None
        rate = g["bckgrd_atlas/bckgrd_rate"][()].astype(np.float64)
        rows_t = g["bckgrd_atlas/delta_time"][()]
        t = (g["geolocation/delta_time"][()] if "geolocation/delta_time" in g
             else g["heights/delta_time"][()] if "heights/delta_time" in g else np.zeros(0))
    rate = np.where((rate >= 0) & (rate < 1e12), rate, np.nan)       # (fill: no rate)
    if t.size and rows_t.size == rate.size and rows_t.size:
        rate = rate[np.clip(np.searchsorted(rows_t, t), 0, rows_t.size - 1)]
    rate = rate[np.isfinite(rate)]
    return float(np.median(rate)) if rate.size else None


def simulate_twin(atl03_path=ATL03, atl08_path=ATL08, beam: str = "gt1r", *,
                  shots: int | None = None, seed: int = 1, out_path=None,
                  representation: str = "gap", floor: str = "auto") -> dict:
    """The twin (module docstring): the clip's shots over :func:`twin_forest` of
    :func:`site_inputs`, written as ATL03 to ``out_path`` (default a temporary file),
    our ATL08 of it. Returns ``{"inputs", "forest", "atl03", "result", "atl08"}``."""
    import warnings
    from .. import twin
    from ..granule import write_atl03
    from ..products import atl08
    inputs = site_inputs(atl08_path, beam)
    forest = twin_forest(inputs, seed=seed, representation=representation, floor=floor)
    tg = twin.read(atl03_path, beams=beam)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        g = twin.simulate_over_surface(tg, surface=forest, beams=beam, shots=shots, seed=seed,
                                       progress=False)
    if out_path is None:
        out_path = pathlib.Path(tempfile.mkdtemp(prefix="forest_twin_")) / "ATL03_twin.h5"
    write_atl03(g, out_path)
    return {"inputs": inputs, "forest": forest, "atl03": pathlib.Path(out_path),
            "result": g.beams[0].result, "atl08": atl08.from_atl03(out_path, beam)}


def _truth_counts(res) -> dict:
    """The twin's own truth: its signal photons' heights above the footprint's mean ground
    (``dh_m``) per shot in :data:`HEIGHT_BINS_M`, and those within 1 m of the ground."""
    sig = res.detections.is_signal
    dh = res.dh_m[sig]
    n = max(res.n_shots, 1)
    return {"signal_per_shot": float(sig.sum() / n),
            "ground_band_per_shot": float(np.sum(np.abs(dh) < 1.0) / n),
            "above_band_per_shot": float(np.sum(dh >= 1.0) / n),
            "height_per_shot": (np.histogram(dh, bins=HEIGHT_BINS_M)[0] / n).tolist()}


def _ratio(a, b) -> float | None:
    return None if a is None or b is None or not b > 0 else float(a / b)


def _verdict(r: float | None, agrees=AGREES) -> str:
    if r is None:
        return "not measured"
    lo, hi = agrees
    return "agrees" if lo <= r <= hi else "disagrees"


def compare(atl03_path=ATL03, atl08_path=ATL08, beam: str = "gt1r", *,
            shots: int | None = None, seed: int = 1, out_path=None,
            floor: str = "auto") -> dict:
    """The twin against the real clip (module docstring): rows of ``quantity``, ``real``,
    ``twin``, ``ratio``, ``verdict``, the inputs and the measurements behind them
    (``floor``: :func:`twin_forest`'s; the doc's ``floor``, ``sunlit_albedo`` and
    ``floor_why`` say what it was and why)."""
    from ..products import atl08
    from ..products.atl08 import read_atl03_beam
    tw = simulate_twin(atl03_path, atl08_path, beam, shots=shots, seed=seed,
                       out_path=out_path, floor=floor)
    spm = read_atl03_beam(atl03_path, beam)["shots_per_m"]
    spm_twin = read_atl03_beam(tw["atl03"], beam)["shots_per_m"]
    real_ours = atl08_counts(atl08.from_atl03(atl03_path, beam), spm)
    twin_ours = atl08_counts(tw["atl08"], spm_twin)
    nasa = nasa_counts(atl08_path, beam, spm)
    bg = {"real": background_hz(atl03_path, beam), "twin": background_hz(tw["atl03"], beam)}
    rows = []

    def row(quantity, real, twin_v, note, agrees=AGREES):
        r = _ratio(twin_v, real)
        rows.append({"quantity": quantity, "real": real, "twin": twin_v, "ratio": r,
                     "verdict": _verdict(r, agrees), "note": note})
    res = tw["result"]
    lw = _like_with_like(atl03_path, atl08_path, beam, res, bg["twin"])
    for name, lo, hi in LAYERS_M:
        row(f"signal photons per shot {lo:g} to {hi:g} m above the ground ({name}; all "
            f"photons less the background, no classifier)", lw["real"][name],
            lw["twin"][name], "real: above NASA's ground (h_ph - ph_h, joined); twin: above "
            f"its true ground; the twin's truth: {lw['twin_truth'][name]:.3f}")
    row("ground photons per shot (NASA's ATL08 on real; ours on twin)",
        nasa["ground_per_shot"], twin_ours["ground_per_shot"], "n_te_photons / shots")
    row("ground photons per shot (our ATL08 on both)", real_ours["ground_per_shot"],
        twin_ours["ground_per_shot"], "same classifier")
    row("canopy photons per shot (NASA's ATL08 on real; ours on twin)",
        nasa["canopy_per_shot"], twin_ours["canopy_per_shot"],
        "(n_ca + n_toc) / shots, background photons in the canopy included")
    row("canopy photons per shot (our ATL08 on both)", real_ours["canopy_per_shot"],
        twin_ours["canopy_per_shot"], "same classifier")
    row("background rate [MHz]", None if bg["real"] is None else bg["real"] / 1e6,
        None if bg["twin"] is None else bg["twin"] / 1e6,
        "bckgrd_atlas/bckgrd_rate median over the clip's rows (the twin's: the model's, the "
        "sun over the forest floor's albedo); agrees within the realism matrix's 0.5-2",
        agrees=BACKGROUND_AGREES)
    row("canopy height h_canopy [m] (our ATL08 on both)", real_ours["h_canopy_m"],
        twin_ours["h_canopy_m"], "NASA's h_canopy median is an input: "
        f"{tw['inputs']['h_canopy_m']:.2f} m")
    for k in range(len(HEIGHT_BINS_M) - 1):
        lo, hi = HEIGHT_BINS_M[k], HEIGHT_BINS_M[k + 1]
        row(f"photons per shot {lo:g} to {hi:g} m above the ground (our ATL08 on both)",
            real_ours["height_per_shot"][k], twin_ours["height_per_shot"][k],
            "NASA's ph_h on real: " + ("-" if nasa["height_per_shot"] is None
                                       else f"{nasa['height_per_shot'][k]:.3f}"))
    return {"atl03": pathlib.Path(atl03_path).name, "atl08": pathlib.Path(atl08_path).name,
            "beam": beam, "inputs": tw["inputs"], **_floor_doc(tw, floor), "stand": {
                "trees": tw["forest"].stand.n_trees, "lai": tw["forest"].stand.lai(),
                "cover": tw["forest"].stand.canopy_cover(),
                "mean_height_m": float(tw["forest"].stand.height_m.mean()),
                "representation": tw["forest"].representation},
            "shots": res.n_shots, "pulse_energy_uj": float(
                res.instrument.link_budget.pulse_energy_uj),
            "nasa": nasa, "ours_real": real_ours, "ours_twin": twin_ours,
            "twin_truth": _truth_counts(res), "background_hz": bg, "like_with_like": lw,
            "rows": rows}


def _like_with_like(atl03_path, atl08_path, beam: str, res, twin_rate_hz: float) -> dict:
    """:func:`layer_signal` of the real file above NASA's ground and of the twin's detections
    above its true ground (and the twin's true signal photons in the same layers)."""
    from ..constants import C_M_PER_NS
    real = nasa_ground_dh(atl03_path, atl08_path, beam)
    n = max(res.n_shots, 1)
    sig = res.detections.is_signal
    if real is None:                       # no NASA ground to stand the real photons on
        real = {"shots": None, "mapped": 0}
        layers = {name: None for name, _, _ in LAYERS_M}
    else:
        layers = layer_signal(real["dh_m"], shots=real["shots"],
                              background_per_m_shot=real["background_per_m_shot"])
    return {"real": layers,
            "twin": layer_signal(res.dh_m, shots=n, background_per_m_shot=twin_rate_hz * 2.0
                                 / (C_M_PER_NS * 1e9)),
            "twin_truth": layer_signal(res.dh_m[sig], shots=n, background_per_m_shot=0.0),
            "real_shots": real["shots"], "real_mapped": real["mapped"]}


def _floor_doc(tw: dict, floor: str) -> dict:
    """The floor a twin was given: ``floor``, ``sunlit_albedo`` (``None``: the floor's own)
    and ``floor_why`` (:func:`floor_of` for ``auto``; a floor asked for, as asked)."""
    f = tw["forest"]
    if floor == "auto":
        name, sunlit, why = floor_of(tw["inputs"])
        return {"floor": name, "sunlit_albedo": sunlit, "floor_why": why}
    return {"floor": floor, "sunlit_albedo": f.sunlit_albedo,
            "floor_why": f"{floor} floor (asked for)"}


def _f(v, spec=".3g") -> str:
    return "-" if v is None else format(v, spec)


def report_md(doc: dict) -> str:
    """The comparison as Markdown: inputs, stand, the table of rows with verdicts."""
    i, s = doc["inputs"], doc["stand"]
    lines = [f"## The forest twin: {doc['atl03']} {doc['beam']}", "",
             f"Inputs from the clip's ATL08 (not fitted): h_canopy {i['h_canopy_m']:.2f} m "
             f"(median), cover {100 * i['cover']:.0f} % (segment_cover), landcover "
             f"{i['landcover']}, DEM slope {i['slope']:+.3f} along track "
             f"({i.get('slope_from', 'dem_h')}); beam "
             f"{i['strength']} (sc_orient {i['sc_orient']}), {doc['pulse_energy_uj']:.1f} uJ; "
             f"forest floor: {doc.get('floor_why', doc.get('floor', 'litter'))}. "
             f"Stand: {s['trees']} conifers, mean height {s['mean_height_m']:.2f} m, LAI "
             f"{s['lai']:.2f}, cover {100 * s['cover']:.0f} %, representation "
             f"`{s['representation']}`; {doc['shots']} shots.", "",
             "| quantity | real | twin | twin / real | verdict | note |",
             "|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        lines.append(f"| {r['quantity']} | {_f(r['real'])} | {_f(r['twin'])} | "
                     f"{_f(r['ratio'], '.2f')} | **{r['verdict']}** | {r['note']} |")
    t = doc["twin_truth"]
    lines += ["", f"The twin's truth: {t['signal_per_shot']:.3f} signal photons per shot, "
              f"{t['ground_band_per_shot']:.3f} within 1 m of the ground, "
              f"{t['above_band_per_shot']:.3f} above it.", ""]
    return "\n".join(lines)


def twins(paths, *, shots: int | None = None, seed: int = 1, progress=print) -> list[dict]:
    """:func:`compare` on every ATL03/ATL08 pair among ``paths`` whose ATL08 says forest
    (a canopy height on some segment), each beam both files have (the realism matrix's
    forest rows take theirs from these: :mod:`~lidar_mitsuba.studies.realism_forest`)."""
    import h5py
    from ..products.atl08 import atl03_lacks
    from .atl08_real import pairs
    out = []
    for a03, a08 in pairs(paths):
        with h5py.File(a08) as f8, h5py.File(a03) as f3:
            beams = [b for b in f8 if b.startswith("gt") and f"{b}/heights/h_ph" in f3
                     and f"{b}/land_segments/canopy/h_canopy" in f8]    # a clip's empty beams
            lacks = {b: _stand_lacks(f8[f"{b}/land_segments"])   # (the ATL03's background
                     + [f"ATL03 {n}" for n in atl03_lacks(f3[b])]  # may be missing)
                     for b in beams}
        for beam in beams:
            if lacks[beam]:
                if progress is not None and lacks[beam] != ["a canopy height"]:
                    progress(f"forest twin of {pathlib.Path(a03).name} {beam}: none, the "
                             f"pair gives no {', '.join(lacks[beam])}")
                continue
            if progress is not None:
                progress(f"forest twin of {pathlib.Path(a03).name} {beam}")
            try:
                out.append(compare(a03, a08, beam, shots=shots, seed=seed))
            except UNREADABLE as e:      # fill where a time, place or index should be
                if progress is not None:
                    progress(f"forest twin of {pathlib.Path(a03).name} {beam}: none, the "
                             f"pair cannot be read ({type(e).__name__}: {e})")
    return out


UNREADABLE = (ValueError, OverflowError, IndexError)
"""What fill values where a time, a place or an index should be raise in the twin's and the
comparison's arithmetic (a ParameterError, naming what is wrong, is a ValueError): a beam
that raises one is passed by, said, as one lacking what they read (session 28's fuzz: a
``ph_index_beg`` or ``segment_dist_x`` at fill)."""


def _stand_lacks(ls) -> list[str]:
    """What a beam's ``land_segments`` lacks of the stand's inputs (:func:`site_inputs`):
    a canopy height and a cover on some segment (not fill), and the segments' places."""
    out = []
    for name, what, ok in (("canopy/h_canopy", "a canopy height", lambda v: v < F4_FILL),
                           ("canopy/segment_cover", "canopy cover (segment_cover)",
                            lambda v: (v >= 0) & (v <= 100)),
                           ("latitude", "latitude", lambda v: np.abs(v) <= 90),
                           ("longitude", "longitude", lambda v: np.abs(v) <= 360)):
        if name not in ls or not np.any(ok(ls[name][()].astype(float))):
            out.append(what)
    return out


def write(docs: list[dict], out_dir) -> None:
    """``forest_twin.md`` and ``forest_twin.json`` of :func:`twins`' ``docs`` in ``out_dir``
    (nothing without a doc)."""
    import json
    if not docs:
        return
    d = pathlib.Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    (d / "forest_twin.json").write_text(json.dumps(docs, indent=1, default=float))
    (d / "forest_twin.md").write_text("# The forest twin\n\n" + "\n".join(
        report_md(r) for r in docs))


def run(paths, out_dir=None, *, shots: int | None = None, seed: int = 1,
        progress=print) -> list[dict]:
    """:func:`twins` of ``paths``, written by :func:`write` to ``out_dir`` when given."""
    out = twins(paths, shots=shots, seed=seed, progress=progress)
    if out_dir is not None:
        write(out, out_dir)
    return out


def main() -> None:
    doc = compare()
    print(report_md(doc))


if __name__ == "__main__":
    main()
