"""ATL09-style cloud flags as ATL06 and ATL07 carry them: the apparent surface reflectance
and the flags derived from it. Pure numpy (h5py only to write).

**Apparent surface reflectance** (ATL06 ``geophysical/r_eff``, "effective reflectance,
uncorrected for atmospheric effects"; ATL07 ``stats/asr_25``; ATL09 ``asr``): the signal
photons per shot over those a Lambertian surface of reflectance 1 would return in clear air
to the same instrument at the same range (Yang et al. 2013, IEEE TGRS 51, 1037: ASR =
surface reflectance times the two-way transmission of the air and clouds above it)::

    asr = n_signal / (n_shots * N1),   N1 = signal_photons * signal_scale * ff * PDE / 0.9

``signal_photons`` is the instrument's photons per shot from a Lambertian 0.9 plate at nadir
(hence the 0.9), ``signal_scale`` the link budget's range and clear-air factor, ``ff * PDE``
the detection-eligible fraction. ATL06's segments count signal as ``fpb_n_corr`` (dead time
and background corrected), ATL07's as the segment's photon rate. A clear Lambertian surface
of albedo rho gives ``asr = rho``; under a cloud ``rho (exp(-2 tau) + F)`` (F its
forward-scattered light in the field of view, :mod:`lidar_mitsuba.atmosphere.cloud_kernel`).

**cloud_flg_asr** (ATL06; ATL07 ``cloud_flag_asr``), 0-5: clear with high, medium, low
confidence, cloudy with low, medium, high confidence, from the ratio of ``asr`` to the
reflectance the surface has in clear air (ATL06's attribute: "assuming a white snow
surface"; here the run's own surface albedo for sunlight when a link budget gives it, else
0.9). The class edges :data:`ASR_RATIO_EDGES` are an ESTIMATE (the ATL09 ATBD's tables were
not at hand): ratio >= 0.9 is clear with high confidence (a two-way transmission above 0.9,
tau < 0.05), each step down one class, < 0.3 cloudy with high confidence (tau > 0.6).

**cloud_flg_atm** (ATL06, 0/1; ATL07 ``cloud_flag_atm``, the number of layers): the layers
ATL09's layer finder would report. The atmospheric profile (ATL04/ATL09) is not simulated,
so this is the run's own cloud: one layer where a cloud was given, else 0.
"""
from __future__ import annotations

import numpy as np

from ..constants import REFERENCE_ALBEDO

ASR_RATIO_EDGES = (0.9, 0.8, 0.7, 0.5, 0.3)
"""asr / clear-sky reflectance at or above ``edges[k]`` gives flag ``k`` (below all: 5).
ESTIMATE (see the module)."""
FLAG_MEANINGS_ASR = ("clear_with_high_confidence clear_with_medium_confidence "
                     "clear_with_low_confidence cloudy_with_low_confidence "
                     "cloudy_with_medium_confidence cloudy_with_high_confidence")
INT8_FILL = np.int8(127)
FLOAT_FILL = np.finfo(np.float32).max


def sky_of(result) -> dict:
    """What the flags need from a :class:`~lidar_mitsuba.run.SimulationResult`: ``unit_photons``
    (N1, detection-eligible photons per shot from a Lambertian reflectance-1 surface in clear
    air), ``expected_reflectance`` (the surface's clear-sky reflectance) and ``layers`` (the
    run's cloud layers)."""
    inst = result.instrument
    rad = getattr(result, "radiometry", None)
    scale = 1.0 if rad is None else float(np.median(rad.signal_scale))
    cloud = (result.config or {}).get("cloud")
    return {"unit_photons": float(inst.signal_photons * scale * inst.fill_factor * inst.pde
                                  / REFERENCE_ALBEDO),
            "expected_reflectance": REFERENCE_ALBEDO if rad is None else float(rad.albedo),
            "layers": 0 if cloud is None else 1}


def apparent_reflectance(signal_per_shot, unit_photons: float) -> np.ndarray:
    """asr = signal photons per shot / N1 (NaN where the count is not finite)."""
    s = np.asarray(signal_per_shot, np.float64)
    return s / float(unit_photons) if unit_photons > 0 else np.full(s.shape, np.nan)


