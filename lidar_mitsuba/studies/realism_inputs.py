"""What the realism matrix (:mod:`lidar_mitsuba.studies.realism`) gives the model of a real
file besides its shots, sun and energy: the surface a user would choose knowing only the
product (its albedo, and for snow the pack whose volume return comes back late:
:mod:`lidar_mitsuba.ground.snow.delay`), and the cloud the file's own flags imply for its
cloudy segments (the optical depth from its apparent surface reflectance, the height from
ATL09's ``msw_flag``). Inputs read or chosen before any comparison; nothing here is fitted.
"""
from __future__ import annotations

import pathlib

import numpy as np

def sea_ice_snow():
    """The snow on sea ice: the floe's pack of :mod:`lidar_mitsuba.studies.sea_ice` (a 5 cm
    wind slab of 130 um grains at 350 kg/m^3 over depth hoar of 330 um at 250 kg/m^3, 18 cm
    deep; each value with its source there), as one half-space of the layers'
    depth-averaged optics (:func:`~lidar_mitsuba.ground.snow.delay.averaged_pack`)."""
    from ..ground.snow import delay
    from .sea_ice import floe_snow
    return delay.averaged_pack(floe_snow())


def ice_sheet_snow():
    """The snow on an ice sheet: wind-packed surface snow as the floe's slab (130 um, 350
    kg/m^3: Sturm et al. 2002, Macfarlane et al. 2023, via
    :data:`~lidar_mitsuba.studies.sea_ice.FLOE`), a half-space (ESTIMATE: dry firn below it,
    seasonally and regionally varying; the grain sizes of Greenland's surface snow, 50-300
    um, bracket it)."""
    from ..ground import snow
    from .sea_ice import FLOE
    slab = FLOE["slab"]
    return snow.snow_from_grains(grain_radius_um=slab["grain_radius_um"],
                                 density_kg_m3=slab["density_kg_m3"])


PRODUCT_SURFACES = {
    "land ice": {"name": "ice-sheet snow (flat, Ward snow, wind-packed snow's delay)",
                 "albedo": 0.9, "water": None, "snow": ice_sheet_snow},
    "sea ice": {"name": "snow-covered sea ice (flat, Ward snow, the floe's snow's delay)",
                "albedo": 0.9, "water": None, "snow": sea_ice_snow, "ice_concentration": True},
    "ocean": {"name": "open water (water BSDF, 5 m/s wind)", "albedo": 0.06, "water": 5.0},
    "inland water": {"name": "open water (water BSDF, 5 m/s wind)", "albedo": 0.06,
                     "water": 5.0},
    "land": {"name": "land: a flat plate of albedo 0.1 (no forest twin)", "albedo": 0.1,
             "water": None, "missing": True},
}
"""The surface a user would choose knowing only the product (ATL06: land ice, ATL07: sea
ice, ATL08: land, ATL03: its ``surf_type``) and its Lambertian albedo for sunlight: snow 0.9
(the reference plate), open water 0.06 (Payne 1972, J. Atmos. Sci. 29, 959: the sea's
albedo at moderate sun) at an ESTIMATE 5 m/s wind, land 0.1 (ESTIMATE: conifer canopy in the
green; a flat plate: a land row's surface is its forest twin where the file's ATL03 + ATL08
pair has one, :mod:`~lidar_mitsuba.studies.realism_forest`, and missing otherwise). Snow surfaces also delay the share of their return that
their volume scatters back (``snow``: the pack, :mod:`lidar_mitsuba.ground.snow.delay`).
Sea ice is flat here; :func:`product_surface` gives it the relief its site's ice has."""


