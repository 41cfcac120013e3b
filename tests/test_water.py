"""The water material: closed forms (``lidar_mitsuba.ground.water``), the ``<bsdf type="water">``
plugin (``plugins/water.py``) loaded from XML and dicts, and its nadir return traced by the
``pathlength`` integrator against the Cox-Munk / Kirchhoff closed form.

Monte Carlo tolerance: Z = 4 standard errors computed from the per-path weights (sigma /
sqrt(n) for a mean).
"""
import math
import re
import subprocess
import sys

import mitsuba as mi
import numpy as np
import pytest

import lidar_mitsuba_plugins
from lidar_mitsuba.ground import water
from lidar_mitsuba.ground.water import (WATER_GROUP_INDEX_532, WATER_INDEX_532, cox_munk_mss,
                                        fresnel_normal, nadir_return_weight, quan_fry_group_index,
                                        quan_fry_index, sigma0_nadir, water_bsdf)

Z = 4.0
AIR = 1.000277


def load_water(**params):
    return mi.load_dict({"type": "water", **params})


def water_xml(**params):
    body = "".join(f'<float name="{k}" value="{v}"/>' for k, v in params.items())
    return mi.load_string(f'<bsdf version="3.0.0" type="water">{body}</bsdf>')


# ------------------------------------------------------------------ closed forms
def test_cox_munk_linear_law():
    assert cox_munk_mss(0.0) == pytest.approx(0.003)
    assert cox_munk_mss(10.0) == pytest.approx(0.003 + 0.0512)
    u = np.array([0.0, 2.0, 5.0, 12.0])
    s2 = cox_munk_mss(u)
    assert np.allclose(np.diff(s2) / np.diff(u), 0.00512)
    for bad in (-1.0, np.array([1.0, -0.5]), math.nan):
        with pytest.raises(ValueError, match="wind_speed_mps"):
            cox_munk_mss(bad)


def test_fresnel_normal():
    assert fresnel_normal(1.333) == pytest.approx(0.0204, abs=1e-4)
    assert fresnel_normal(1.0) == 0.0
    assert fresnel_normal(1.5) == pytest.approx(0.04)


def test_quan_fry_index_sodium_d_and_dispersion():
    """The coefficients were recalled from memory: pure water at 589.3 nm and 20 C is 1.3330
    (textbook), and the index rises toward blue (normal dispersion)."""
    assert abs(quan_fry_index(589.3, temperature_c=20.0, salinity_psu=0.0) - 1.3330) < 5e-4
    lam = np.linspace(400.0, 700.0, 31)
    assert np.all(np.diff(quan_fry_index(lam)) < 0)
    # salt raises the index (~0.0063 at 35 PSU), warming lowers it
    assert quan_fry_index(532.0, salinity_psu=35.0) > quan_fry_index(532.0)
    assert quan_fry_index(532.0, temperature_c=25.0) < quan_fry_index(532.0)
    with pytest.raises(ValueError, match="wavelength_nm"):
        quan_fry_index(-532.0)
    with pytest.raises(ValueError, match="salinity_psu"):
        quan_fry_index(532.0, salinity_psu=-1.0)


def test_group_index_is_the_derivative_and_exceeds_the_phase_index():
    lam, h = np.array([450.0, 532.0, 650.0]), 1e-3
    dn = (quan_fry_index(lam + h, temperature_c=5.0, salinity_psu=30.0)
          - quan_fry_index(lam - h, temperature_c=5.0, salinity_psu=30.0)) / (2 * h)
    ng = quan_fry_index(lam, temperature_c=5.0, salinity_psu=30.0) - lam * dn
    assert np.allclose(quan_fry_group_index(lam, temperature_c=5.0, salinity_psu=30.0), ng,
                       atol=1e-9)
    assert np.all(quan_fry_group_index(lam) > quan_fry_index(lam))
    assert WATER_INDEX_532 == quan_fry_index(532.0)
    assert WATER_GROUP_INDEX_532 == quan_fry_group_index(532.0)
    assert WATER_INDEX_532 == pytest.approx(1.3360, abs=1e-4)
    assert WATER_GROUP_INDEX_532 == pytest.approx(1.357, abs=2e-3)      # 1.35769


def test_nadir_sigma0_and_weight():
    n, s2 = 1.333, 0.0286
    assert sigma0_nadir(n, s2) == pytest.approx(fresnel_normal(n) / s2)
    # the Beckmann microfacet BRDF at nadir, pi f_r cos / 0.9 with f_r = F D G / (4 cos cos)
    alpha2 = s2
    f_r = fresnel_normal(n) * (1 / (math.pi * alpha2)) * 1.0 / 4.0
    assert nadir_return_weight(n, s2) == pytest.approx(math.pi * f_r / 0.9)
    assert nadir_return_weight(n, s2) == pytest.approx(sigma0_nadir(n, s2) / 3.6)
    assert water.REFERENCE_ALBEDO == lidar_mitsuba_plugins.constants.REFERENCE_ALBEDO
    with pytest.raises(ValueError, match="mss"):
        nadir_return_weight(n, 0.0)
    with pytest.raises(ValueError, match="n must"):
        sigma0_nadir(-1.0, s2)


