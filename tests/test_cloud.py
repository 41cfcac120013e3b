"""Clouds and near-surface layers (lidar_mitsuba.studies.cloud): physics checks at small
sizes, fixed seeds, tolerances of four standard errors from the sampling itself."""
import math
import warnings

import numpy as np
import pytest

from lidar_mitsuba.constants import C_M_PER_NS, SimulationWarning
from lidar_mitsuba.instrument import Instrument
from lidar_mitsuba.studies import cloud

pytestmark = pytest.mark.filterwarnings("ignore", category=SimulationWarning)


def test_photons_through_an_absorbing_cloud_are_poisson_times_exp_minus_2tau():
    """An absorbing layer (albedo 0) 1-1.5 km up, ideal detector: the detected ground photons
    are the clear sky's times exp(-2 tau); both counts are Poisson sums over the shots."""
    tau, shots = 0.5, 1500
    ideal = Instrument.atlas("strong", ideal_detector=True)
    kw = dict(shots=shots, seed=11, paths_per_shot=64, instrument=ideal)
    clear = cloud.run_case(scene=cloud.layer_scene(tau=0.0, base_m=1000, top_m=1500), **kw)
    dark = cloud.run_case(scene=cloud.layer_scene(tau=tau, base_m=1000, top_m=1500,
                                                  albedo=0.0), **kw)
    n_c, n_t = clear["signal_per_shot"] * shots, dark["signal_per_shot"] * shots
    f = math.exp(-2 * tau)
    z = (n_t - f * n_c) / math.sqrt(n_t + f * f * n_c)
    assert abs(z) < 4, (n_t, n_c, z)
    # no light scattered: no delay either (the mean elevation is the clear sky's)
    assert abs(dark["dh_m"] - clear["dh_m"]) < 4 * math.hypot(dark["dh_se_m"], clear["dh_se_m"])


def test_traced_unscattered_part_is_beer_lambert_and_scattering_adds_light():
    s = cloud.trace_split(cloud.layer_scene(tau=1.0, base_m=1000, top_m=1500), shots=1000,
                          paths_per_shot=64, seed=3)
    assert abs(s["direct"] - math.exp(-2.0)) < 4 * s["direct_se"] + 1e-6, s
    assert s["scattered"] > 4 * s["scattered_se"] > 0


def test_forward_scatter_delay_is_positive_and_grows_with_tau():
    """The ideal detector's mean elevation (the trace's weighted mean: no pulse, no dead
    time) drops below the ground through a low cloud, more for a thicker one."""
    d = {tau: cloud.trace_split(cloud.layer_scene(tau=tau, base_m=50, top_m=250),
                                shots=1000, paths_per_shot=64, seed=5) for tau in (0.5, 2.0)}
    lo, hi = d[0.5], d[2.0]
    assert lo["delay_dh_m"] < -4 * lo["delay_dh_se_m"], lo
    assert hi["delay_dh_m"] < lo["delay_dh_m"] - 4 * math.hypot(hi["delay_dh_se_m"],
                                                                lo["delay_dh_se_m"]), d


def test_cheap_model_is_better_for_a_high_cloud_than_for_a_low_one():
    """exp(-2 tau) times the clear return misses the forward-scattered light the receiver
    sees: a large part of it under a low cloud, a small one under a high cloud."""
    err = {}
    for base, top in (cloud.LOW, cloud.HIGH):
        s = cloud.trace_split(cloud.layer_scene(tau=1.0, base_m=base, top_m=top), shots=1000,
                              paths_per_shot=64, seed=9)
        total = s["direct"] + s["scattered"]
        err[base] = (s["scattered"] / total, s["scattered_se"] / total)
    (e_low, se_low), (e_high, se_high) = err[cloud.LOW[0]], err[cloud.HIGH[0]]
    assert e_low > e_high + 4 * math.hypot(se_low, se_high), err
    assert e_low > cloud.CHEAP_COUNT_TOL       # a fog's scattered light is not negligible


def test_cloud_table_splits_the_elevation_change_into_its_two_causes():
    rows = cloud.cloud_table(base_m=50, top_m=250, taus=(0.0, 1.0), shots=800,
                             paths_per_shot=64, trace_shots=300)
    clear, one = rows
    assert clear["dh_total_m"] == 0.0 and clear["fpb_m"] > 0      # dead time: early photons
    assert one["dh_total_m"] == pytest.approx(one["fpb_change_m"] + one["delay_m"], abs=1e-12)
    # fewer photons per channel: a smaller first-photon bias
    assert one["fpb_change_m"] < 4 * one["fpb_change_se_m"]
    assert one["signal_per_shot"] < clear["signal_per_shot"]
    cheap = cloud.cheap_model(rows, shots=800)
    assert len(cheap) == 1 and cheap[0]["count_error"] < 0     # it misses scattered light


def test_blowing_snow_photons_above_the_ground_grow_with_tau_and_convert_to_hz():
    rows = cloud.night_background(kind="snow", taus=(0.05, 0.5), shots=1500, seed=4)
    thin, thick = rows
    assert thick["above_per_shot"] > thin["above_per_shot"] + 4 * math.hypot(
        thick["above_per_shot_se"], thin["above_per_shot_se"])
    window_s = 2 * (thick["top_m"] - 2.0) / C_M_PER_NS * 1e-9
    assert thick["rate_layer_hz"] == pytest.approx(thick["above_per_shot"] / window_s)
    assert thick["rate_5km_hz"] < thick["rate_layer_hz"]
    # the layer dims the ground
    assert thick["ground_signal_per_shot"] < thin["ground_signal_per_shot"]
    assert np.isfinite(thick["rate_30m_gate_hz"])
