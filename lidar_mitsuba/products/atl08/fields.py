"""The ATL08 datasets we write, as the real product carries them: path under the beam group,
dtype, trailing shape and fill value as in ATL08 release 006 (checked against the real clip
``/work/shared/real/ATL08_gt1r_20220401_forest_wyoming.h5`` by tests/test_atl08.py; the
clip's datasets keep their HDF5 fill values but its subsetter dropped the attributes), units
and long names from the ATL08 data dictionary, and our own description of what we compute.
Every other dataset of the real beam group is left out (:data:`NOT_WRITTEN` says why).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

F4_FILL = np.float32(np.finfo(np.float32).max)     #: ATL08's float32 fill (3.4028235e+38)
RH_PERCENTILES = tuple(range(10, 100, 5))
"""The relative-height percentiles of ``canopy_h_metrics`` (ATL08 release 006: 18 values,
RH10 to RH95 in steps of 5; RH98 is ``h_canopy``)."""


@dataclass(frozen=True)
class Field:
    """One ATL08 dataset: numpy dtype, HDF5 fill value (``None``: the writer sets none),
    trailing shape, units, long name, description."""
    dtype: str
    fill: object
    units: str
    long_name: str
    description: str
    shape: tuple = ()


def _h(long_name: str, description: str, shape: tuple = ()) -> Field:
    return Field("f4", F4_FILL, "meters", long_name, description, shape)


def _n(long_name: str, description: str) -> Field:
    return Field("i4", np.int32(0), "counts", long_name, description)


_T = "seconds since 2018-01-01"
LAND = {
    "segment_id_beg": Field("i4", np.int32(0), "1", "Beginning segment identifier",
                            "the first of the five ATL03 20 m segment_id of the segment"),
    "segment_id_end": Field("i4", np.int32(0), "1", "Ending segment identifier",
                            "the last of the five ATL03 20 m segment_id of the segment"),
    "delta_time": Field("f8", np.float64(0.0), _T, "Elapsed GPS seconds",
                        "time at the segment's mid-point: the mean of its photons' times"),
    "delta_time_beg": Field("f8", np.float64(0.0), _T, "Delta time of first photon",
                            "time of the segment's first photon"),
    "delta_time_end": Field("f8", np.float64(0.0), _T, "Delta time of last photon",
                            "time of the segment's last photon"),
    "latitude": Field("f4", np.float32(0.0), "degrees_north", "latitude",
                      "latitude of the segment's mid-point: the mean of its five 20 m "
                      "segments' reference photons"),
    "longitude": Field("f4", np.float32(0.0), "degrees_east", "longitude",
                       "longitude of the segment's mid-point"),
    "latitude_20m": Field("f4", F4_FILL, "degrees_north", "Latitude of the 20m segment",
                          "reference-photon latitude of each 20 m segment", (5,)),
    "longitude_20m": Field("f4", F4_FILL, "degrees_east", "Longitude of the 20m segment",
                           "reference-photon longitude of each 20 m segment", (5,)),
    "night_flag": Field("i4", np.int32(2147483647), "1", "night flag",
                        "1 where the sun is below the horizon (solar_elevation < 0), else 0"),
    "solar_elevation": Field("f4", np.float32(0.0), "degrees", "solar elevation",
                             "mean solar elevation of the five 20 m segments"),
    "solar_azimuth": Field("f4", np.float32(0.0), "degrees_east", "solar azimuth",
                           "mean solar azimuth of the five 20 m segments"),
    "n_seg_ph": Field("i4", np.int32(0), "counts", "Number of photons within each land segment",
                      "photons of the segment that passed the noise filter (d_flag 1)"),
}
TERRAIN = {
    "h_te_best_fit": _h("terrain height best fit", "linear least-squares fit of the ground "
                        "photons' heights along track, at the segment's mid-point"),
    "h_te_best_fit_20m": _h("terrain height best fit 20m", "the same line at each 20 m "
                            "segment's mid-point, where that 20 m segment has ground photons",
                            (5,)),
    "h_te_interp": _h("interpolated terrain surface height", "the ground surface (final "
                      "smoothing spline) at the segment's mid-point"),
    "h_te_mean": _h("mean terrain height", "mean height of the ground photons"),
    "h_te_median": _h("median terrain height", "median height of the ground photons"),
    "h_te_min": _h("minimum terrain height", "lowest ground photon"),
    "h_te_max": _h("maximum terrain height", "highest ground photon"),
    "h_te_std": _h("standard deviation of terrain height", "standard deviation of the ground "
                   "photons about their mean"),
    "h_te_uncertainty": _h("uncertainty of the mean terrain height", "standard error of "
                           "h_te_best_fit: sigma_res sqrt(1/n + (x_mid - x_bar)^2 / Sxx) of "
                           "the line fit"),
    "terrain_slope": Field("f4", F4_FILL, "1", "terrain slope", "along-track slope of the "
                           "ground photons' line fit (rise over run)"),
    "n_te_photons": _n("number of ground photons", "photons classed ground (classed_pc_flag 1)"),
    "photon_rate_te": Field("f4", F4_FILL, "photons/shot", "photon rate of ground photons",
                            "ground photons per shot of the segment"),
}
CANOPY = {
    "h_canopy": _h("height of top of canopy", "RH98: 98th percentile of the canopy and "
                   "top-of-canopy photons' heights above the ground surface"),
    "canopy_h_metrics": _h("canopy height metrics", "relative-height percentiles RH10, "
                           "RH15, ..., RH95 of the canopy photons above the ground",
                           (len(RH_PERCENTILES),)),
    "h_mean_canopy": _h("mean canopy height", "mean height of the canopy photons above the "
                        "ground"),
    "h_median_canopy": _h("median canopy height", "median height of the canopy photons above "
                          "the ground"),
    "h_max_canopy": _h("maximum canopy height", "highest canopy photon above the ground"),
    "h_min_canopy": _h("minimum canopy height", "lowest canopy photon above the ground"),
    "h_dif_canopy": _h("difference between h_canopy and h_median_canopy",
                       "h_canopy - h_median_canopy"),
    "canopy_openness": _h("canopy openness", "standard deviation of the canopy photons' "
                          "heights above the ground"),
    "toc_roughness": _h("top of canopy roughness", "standard deviation of the top-of-canopy "
                        "photons' heights above the ground"),
    "h_canopy_abs": _h("absolute height of top of canopy", "98th percentile of the canopy "
                       "photons' heights above the ellipsoid"),
    "canopy_h_metrics_abs": _h("absolute canopy height metrics", "percentiles RH10 ... RH95 of "
                               "the canopy photons' heights above the ellipsoid",
                               (len(RH_PERCENTILES),)),
    "h_mean_canopy_abs": _h("mean absolute canopy height", "mean canopy photon height above "
                            "the ellipsoid"),
    "h_median_canopy_abs": _h("median absolute canopy height", "median canopy photon height "
                              "above the ellipsoid"),
    "h_max_canopy_abs": _h("maximum absolute canopy height", "highest canopy photon above the "
                           "ellipsoid"),
    "h_min_canopy_abs": _h("minimum absolute canopy height", "lowest canopy photon above the "
                           "ellipsoid"),
    "centroid_height": _h("canopy and terrain centroid height", "mean height above the "
                          "ellipsoid of the ground and canopy photons"),
    "n_ca_photons": _n("number of canopy photons", "photons classed canopy (classed_pc_flag 2)"),
    "n_toc_photons": _n("number of top of canopy photons",
                        "photons classed top of canopy (classed_pc_flag 3)"),
    "photon_rate_can": Field("f4", F4_FILL, "photons/shot", "photon rate of canopy photons",
                             "canopy and top-of-canopy photons per shot of the segment"),
}
SIGNAL_PHOTONS = {
    "classed_pc_flag": Field("i1", None, "1", "Photon Land Vegetation Classification",
                             "0 noise, 1 ground, 2 canopy, 3 top of canopy"),
    "classed_pc_indx": Field("i4", None, "1", "Classified photon index",
                             "1-based index of the photon within its ATL03 20 m segment "
                             "(ATL03 photon = ph_index_beg - 1 + classed_pc_indx - 1, with "
                             "ph_index_beg 1-based)"),
    "ph_segment_id": Field("i4", None, "1", "Georeferenced bin number",
                           "the ATL03 segment_id of the photon's 20 m segment"),
    "delta_time": Field("f8", None, _T, "Elapsed GPS seconds", "the photon's time"),
    "ph_h": Field("f4", F4_FILL, "meters", "Photon height above ground",
                  "photon height above the interpolated ground surface"),
    "d_flag": Field("i1", None, "1", "DRAGANN flag",
                    "1: the photon passed our noise filter (all photons written here did)"),
}
GROUPS = {"land_segments": LAND, "land_segments/terrain": TERRAIN,
          "land_segments/canopy": CANOPY, "signal_photons": SIGNAL_PHOTONS}
"""Every dataset we write, by group under the beam group."""
NOT_WRITTEN = (
    "the ancillary inputs ATL08 takes from outside the photons (dem_h, dem_flag, "
    "segment_landcover, segment_snowcover, segment_watermask, urban_flag, surf_type, "
    "cloud_flag_atm, layer_flag, msw_flag, asr, snr, sigma_*, psf_flag, sat_flag, rgt, ...), "
    "the products of steps we do not run (h_canopy_quad, h_canopy_20m, canopy_rh_conf, "
    "subset_*_flag, h_te_mode, h_te_skew, h_te_rh25, segment_cover, can_noise, "
    "h_canopy_uncertainty, photon_rate_can_nr), and the pointers (ph_ndx_beg) whose "
    "conventions we could not check on the clip")
"""What of the real ``land_segments`` we leave out, and why."""
