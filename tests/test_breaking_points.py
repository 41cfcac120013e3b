"""The edges of each model: finite results with their accuracy, or a clear refusal.

Tolerances: Monte Carlo standard errors (Z = 4.5) where a closed form exists; otherwise the
assertion is finiteness and the documented qualitative behaviour.
"""
import math

import mitsuba as mi
import numpy as np
import pytest

from lidar_mitsuba.constants import ParameterError
from lidar_mitsuba.instrument import Instrument
from lidar_mitsuba.run import simulate
from lidar_mitsuba.ground.surface import SurfaceSpec
from lidar_mitsuba.studies import breaking_points as stability

Z = 4.5


def test_steepest_slope_runs_and_90_is_refused():
    res = simulate(instrument=Instrument(ideal_detector=True, range_gate_m=2000.0),
                   surface=SurfaceSpec(kind="slope", slope_deg=89.0), shots=3000, seed=1,
                   progress=False)
    st = res.report().overall
    assert st.n_photons > 30 and math.isfinite(st.bias_m) and math.isfinite(st.std_m)
    # return weight cos(89 deg) for a Lambertian-like plane: photons/shot ~ 8.17*0.4*w*cos
    with pytest.raises(ParameterError, match="slope_deg"):
        SurfaceSpec(kind="slope", slope_deg=90.0)


def test_near_mirror_ward_saturates_but_stays_finite():
    """alpha = 0.003: ~12,600 photons per shot reach the detector (closed form), every one of
    the 16 channels fires once (dead time), and nothing blows up."""
    res = simulate(surface=SurfaceSpec(kind="flat", alpha=0.003), shots=40, seed=1, progress=False)
    w = math.pi * (0.9 / math.pi + 0.05 / (4 * math.pi * 0.003 ** 2)) / 0.9
    assert np.allclose(res.detections.mean_photons_per_shot, 8.17 * w, rtol=1e-4)
    assert res.report().overall.photons_per_shot == pytest.approx(16.0, abs=0.5)
    with pytest.raises(ParameterError, match="alpha"):
        SurfaceSpec(alpha=0.0)


def test_fractal_exponent_and_grid_edges():
    for p in (0.5, 4.0):
        st = simulate(surface=SurfaceSpec(kind="fractal", p=p, size_m=128.0), shots=200,
                      seed=1, progress=False).report().overall
        assert math.isfinite(st.std_m)
    with pytest.raises(ParameterError, match="^p"):
        SurfaceSpec(p=5.5)
    with pytest.raises(ParameterError, match="grid_m"):
        SurfaceSpec(size_m=1024.0, grid_m=0.1)
    res = simulate(surface=SurfaceSpec(kind="fractal", size_m=1024.0, grid_m=20.0), shots=100,
                   seed=1, progress=False)
    assert any("coarser than the footprint resolves" in c for c in res.config["choices"])


def test_altitude_edges():
    """Float64 legs stay exact from 1 km to 1000 km; a spacecraft inside the scene is refused."""
    rows = stability.sweep_altitude(quick=True)
    assert all(r["max_error_m"] < 1e-6 for r in rows)
    assert rows[3]["float32_error_m"] > 1e-3      # what float32 legs would cost at 496 km
    with pytest.raises(ParameterError, match="must be above the scene, which reaches") as e:
        simulate(instrument=Instrument(altitude_m=10.0),
                 surface=SurfaceSpec(kind="fractal", size_m=64.0, relief_m=30.0), shots=2,
                 progress=False)
    assert e.value.name == "altitude_m"


def test_photons_per_launch_edges():
    scene = mi.load_dict({"type": "scene", "plate": {
        "type": "rectangle", "to_world": mi.ScalarTransform4f().scale(50)}})
    out = mi.load_dict({"type": "pathlength", "max_lanes": 1}).trace(
        scene, shot_x_m=np.zeros(20), shot_y_m=np.zeros(20), paths_per_shot=1)
    assert out.weight.size == 20
    with pytest.raises(RuntimeError, match="max_lanes"):
        mi.load_dict({"type": "pathlength", "max_lanes": 2 ** 30 + 1})


def test_saturated_signal_first_photon_bias_grows():
    """16 channels, 3 ns dead time: the bias grows monotonically with signal as channels
    saturate (1000 photons/shot: every channel fires on its first photon)."""
    biases = []
    for sig in (3.0, 100.0, 1000.0):
        st = simulate(instrument=Instrument(signal_photons=sig), surface=SurfaceSpec(kind="flat"),
                      shots=400, seed=2, paths_per_shot=int(max(128, 4 * sig)),
                      progress=False).report().overall
        biases.append((st.bias_m, st.bias_se_m))
    assert biases[0][0] + Z * biases[0][1] < biases[1][0] - Z * biases[1][1]
    assert biases[1][0] + Z * biases[1][1] < biases[2][0] - Z * biases[2][1]