def product_surface(rb) -> dict:
    """The surface of a real beam ``rb``'s row: its product's (:data:`PRODUCT_SURFACES`), and
    for sea ice the relief the twin of ice at the beam's median latitude gets
    (:func:`~lidar_mitsuba.twin.sea_ice_surface`, ``validate``'s too: the central Arctic
    pack's published Fram Strait roughness with ridge sails under the same Ward snow and
    snow delay; flat elsewhere, no first-year preset existing) as ``relief`` (a
    :class:`~lidar_mitsuba.ground.surface.SurfaceSpec`, None for flat) with its reason
    ``relief_why``."""
    surface = PRODUCT_SURFACES.get(rb.surface, PRODUCT_SURFACES["land"])
    if surface is not PRODUCT_SURFACES["sea ice"]:
        return surface
    from ..twin import sea_ice_surface
    lat = _median(getattr(rb, "lat_deg", None))
    spec, why = sea_ice_surface(lat_deg=float("nan") if lat is None else lat)
    if spec is None:
        return {**surface, "relief": None, "relief_why": why}
    ridges = "" if spec.surface_ridges == "none" else f", ridge sails {spec.surface_ridges}"
    name = (f"snow-covered sea ice (rough: {100 * spec.surface_rms_m:.0f} cm rms, "
            f"{spec.surface_corr_m:g} m correlation length{ridges}, as validate's twin; "
            "Ward snow, the floe's snow's delay)")
    return {**surface, "name": name, "relief": spec, "relief_why": why}


def sunlit_albedo(rb, surface: dict) -> float:
    """The albedo the sun sees around a beam: the product surface's, or on sea ice with the
    file's ice concentration ``c`` (ATL07 ``ice_conc``) the area mean ``c A_ice + (1 - c)
    A_water`` with open water's 0.06 (:data:`PRODUCT_SURFACES`' ``ocean``; the sky's light
    is reflected over kilometres, the concentration's passive-microwave cells are 25 km)."""
    c = getattr(rb, "ice_fraction", None)
    if not surface.get("ice_concentration") or c is None:
        return float(surface["albedo"])
    c = _median(c)
    if c is None:
        return float(surface["albedo"])
    c = min(max(c, 0.0), 1.0)
    return c * surface["albedo"] + (1.0 - c) * PRODUCT_SURFACES["ocean"]["albedo"]


def snow_delay(surface: dict):
    """``(pack, share)``: the surface's snow (a half-space) and the share of its nadir return
    the volume carries (the flat Ward surface's diffuse lobe), or ``(None, 0)``."""
    if surface.get("snow") is None:
        return None, 0.0
    from ..ground.snow import delay
    from ..ground.surface import SurfaceSpec
    w = SurfaceSpec(kind="flat")
    return surface["snow"](), delay.volume_share(rho_d=w.rho_d, rho_s=w.rho_s, alpha=w.alpha)


LAYER_BASE_M = {3: 500.0, 2: 2000.0, 1: 4000.0}
"""The base [m above the surface] of the cloud a file implies, from ATL09's ``msw_flag`` that
ATL06 and ATL07 copy (its description in the files: the lowest layer's base below 1 km: 3,
1-3 km: 2, above 3 km: 1): the middle of each class, 4 km for the open one (ESTIMATE; the
flag's heights taken above the surface)."""
LAYER_THICKNESS_M = 1000.0
"""The implied cloud's thickness [m] (ESTIMATE: no product here carries the layer's top; a
kilometre is the order of Arctic stratus and of the polar cirrus the flag's upper classes
hold)."""
BLOWING_SNOW_TOP_M = 100.0
"""The top [m] of a blowing-snow layer (``msw_flag`` 4-5) where the file gives no ``bsnow_h``
(ESTIMATE: ATL09's blowing snow lies in the lowest few hundred metres)."""