def asr_flag(asr, expected_reflectance: float) -> np.ndarray:
    """cloud_flg_asr, 0-5 (int8; 127 where asr is not finite), from asr / the clear-sky
    reflectance against :data:`ASR_RATIO_EDGES`."""
    a = np.asarray(asr, np.float64)
    ratio = a / float(expected_reflectance)
    flag = np.full(a.shape, 5, np.int8)
    for k, edge in reversed(list(enumerate(ASR_RATIO_EDGES))):
        flag[ratio >= edge] = k
    flag[~np.isfinite(a)] = INT8_FILL
    return flag


def implied_optical_depth(asr, clear_reflectance: float) -> np.ndarray:
    """The cloud optical depth a measured ``asr`` implies over a surface of clear-sky
    reflectance ``clear_reflectance``, attenuation only: ``tau = -ln(asr / R) / 2`` (0 where
    asr >= R; NaN where not finite). The forward-scattered light a cloud adds (F, a few % of
    the ground's under a cloud 1 km up: :mod:`lidar_mitsuba.atmosphere.cloud_kernel`) makes
    this a slight underestimate. For giving a real granule's twin its cloud
    (``simulate(cloud=...)``) from the file's own ``r_eff`` or ``asr_25``."""
    a = np.asarray(asr, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = -0.5 * np.log(a / float(clear_reflectance))
    return np.where(np.isfinite(tau), np.maximum(tau, 0.0), np.nan)


def atl06_columns(table, sky: dict) -> dict:
    """ATL06's ``geophysical`` cloud columns of a segment table
    (:class:`~lidar_mitsuba.products.atl06.SegmentTable`): ``r_eff`` from ``fpb_n_corr /
    n_seg_pulses``, ``cloud_flg_asr``, ``cloud_flg_atm``."""
    n = np.asarray(table.n_seg_pulses, np.float64)
    count = np.asarray(table.fpb_n_corr, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = apparent_reflectance(np.where(n > 0, count / n, np.nan), sky["unit_photons"])
    return {"r_eff": r, "cloud_flg_asr": asr_flag(r, sky["expected_reflectance"]),
            "cloud_flg_atm": np.full(r.shape, min(sky["layers"], 1), np.int8)}


def atl07_columns(seg, sky: dict) -> dict:
    """ATL07's ``stats`` cloud columns of sea-ice segments
    (:class:`~lidar_mitsuba.products.atl07.Segments`): ``asr_25`` from the segment's photon
    rate, ``cloud_flag_asr`` (int16, ATL07's type), ``cloud_flag_atm`` (layers)."""
    r = apparent_reflectance(seg.photon_rate, sky["unit_photons"])
    flag = asr_flag(r, sky["expected_reflectance"]).astype(np.int16)
    flag[flag == INT8_FILL] = 6                                     # ATL07's "unknown"
    return {"asr_25": r, "cloud_flag_asr": flag,
            "cloud_flag_atm": np.full(r.shape, sky["layers"], np.int8)}


def _write(group, specs: dict, common: dict) -> None:
    """Create or append (a granule's sections) each ``name: (data, attrs)`` of ``specs``."""
    from . import h5write
    for name, (data, attrs) in specs.items():
        attrs = {**common, **attrs}
        fill = attrs.get("_FillValue")
        ds = h5write.put(group, name, data, attrs.pop("units"), attrs.pop("description"),
                         append=True, fillvalue=None if fill is None else np.ravel(fill)[0])
        h5write.set_attrs(ds, attrs)


def put_atl06(geophysical, cols: dict) -> None:
    """Append ``cols`` (:func:`atl06_columns`) to an ATL06 ``land_ice_segments/geophysical``
    group with ATL06's names, types and attributes (a granule's sections append)."""
    _write(geophysical, *_atl06_specs(cols))


def atl06_datasets(cols: dict, prefix: str = "geophysical/") -> list:
    """:func:`put_atl06`'s datasets as ``(prefix + name, data, units, description, attrs,
    fill value)`` (the columns of :func:`lidar_mitsuba.products.h5template.put_group`)."""
    specs, common = _atl06_specs(cols)
    out = []
    for name, (data, attrs) in specs.items():
        attrs = {**common, **attrs}
        units, desc = attrs.pop("units"), attrs.pop("description")
        fill = attrs.get("_FillValue")
        out.append((prefix + name, data, units, desc, attrs,
                    None if fill is None else np.ravel(fill)[0]))
    return out


def _atl06_specs(cols: dict) -> tuple[dict, dict]:
    """``({name: (data, attrs)}, attributes common to all)`` of ATL06's cloud columns."""
    common = {"contentType": "referenceInformation", "source": "ATL09 (lidar_mitsuba: "
              "products.cloud_flags)", "coordinates": "../delta_time ../latitude ../longitude"}
    r = np.where(np.isfinite(cols["r_eff"]), cols["r_eff"], FLOAT_FILL).astype(np.float32)
    specs = {
        "r_eff": (r, {"units": "1", "long_name": "Effective uncorrected reflectance",
                      "description": "Effective reflectance, uncorrected for atmospheric "
                      "effects: signal photons per pulse over those of a Lambertian "
                      "reflectance-1 surface in clear air", "_FillValue": FLOAT_FILL}),
        "cloud_flg_asr": (cols["cloud_flg_asr"].astype(np.int8), {
            "units": "1", "long_name": "cloud flag confidence", "description":
            "Indicates cloud attenuation as calculated from the apparent surface reflectance",
            "flag_meanings": FLAG_MEANINGS_ASR, "flag_values": np.arange(6, dtype=np.int8),
            "valid_min": np.int8(0), "valid_max": np.int8(5), "_FillValue": INT8_FILL}),
        "cloud_flg_atm": (cols["cloud_flg_atm"].astype(np.int8), {
            "units": "1", "long_name": "Cloud flag", "description": "Indicates the "
            "probability of clouds based on backscatter measurements (simulated: the run's "
            "own cloud)", "flag_meanings": "no yes", "flag_values": np.arange(2, dtype=np.int8),
            "valid_min": np.int8(0), "valid_max": np.int8(1), "_FillValue": INT8_FILL}),
    }
    return specs, common


def put_atl07(stats, cols: dict) -> None:
    """Write ``cols`` (:func:`atl07_columns`) to an ATL07 ``sea_ice_segments/stats`` group
    with ATL07's names, types and attributes."""
    common = {"coordinates": "../delta_time ../latitude ../longitude",
              "source": "Atmosphere ATBD (lidar_mitsuba: products.cloud_flags)"}
    asr = np.where(np.isfinite(cols["asr_25"]), cols["asr_25"], FLOAT_FILL).astype(np.float32)
    specs = {
        "asr_25": (asr, {"contentType": "referenceInformation", "units": "1",
                         "long_name": "Apparent Surface Reflectance 25hz",
                         "description": "Apparent surface reflectance, averaged to the sea "
                         "ice segment.", "_FillValue": np.array([FLOAT_FILL], np.float32)}),
        "cloud_flag_asr": (cols["cloud_flag_asr"].astype(np.int16), {
            "contentType": "modelResult", "units": "1", "long_name": "Cloud Flag ASR",
            "description": "Cloud flag (probability) from apparent surface reflectance. "
            "0=clear with high confidence; 1=clear with medium confidence; 2=clear with low "
            "confidence; 3=cloudy with low confidence; 4=cloudy with medium confidence; "
            "5=cloudy with high confidence; 6=unknown",
            "flag_meanings": FLAG_MEANINGS_ASR + " unknown",
            "flag_values": np.arange(7, dtype=np.int16), "valid_min": np.int16(0),
            "valid_max": np.int16(6)}),
        "cloud_flag_atm": (cols["cloud_flag_atm"].astype(np.int8), {
            "contentType": "modelResult", "units": "1", "long_name": "Cloud Flag Atm",
            "description": "Number of layers found from the backscatter profile (simulated: "
            "the run's own cloud layers)", "valid_min": np.int8(0), "valid_max": np.int8(10)}),
    }
    _write(stats, specs, common)
