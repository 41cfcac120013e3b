"""The ATL03 datasets of one beam group, as real granules carry them: name, dtype, trailing
shape, units, long name and ``_FillValue`` as in ATL03 version 006 (checked against the real
subset ``lidar_mitsuba/data/ATL03_gt1l_20181014.h5``), with our own description of what the simulation
writes there.

A field the simulation does not model is written with a constant (``Field.const``): ATL03's
documented fill value where nothing sensible can be said (the transmit pulse widths: their
thresholds are the start-pulse detector's voltages, unpublished), or zero where zero is what
the simulated photons need (no tides, no atmospheric delay, no geolocation error: the heights
are exact in the scene's frame). Such a dataset carries a ``model_note`` attribute saying so.
The writer is :mod:`lidar_mitsuba.products.atl03.beam`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

F4_FILL = np.finfo(np.float32).max      #: ATL03's float32 _FillValue (3.4028235e+38)
F8_FILL = np.finfo(np.float64).max      #: ATL03's float64 _FillValue
SURFACE_TYPES = ("land", "ocean", "sea_ice", "land_ice", "inlandwater")
"""ATL03's surface types, in the order of ``signal_conf_ph`` and ``surf_type`` columns, and the
groups of ``signal_find_output``."""


@dataclass(frozen=True)
class Field:
    """One ATL03 dataset.

    Attributes:
        dtype: numpy dtype string (``"f4"``, ``"u1"``, ...).
        units, long_name: as in ATL03.
        description: what the simulation writes.
        fill: ATL03's ``_FillValue`` (``None``: it has none).
        shape: trailing shape (``(5,)`` for one column per surface type).
        const: the value written when the writer computes none (a field not modelled), with
            ``model_note`` saying why; ``None``: the writer must give the values.
        attrs: further ATL03 attributes (``valid_min``, ``flag_values``, ...).
    """
    dtype: str
    units: str
    long_name: str
    description: str
    fill: object = None
    shape: tuple = ()
    const: object = None
    model_note: str = ""
    attrs: dict = field(default_factory=dict)


def _f4(units, long_name, description, **kw):
    return Field("f4", units, long_name, description, fill=F4_FILL, **kw)


def _zero(units, long_name, why, **kw):
    """A float32 field written as 0: not modelled because nothing in the simulation needs it."""
    return _f4(units, long_name, f"0: {why}", const=0.0, model_note=f"not modelled: {why}", **kw)


_TIME = "seconds since 2018-01-01"
_LAT = dict(valid_min=-90.0, valid_max=90.0, standard_name="latitude")
_LON = dict(valid_min=-180.0, valid_max=180.0, standard_name="longitude")
_NO_TIDES = "a simulated surface has no tides; the heights need no correction"
_NO_ATM = ("the simulated ranges have no atmospheric delay (photons travel at c), so the "
           "heights need no correction")
_EXACT = "a simulation has no geolocation error"

HEIGHTS = {
    "delta_time": Field("f8", _TIME, "Elapsed GPS seconds", "transmit time of the photon's shot",
                        attrs=dict(standard_name="time")),
    "dist_ph_across": Field("f4", "meters", "Distance off RGT.",
                            "across-track distance from the beam's own ground track (0: the "
                            "photon is placed at its footprint centre)"),
    "dist_ph_along": Field("f4", "meters", "Distance from equator crossing.",
                           "along-track distance of the photon's footprint centre from the "
                           "start of its 20 m segment"),
    "h_ph": Field("f4", "meters", "Photon WGS84 Height",
                  "photon height above the scene's z = 0 (the ellipsoid for a built-in "
                  "surface or scene, the DEM's vertical datum for a DEM): altitude - c t / 2",
                  attrs=dict(standard_name="height")),
    "lat_ph": Field("f8", "degrees_north", "Latitude",
                    "latitude of the photon's footprint centre (the beam points at nadir)",
                    attrs=_LAT),
    "lon_ph": Field("f8", "degrees_east", "Longitude", "longitude of the photon's footprint "
                    "centre", attrs=_LON),
    "pce_mframe_cnt": Field("u4", "counts", "PCE Major frame counter",
                            "major frame (200 shots) of the photon's shot, from 0 at the "
                            "track's first shot"),
    "ph_id_channel": Field("u1", "1", "Receive channel id",
                           "detector channel: strong beam 1-16, weak beam 17-20",
                           attrs=dict(valid_min=1, valid_max=120)),
    "ph_id_count": Field("u1", "counts", "photon event counter",
                         "1-based index of the event among its channel's events of the pulse"),
    "ph_id_pulse": Field("u1", "counts", "laser pulse counter",
                         "pulse number within the major frame (1-200)"),
    "quality_ph": Field("i1", "1", "Photon Quality",
                        "0 nominal; in a fully or nearly saturated pulse (see full_sat_fract), "
                        "1 possible afterpulse 1.8-4.7 m and 2 possible impulse-response effect "
                        "4.7-45 m below its highest surface event (windows bracketing Lu et al. "
                        "2021's receiver echoes and afterpulses; ATL03's own are not published); "
                        "3 (possible TEP) never: the transmitter echo path is not simulated",
                        attrs=dict(valid_min=0, valid_max=3, flag_values=[0, 1, 2, 3],
                                   flag_meanings="nominal possible_afterpulse "
                                   "possible_impulse_response_effect possible_tep")),
    "signal_conf_ph": Field("i1", "1", "Photon Signal Confidence",
                            "confidence from lidar_mitsuba.products.classify's histogram test (one test "
                            "for all five surface types): 0 noise, 2 low, 3 medium, 4 high",
                            shape=(5,), attrs=dict(
                                valid_min=-2, valid_max=4, flag_values=[-2, -1, 0, 1, 2, 3, 4],
                                flag_meanings="possible_tep not_considered noise buffer low "
                                "medium high")),
    "weight_ph": Field("u1", "1", "Photon weight",
                       "255 min(1, -log10(P) / 6), P the histogram test's probability of the "
                       "photon's neighbourhood count under noise alone (255: P <= 1e-6, high "
                       "confidence; 0: P = 1); 255 for every photon of a noiseless run",
                       attrs=dict(valid_min=0, valid_max=255)),
}

GEOLOCATION = {
    "altitude_sc": Field("f8", "meters", "Altitude", "height of the spacecraft above the "
                         "heights' datum (z = 0): Instrument.altitude_m", fill=F8_FILL),
    "bounce_time_offset": _f4("seconds", "ground bounce time offset",
                              "one-way time from the spacecraft to the reference shot's "
                              "reference elevation: (altitude - z_ref) / c"),
    "delta_time": Field("f8", _TIME, "Delta Time", "transmit time of the reference shot (the "
                        "shot nearest the segment centre)", attrs=dict(standard_name="time")),
    "full_sat_fract": _f4("1", "Full Saturation Fraction",
                          "fraction of the segment's pulses with photons whose surface events "
                          "(signal_conf_ph >= 2) are at least the beam's channels (16 strong, "
                          "4 weak: every channel fired on the surface)",
                          attrs=dict(valid_min=0.0, valid_max=1.0)),
    "knn": Field("i4", "counts", "K Nearest Neighbors", "0: weight_ph comes from a histogram "
                 "test, not a nearest-neighbour count", const=0,
                 model_note="not applicable: no KNN photon weighting"),
    "near_sat_fract": _f4("1", "Near Saturation Fraction",
                          "fraction of the segment's pulses with photons whose surface events "
                          "are at least 3/4 of the beam's channels but fewer than all of them",
                          attrs=dict(valid_min=0.0, valid_max=1.0)),
    "neutat_delay_derivative": _zero("meters/meters", "(Neutral Atmosphere delay)/dh", _NO_ATM),
    "neutat_delay_total": _zero("meters", "Total Neutral Atmospheric Delay", _NO_ATM),
    "neutat_ht": _zero("meters", "Neutral atmosphere ref height", _NO_ATM),
    "ph_index_beg": Field("i8", "counts", "Photon Index Begin",
                          "1-based index in heights/ of the segment's first photon (0: none)",
                          fill=np.int64(0)),
    "pitch": _zero("degrees", "Pitch", "the spacecraft points the beams at nadir exactly"),
    "podppd_flag": Field("i1", "1", "POD_PPD Flag", "0: nominal (the simulated geolocation is "
                         "exact)", const=0, model_note=f"not modelled: {_EXACT}",
                         attrs=dict(valid_min=0, valid_max=7, flag_values=list(range(8)),
                                    flag_meanings="nominal pod_degrade ppd_degrade "
                                    "podppd_degrade cal_nominal cal_pod_degrade "
                                    "cal_ppd_degrade cal_podppd_degrade")),
    "range_bias_corr": _zero("meters", "range bias correction",
                             "the simulated ranges have no bias to correct"),
    "ref_azimuth": _f4("radians", "Azimuth", "direction of travel at the reference shot, "
                       "clockwise from north (the beam points at nadir)",
                       attrs=dict(standard_name="azimuth")),
    "ref_elev": _f4("radians", "elevation", "elevation of the pointing vector: pi / 2 (nadir)",
                    attrs=dict(standard_name="elevation")),
    "reference_photon_index": Field("i4", "counts", "Reference Photon Index",
                                    "1-based index in the segment of the reference shot's "
                                    "first photon (0: none)", fill=np.int32(0)),
    "reference_photon_lat": Field("f8", "degrees_north", "Segment Latitude",
                                  "footprint centre of the reference shot", attrs=_LAT),
    "reference_photon_lon": Field("f8", "degrees_east", "Segment Longitude",
                                  "footprint centre of the reference shot", attrs=_LON),
    "roll": _zero("degrees", "roll", "the spacecraft points the beams at nadir exactly"),
    "segment_dist_x": Field("f8", "meters", "Segment Distance from EQC",
                            "along-track distance of the segment start from the track's first "
                            "shot (not from the equator)"),
    "segment_id": Field("i4", "1", "along-track segment ID number.",
                        "20 m segment number, from 1 at the track's first shot"),
    "segment_length": Field("f8", "meters", "along-track segment length", "20 m, every segment"),
    "segment_ph_cnt": Field("i4", "counts", "Number of photons", "photons in the segment",
                            fill=np.int32(0)),
    "sigma_across": _zero("meters", "across-track geolocation uncertainty", _EXACT),
    "sigma_along": _zero("meters", "along-track geolocation uncertainity", _EXACT),
    "sigma_h": _zero("meters", "height uncertainty", _EXACT),
    "sigma_lat": _zero("degrees", "latitude uncertainty", _EXACT),
    "sigma_lon": _zero("degrees", "longitude uncertainty", _EXACT),
    "solar_azimuth": _f4("degrees_east", "solar azimuth",
                         "the sun's azimuth at the reference shot, clockwise from north (NREL "
                         "SPA, lidar_mitsuba.radiometry.solar_angles)"),
    "solar_elevation": _f4("degrees", "solar elevation",
                           "the sun's geometric elevation at the reference shot (NREL SPA, "
                           "lidar_mitsuba.radiometry.solar_angles; no refraction)"),
    "surf_type": Field("i1", "1", "Surface Type", "surface types (land, ocean, sea ice, land "
                       "ice, inland water): land ice", shape=(5,),
                       attrs=dict(valid_min=0, valid_max=1, flag_values=[0, 1],
                                  flag_meanings="not_type is_type")),
    "tx_pulse_energy": _f4("Joules", "Transmit Pulse Energy",
                           "the beam's transmitted pulse energy (the link budget's)"),
    "tx_pulse_skew_est": _f4("seconds", "Transmit Pulse Skew Estimate",
                             "0: the simulated pulse is a symmetric Gaussian", const=0.0,
                             model_note="a symmetric Gaussian pulse has no skew"),
    "tx_pulse_width_lower": _f4(
        "seconds", "Transmit Pulse Energy Lower Width", "fill value: see model_note",
        const=F4_FILL, model_note="not modelled: the start-pulse detector's thresholds are "
        "voltages whose fraction of the pulse peak is not published, so the widths of the "
        "simulated Gaussian pulse at them cannot be given"),
    "tx_pulse_width_upper": _f4(
        "seconds", "Transmit Pulse Energy Upper Width", "fill value: see model_note",
        const=F4_FILL, model_note="not modelled: the start-pulse detector's thresholds are "
        "voltages whose fraction of the pulse peak is not published"),
    "velocity_sc": _f4("meters/second", "spacecraft velocity",
                       "east, north, up velocity of the beam's footprint at the reference shot "
                       "(its neighbours' ECEF positions on the ellipsoid, pyproj), which is what "
                       "ATL03 reports (a real granule's velocity_sc is its footprints' ground "
                       "speed, ~7.1 km/s, not the orbital 7.6 km/s)", shape=(3,)),
    "yaw": _f4("degrees", "Yaw", "180 flying backward (sc_orient 0), 0 forward; pitch and roll "
               "are 0"),
}

BCKGRD_ATLAS = {
    "bckgrd_counts": Field("i4", "counts", "ATLAS 50-shot background count",
                           "detected events (signal and noise) in the 50 shots' range gates"),
    "bckgrd_counts_reduced": Field("i4", "counts", "ATLAS 50-shot background count - reduced",
                                   "bckgrd_counts less the 50 shots' high-confidence "
                                   "events (signal_conf_ph 4), as real ATL03's rows remove"),
    "bckgrd_hist_top": Field("f4", "meters", "Top of the altimetric range window",
                             "height of the top of the first shot's range gate"),
    "bckgrd_int_height": Field("f4", "meters", "Altimetric range window width",
                               "height of the range gate (Instrument.range_gate_m)"),
    "bckgrd_int_height_reduced": Field("f4", "meters", "Altimetric range window height - "
                                       "reduced", "range gate less the height span of the "
                                       "50 shots' high-confidence events (signal_conf_ph 4), as "
                                       "real ATL03's rows remove"),
    "bckgrd_rate": Field("f4", "counts / second", "Background count rate based on the ATLAS "
                         "50-shot sum", "the modelled rate of noise events the detector "
                         "records, averaged over the 50 shots: background reaching the "
                         "detector x fill factor x PDE + dark counts x channels (not estimated "
                         "from the counts)"),
    "delta_time": Field("f8", _TIME, "Time at the start of ATLAS 50-shot sum",
                        "transmit time of the first of the 50 shots",
                        attrs=dict(standard_name="time")),
    "pce_mframe_cnt": Field("i8", "counts", "PCE Major frame counter",
                            "major frame of the first of the 50 shots"),
    "tlm_height_band1": Field("f4", "meters", "Height of the telemetry band 1",
                              "height of the range gate (the one telemetry band)"),
    "tlm_height_band2": Field("f4", "meters", "Height of the telemetry band 2",
                              "0: no second band", const=0.0,
                              model_note="the simulation records one band, the range gate"),
    "tlm_top_band1": Field("f4", "meters", "Ellipsoidal height of the top of the telemetry "
                           "band 1.", "height of the top of the first shot's range gate"),
    "tlm_top_band2": Field("f4", "meters", "Ellipsoidal height of the top of the telemetry "
                           "band 2.", "0: no second band", const=0.0,
                           model_note="the simulation records one band, the range gate"),
}

GEOPHYS_CORR = {
    "dac": _zero("meters", "Dynamic Atmosphere Correction", _NO_TIDES),
    "delta_time": Field("f8", _TIME, "Elapsed GPS seconds", "transmit time of the segment's "
                        "reference shot", attrs=dict(standard_name="time")),
    "dem_flag": Field("i1", "1", "dem source flag", "fill value: the DEM is the simulation's "
                      "own surface, none of ATL03's sources", fill=np.int8(127), const=127,
                      model_note="the surface simulated is its own DEM",
                      attrs=dict(valid_min=0, valid_max=4, flag_values=[0, 1, 2, 3, 4],
                                 flag_meanings="none arctic global mss antarctic")),
    "dem_h": _f4("meters", "DEM Height", "height of the simulated surface at the reference "
                 "shot's footprint centre (fill value over nodata)"),
    "geoid": _zero("meters", "Geoid", "heights are above the scene's z = 0; no geoid model"),
    "geoid_free2mean": _zero("meters", "Geoid Free-to-Mean conversion", "no geoid model"),
    "tide_earth": _zero("meters", "Earth Tide", _NO_TIDES),
    "tide_earth_free2mean": _zero("meters", "Earth Tide Free-to-Mean conversion", _NO_TIDES),
    "tide_equilibrium": _zero("meters", "Long Period Equilibrium Tide", _NO_TIDES),
    "tide_load": _zero("meters", "Load Tide", _NO_TIDES),
    "tide_oc_pole": _zero("meters", "Ocean Pole Tide", _NO_TIDES),
    "tide_ocean": _zero("meters", "Ocean Tide", _NO_TIDES),
    "tide_pole": _zero("meters", "Solid Earth Pole Tide", _NO_TIDES),
}

SIGNAL_FIND = {
    "bckgrd_mean": _f4("counts", "background counts per bin",
                       "the histogram test's noise level: expected noise events in one bin of "
                       "z_pc_delta over t_pc_delta (pooled over 11 blocks)"),
    "bckgrd_sigma": _f4("counts", "background counts per bin sigma",
                        "its Poisson standard deviation, sqrt(bckgrd_mean)"),
    "delta_time": Field("f8", _TIME, "Elapsed GPS seconds",
                        "transmit time of the block's first shot",
                        attrs=dict(standard_name="time")),
    "t_pc_delta": _f4("seconds", "bin width size",
                      "the histogram's block length (20 shots) in time"),
    "z_pc_delta": _f4("meters", "bin height size", "the histogram's bin height"),
}

GROUPS = {"heights": HEIGHTS, "geolocation": GEOLOCATION, "bckgrd_atlas": BCKGRD_ATLAS,
          "geophys_corr": GEOPHYS_CORR,
          **{f"signal_find_output/{s}": SIGNAL_FIND for s in SURFACE_TYPES}}
"""Every group of a beam and its fields."""

COORDINATES = {"heights": "delta_time lat_ph lon_ph",
               "geolocation": "delta_time reference_photon_lat reference_photon_lon"}
"""The ``coordinates`` attribute of a group's fields (``delta_time`` elsewhere)."""