def implied_cloud(rb, *, reflectance=None, segments=None):
    """The cloud a real beam's own cloudy segments imply, or None. Its optical depth: the
    median ``tau = -ln(r / r_clear) / 2`` of the cloudy segments' apparent reflectance ``r``
    (``reflectance``: one of the beam's, default its first, ``rb.reflectance``; ``segments``:
    a mask of the segments to take, default all)
    (:func:`~lidar_mitsuba.products.cloud_flags.implied_optical_depth`: the two-way
    attenuation of the surface's return, a slight underestimate where forward-scattered light
    comes back too), ``r_clear`` the median of the beam's clear segments' (its own
    calibration) or snow's 0.9 (:data:`~lidar_mitsuba.products.real.SNOW_REFLECTANCE`) where
    it has none. Its height: the most frequent ``msw_flag`` class of those segments
    (:data:`LAYER_BASE_M`, :data:`LAYER_THICKNESS_M`; blowing snow from the ground to
    :data:`BLOWING_SNOW_TOP_M`); without the flag, a low cloud (class 3: Arctic low cloud is
    the most frequent, Shupe et al. 2011, J. Appl. Meteor. Climatol. 50, 626, recalled).
    A liquid-water layer (its lidar ratio; ESTIMATE for the higher classes, often ice)."""
    from ..atmosphere.cloud_layer import MAX_OPTICAL_DEPTH, Cloud
    from ..products.cloud_flags import implied_optical_depth
    from ..products.real import SNOW_REFLECTANCE
    r, clear = rb.reflectance if reflectance is None else reflectance, rb.clear
    if r is None or clear is None or clear.all():
        return None
    r_clear = _median(r[clear]) if clear.any() else None
    cloudy = ~clear if segments is None else ~clear & np.asarray(segments, bool)
    tau = _median(implied_optical_depth(r[cloudy], r_clear or SNOW_REFLECTANCE))
    if tau is None or not tau > 0:
        return None
    base, top = layer_heights_m(None if rb.layer_class is None else rb.layer_class[cloudy])
    return Cloud.water(round(min(tau, MAX_OPTICAL_DEPTH), 3), base, top)


def pair_clouds(beams) -> dict:
    """Each beam's implied cloud (:func:`implied_cloud`) by name, a weak beam taking its pair's
    strong beam's where that has one: the two beams of a pair are 90 m apart across the track
    and see one cloud, and ATL09, whose ``msw_flag`` and apparent reflectance ATL06 and ATL07
    copy (their attributes: "from the backscatter profile using the DDA layer finder", source
    "Atmosphere ATBD"), profiles the atmosphere with the strong beams only ("NRB profiles are
    generated from the strong beam only of each beam pair", NSIDC's ICESat-2 Level-2 product
    page), so a weak beam's flags are its partner's, resampled
    at fewer, longer segments. ESTIMATE that they are the better of the two. Without this a
    pair's beams got clouds of different heights (Baffin night gt3l below 1 km, gt3r at
    1-3 km) and the night's strong:weak ratio of the model 6.9 against 3.9 for the other
    pair."""
    own = {rb.name: implied_cloud(rb) for rb in beams}
    return {name: own[flags.name] if own[name] is not None else None
            for name, flags in pair_flags(beams, clouds=own).items()}


def pair_flags(beams, *, clouds: dict | None = None) -> dict:
    """Each beam's name to the beam whose ATL09 flags give its cloud (:func:`pair_clouds`): its
    pair's strong beam for a weak beam where that has a cloud, itself otherwise (``clouds``:
    each beam's :func:`implied_cloud` by name, where the caller has them)."""
    by = {rb.name: rb for rb in beams}
    if clouds is None:
        clouds = {name: implied_cloud(rb) for name, rb in by.items()}
    out = {}
    for name, rb in by.items():
        partner = by.get(name[:3] + ("r" if name[3] == "l" else "l"))
        out[name] = partner if (rb.strength == "weak" and partner is not None
                                and partner.strength == "strong"
                                and clouds[partner.name] is not None) else rb
    return out


REFLECTANCES = {
    "ATL06": ("r_eff", "ATL06's, from its fitted photons", True),
    "ATL07": ("asr_25", "ATL09's, from the strong beam's 25 Hz profile", False),
}
"""Each product's first apparent reflectance (``RealBeam.reflectance``): its dataset, where it
comes from, and whether it is made from the photons whose rate is the signal (then a signal
predicted with its cloud is circular). The descriptions are the files' own attributes and the
products' documentation: ATL06 ``r_eff`` "Effective reflectance, uncorrected for atmospheric
effects", source its ATBD's section 3.1.5.4 (the segment's signal photons per pulse against a
unit reflector's: recalled, not re-read); ATL07 ``asr_25`` "Apparent surface reflectance at 25 hz, averaged to the sea ice
segment", source "Sea Ice ATBD", ATL09's ASR from the atmospheric profiles, which ATLAS makes
for the strong beams only (NSIDC's ICESat-2 Level-2 product page: 400-shot sums, ~30 m bins,
13.75 km above the DEM to 0.25 km below it, the ground included)."""
PHOTON_REFLECTANCE = ("height_segment_asr_calc", "ATL07's, from photon_rate", True)
"""ATL07's second reflectance (``RealBeam.reflectance_photons``), "Computed apparent surface
reflectance for the sea ice segment": in the real files ``photon_rate / asr_calc`` is one
constant a beam (sd/mean 0.2-5 %), so it is the photon rate rescaled."""
LAYER_COUNT = {"ATL06": "cloud_flg_atm", "ATL07": "cloud_flag_atm"}
"""The dataset that counts ATL09's layers (the files: "Number of layers found from the
backscatter profile using the DDA layer finder")."""