def test_module_imports_no_mitsuba():
    """lidar_mitsuba/ground/water.py executed on its own (not through the package, which sets up
    Mitsuba) leaves mitsuba and drjit unimported."""
    code = ("import importlib.util, sys\n"
            f"spec = importlib.util.spec_from_file_location('w', {water.__file__!r})\n"
            "m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m)\n"
            "print(m.WATER_GROUP_INDEX_532, 'mitsuba' in sys.modules, 'drjit' in sys.modules)")
    out = subprocess.run([sys.executable, "-I", "-c", code], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split()[1:] == ["False", "False"]


def test_water_bsdf_dict():
    assert water_bsdf() == {"type": "water", "wind_speed_mps": 0.0}
    d = water_bsdf(mss=0.02, ior=1.34, group_index=1.36)
    assert d == {"type": "water", "mss": 0.02, "int_ior": 1.34, "group_index": 1.36}
    b = mi.load_dict(water_bsdf(wind_speed_mps=5))
    assert b.mss == pytest.approx(cox_munk_mss(5.0))
    for kw, text in (({"wind_speed_mps": -1}, "wind_speed_mps must be >= 0"),
                     ({"mss": 0}, "mss must be > 0"), ({"mss": math.inf}, "mss must be > 0"),
                     ({"ior": 0.9}, "ior must be > 1"),
                     ({"group_index": 0.5}, "group_index must be >= 1"),
                     ({"ior": "x"}, "ior must be a number"),
                     ({"wind_speed_mps": 1, "mss": 0.01}, "give wind_speed_mps or mss")):
        with pytest.raises(ValueError, match=re.escape(f"water: {text}")):
            water_bsdf(**kw)


# ------------------------------------------------------------------ the plugin
def test_plugin_defaults_match_the_closed_forms():
    mod = lidar_mitsuba_plugins.module("water")
    b = load_water()
    assert isinstance(b, mod.WaterBSDF)
    assert b.mss == pytest.approx(cox_munk_mss(0.0))
    assert b.wind_speed_mps == 0.0
    assert b.phase_index == pytest.approx(WATER_INDEX_532 / AIR, rel=1e-12)
    assert b.group_index == pytest.approx(WATER_GROUP_INDEX_532, rel=1e-12)
    for u in (0.0, 3.3, 12.0):
        assert mod.cox_munk_mss(u) == pytest.approx(cox_munk_mss(u), rel=1e-12)
    for t, s in ((0.0, 0.0), (20.0, 35.0)):
        assert mod.quan_fry_index(450.0, t, s) == pytest.approx(
            quan_fry_index(450.0, temperature_c=t, salinity_psu=s), rel=1e-12)
        assert mod.quan_fry_index(450.0, t, s, group=True) == pytest.approx(
            quan_fry_group_index(450.0, temperature_c=t, salinity_psu=s), rel=1e-12)
    assert "water" in lidar_mitsuba_plugins.PLUGIN_FILES


def test_xml_parameters():
    b = water_xml(wind_speed_mps=5)
    assert b.mss == pytest.approx(0.003 + 5 * 0.00512) and b.wind_speed_mps == 5.0
    assert b.alpha == pytest.approx(math.sqrt(b.mss))
    b = water_xml(wind_speed_mps=5, mss=0.01)                 # mss overrides the wind
    assert b.mss == pytest.approx(0.01) and b.wind_speed_mps is None
    b = water_xml(int_ior=1.34, ext_ior=1.0)
    assert b.phase_index == pytest.approx(1.34)
    b = water_xml(group_index=1.4)
    assert b.group_index == pytest.approx(1.4)
    # the inner roughdielectric carries alpha and eta
    params = mi.traverse(water_xml(mss=0.04, int_ior=1.5, ext_ior=1.0))
    assert params["alpha"][0] == pytest.approx(0.2)
    assert params["eta"][0] == pytest.approx(1.5)
    assert "WaterBSDF[mss=0.04" in str(water_xml(mss=0.04))


@pytest.mark.parametrize("params, message", [
    ({"mss": 0}, "water: mss must be > 0 (got 0.0)"),
    ({"mss": -0.1}, "water: mss must be > 0 (got -0.1)"),
    ({"wind_speed_mps": -2}, "water: wind_speed_mps must be >= 0 (got -2.0)"),
    ({"int_ior": 0}, "water: int_ior must be > 0 (got 0.0)"),
    ({"ext_ior": -1}, "water: ext_ior must be > 0 (got -1.0)"),
    ({"group_index": 0.5}, "water: group_index must be >= 1 (got 0.5)"),
    ({"mss": "nan"}, "water: mss must be finite (got nan)"),
])
def test_xml_errors(params, message):
    # The plugin raises ValueError("water: <name> ..."); Mitsuba's loader re-raises it as a
    # RuntimeError containing that text.
    with pytest.raises(RuntimeError, match=re.escape(message)):
        water_xml(**params)


def test_scene_gives_back_the_python_object():
    mod = lidar_mitsuba_plugins.module("water")
    scene = water_plane(mss=0.02)
    b = scene.shapes()[0].bsdf()
    assert isinstance(b, mod.WaterBSDF) and b.group_index == pytest.approx(WATER_GROUP_INDEX_532)
    params = mi.traverse(scene)
    key = "plane.bsdf.alpha"
    params[key] = 0.1
    params.update()
    assert b.mss == pytest.approx(0.01)           # the Python attributes follow the edit
    # ... and so does the scattering: the traced nadir return is the closed form for 0.01
    mean, se, r_max = traced_mean_weight(scene, n_shots=4)
    expected = nadir_return_weight(b.phase_index, 0.01)
    assert abs(mean - expected) <= tolerance(expected, se, r_max, 0.01)


# ------------------------------------------------------------------ rendered nadir return
def water_plane(**params):
    return mi.load_dict({"type": "scene", "plane": {
        "type": "rectangle", "bsdf": {"type": "water", **params},
        "to_world": mi.ScalarTransform4f().scale(200.0)}})


def traced_mean_weight(scene, n_shots=64, paths_per_shot=256, seed=1):
    """Mean return weight per emitted path, its standard error from the per-path weights
    (paths with no return count as 0), and the largest footprint offset [m]."""
    integ = mi.load_dict({"type": "pathlength"})
    out = integ.trace(scene, shot_x_m=np.zeros(n_shots), shot_y_m=np.zeros(n_shots),
                      paths_per_shot=paths_per_shot, seed=seed)
    n = out.n_shots * out.paths_per_shot
    assert n == n_shots * paths_per_shot
    w = np.zeros(n)
    w[:out.weight.size] = out.weight
    r_max = float(np.sqrt(out.x_m ** 2 + out.y_m ** 2).max())
    return w.mean(), w.std(ddof=1) / math.sqrt(n), r_max


def tolerance(expected, se, r_max, mss, altitude_m=496e3):
    """Z standard errors, plus float32 evaluation (1e-5 relative), plus the off-nadir terms:
    a return from r_max off the footprint centre sees the receiver tilted by r / H (~1e-5 rad
    at 496 km for a ~5 m footprint), so the half vector tilts by theta_h = r / (2H) and
    D changes by exp(-tan^2 theta_h / s^2) / cos^4 theta_h - 1 ~ theta_h^2 / s^2 (< 1e-8),
    F(i.h) by ~theta_h^2 and the Smith G1 by less than exp(-1 / (s theta_h)^2): none, but
    bounded here by 10 theta_h^2 (1 + 1 / s^2) of the value."""
    theta_h = r_max / (2.0 * altitude_m)
    return Z * se + expected * (1e-5 + 10.0 * theta_h ** 2 * (1.0 + 1.0 / mss))


def test_flat_water_nadir_return_is_the_closed_form():
    """A flat horizontal water plane (mss from a 5 m/s wind) traced at single bounce: the mean
    weight per path is F(0) / (4 * 0.9 * s^2). (Every path hits the plane at near-exact nadir,
    so every path carries the same weight: the standard error is float32 noise.)"""
    mss = cox_munk_mss(5.0)
    mean, se, r_max = traced_mean_weight(water_plane(wind_speed_mps=5.0))
    expected = nadir_return_weight(WATER_INDEX_532 / AIR, mss)
    assert r_max < 20.0
    assert abs(mean - expected) <= tolerance(expected, se, r_max, mss), (mean, expected, se)


def test_nadir_return_follows_one_over_mss():
    """Winds of 0, 5 and 12 m/s: the return falls as 1 / s^2 (s^2 = 0.003, 0.0286, 0.0644),
    a factor 21 from calm to 12 m/s, and w * s^2 = F(0) / 3.6 at every wind."""
    n = WATER_INDEX_532 / AIR
    products = []
    for u in (0.0, 5.0, 12.0):
        mss = cox_munk_mss(u)
        mean, se, r_max = traced_mean_weight(water_plane(wind_speed_mps=u), n_shots=16, seed=2)
        expected = nadir_return_weight(n, mss)
        assert abs(mean - expected) <= tolerance(expected, se, r_max, mss), (u, mean, expected)
        products.append(mean * mss)
    assert np.allclose(products, fresnel_normal(n) / 3.6, rtol=2e-5)