def layer_count(rb) -> int | None:
    """The most frequent number of layers ATL09 found over the beam's cloudy segments, or
    None without the flag."""
    n = getattr(rb, "layer_count", None)
    if n is None or rb.clear is None:
        return None
    n = np.asarray(n, np.float64)[~np.asarray(rb.clear, bool)]
    n = n[np.isfinite(n) & (n >= 0)].astype(int)
    return int(np.bincount(n).argmax()) if n.size else None


def cloud_alternatives(rb, cloud, *, product: str, band_top_m: float,
                       flags=None) -> list[dict]:
    """Every cloud the file's inputs allow for a beam's cloudy segments, the matrix's own
    ``cloud`` (:func:`pair_clouds`) first: the same layer with the optical depth each other
    reflectance of the beam implies (:data:`PHOTON_REFLECTANCE`, the same rule, its own
    clear segments or snow's 0.9), and, where ATL09 found several layers
    (:func:`layer_count` of ``flags``, the beam whose flags gave ``cloud``: :func:`pair_flags`;
    default ``rb``, >= 2) and the lowest, the one ``msw_flag`` places, lies below the band's
    top ``band_top_m`` [m above the surface], each of those depths as one layer above the
    band: the file does not say how the depth splits between its layers, and only the part
    inside the band adds backscatter to the background (the other limit, all of it in the
    lowest layer, is the matrix's own); the others only where every segment is cloudy (a
    beam with clear segments is judged on those). Each: ``{"dataset", "from", "circular",
    "above_band", "cloud", "signal_cloud"}``, ``signal_cloud`` the same layer with the depth
    that reflectance implies on the beam's own segments that measure the signal
    (:func:`signal_segments`; the signal is a median over those, the background over all)."""
    import dataclasses
    if cloud is None:
        return []
    name, where, circular = REFLECTANCES.get(product, ("reflectance", "the product's", False))
    out = [{"dataset": name, "from": where, "circular": circular, "above_band": False,
            "cloud": cloud, "signal_cloud": _on_signal_segments(rb, cloud, rb.reflectance)}]
    if rb.clear is None or np.any(rb.clear):
        return out          # a beam with clear segments is judged on them: its cloud alone
    other = getattr(rb, "reflectance_photons", None)
    c = None if other is None else implied_cloud(rb, reflectance=other)
    if c is not None:
        name, where, circular = PHOTON_REFLECTANCE
        own = dataclasses.replace(cloud, optical_depth=c.optical_depth)
        out.append({"dataset": name, "from": where, "circular": circular, "above_band": False,
                    "cloud": own, "signal_cloud": _on_signal_segments(rb, own, other)})
    n = layer_count(rb if flags is None else flags)
    unknown = height_unknown(rb if flags is None else flags)
    if (unknown or (n is not None and n >= 2)) and cloud.base_m < band_top_m:
        out += [{**a, "above_band": True, "height_unknown": unknown,
                 "cloud": dataclasses.replace(a["cloud"], base_m=band_top_m,
                                              top_m=band_top_m + LAYER_THICKNESS_M)}
                for a in list(out)]
    return out


def height_unknown(rb) -> bool:
    """Whether the file places no layer over the beam's cloudy segments (no ``msw_flag``, or
    none of 1-5 there: a subset that dropped it, or fill): the implied cloud then takes
    :func:`layer_heights_m`'s default, inside the band, and :func:`cloud_alternatives` runs
    it above the band too."""
    k = getattr(rb, "layer_class", None)
    if k is None or rb.clear is None:
        return k is None
    k = np.asarray(k, np.float64)[~np.asarray(rb.clear, bool)]
    return not np.any(np.isfinite(k) & (k >= 1) & (k <= 5))


def signal_segments(rb) -> np.ndarray | None:
    """The segments where the product measured a signal (a finite ``signal_per_shot``: ATL07's
    snow-covered ice with a ``photon_rate``, ATL06's quality-0 fits), or None."""
    s = rb.signal_per_shot
    return None if s is None else np.isfinite(np.asarray(s, np.float64))


def _on_signal_segments(rb, cloud, reflectance):
    """``cloud`` with the optical depth ``reflectance`` implies on the beam's cloudy segments
    that measure the signal (:func:`signal_segments`), or ``cloud`` itself where none has it."""
    import dataclasses
    seg = signal_segments(rb)
    c = None if seg is None or reflectance is None else implied_cloud(
        rb, reflectance=reflectance, segments=seg)
    return cloud if c is None else dataclasses.replace(cloud, optical_depth=c.optical_depth)


def layer_heights_m(layer_class) -> tuple[float, float]:
    """``(base, top)`` [m above the surface] of the implied layer from the ``msw_flag`` values
    of the cloudy segments (their most frequent class among 1-5; class 3 without any)."""
    k = np.asarray([] if layer_class is None else layer_class, np.float64)
    k = k[np.isfinite(k) & (k >= 1) & (k <= 5)].astype(int)
    mode = int(np.bincount(k).argmax()) if k.size else 3
    if mode >= 4:
        return 0.0, BLOWING_SNOW_TOP_M
    base = LAYER_BASE_M[mode]
    return base, base + LAYER_THICKNESS_M


def equation_outside_fraction(inst, span_m, *, surface: dict):
    """Without a simulation, the share of the surface photons outside the removed span(s)
    ``span_m`` [m]: the Gaussian pulse's (:func:`~lidar_mitsuba.night.gaussian_outside_fraction`)
    and the snow's volume return below half the span, as independent
    (``1 - (1 - f_pulse) (1 - share SF(w / 2))``; the pulse's width, 0.1 m, is small beside
    the snow's tail)."""
    from .. import night
    from ..constants import C_M_PER_NS
    f = night.gaussian_outside_fraction(span_m, C_M_PER_NS * inst.pulse_sigma_ns / 2.0)
    pack, share = snow_delay(surface)
    if pack is None:
        return f
    from ..ground.snow import delay
    return 1.0 - (1.0 - f) * (1.0 - share * delay.apparent_depth_sf(
        pack, np.asarray(span_m, np.float64) / 2.0))




def _median(a) -> float | None:
    a = np.asarray(a, np.float64)
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else None


def read_files(paths, *, twins: bool, skippable=()) -> tuple[list[tuple], list[tuple]]:
    """``([(RealFile, TwinGranule or None), ...], [(path, why), ...])``: every file read before
    any run (:func:`~lidar_mitsuba.products.real.read_product`; with ``twins`` its shots,
    :func:`~lidar_mitsuba.twin.read`), and the files passed by. A file that cannot be used
    stops it in one line naming the file (``ParameterError``, ``real``), unless it is among
    ``skippable`` (found in a folder the user named, not named itself: an ATL10 or a cut
    beside the files it can read), which is passed by with its reason; when every file is
    passed by, that stops it too."""
    from .. import twin
    from ..constants import ParameterError
    from ..products.real import read_product
    out, skipped = [], []
    skippable = {pathlib.Path(p) for p in skippable}
    for path in paths:
        try:
            out.append((read_product(path), twin.read(path) if twins else None))
        except ParameterError as e:
            if pathlib.Path(path) not in skippable:
                raise ParameterError("real", e.message) from None
            skipped.append((pathlib.Path(path), e.message))
    if not out:
        raise ParameterError("real", "no usable file: " + "; ".join(why for _, why in skipped))
    return out, skipped


def ratio_words(bg: float | None, bg_measured, sig: float | None, sig_measured) -> str:
    """A row's reason for its background and signal ratios (predicted / measured), each
    saying why it is not compared where it is not: the file gives no rate, or a rate of 0."""
    def words(name: str, ratio, measured) -> str:
        if ratio is not None:
            return f"{name} x{ratio:.2f}"
        if measured is None:
            return f"{name} not measured (the file gives no {name} rate here)"
        return f"{name} not compared (measured {measured:.3g})"
    return words("background", bg, bg_measured) + ", " + words("signal", sig, sig_measured)
