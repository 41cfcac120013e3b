"""Water and air: the mediapathlength integrator against closed forms, and simulate()'s choice
of model from a scene's materials (lidar_mitsuba.trace.materials).

Every Monte Carlo check compares a mean over iid shots with its closed form within four
standard errors, the standard error taken from the spread of the per-shot means (the shots
are independent; the paths of one shot share nothing either, but the per-shot mean is what
the detector uses). Fixed seeds.
"""
import numpy as np
import pytest

import mitsuba as mi

from lidar_mitsuba.trace import materials
from lidar_mitsuba.constants import C_M_PER_NS, ParameterError
from lidar_mitsuba.run import simulate

T = mi.ScalarTransform4f
ALT_M = 496e3


def _plate(z=0.0, albedo=0.9, size=200.0):
    return {"type": "rectangle", "to_world": T().translate([0, 0, z]).scale([size, size, 1]),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "uniform", "value": albedo}}}


def _layer_scene(*, tau, height_m=20.0, base_m=10.0, albedo=0.0, g=0.0):
    """A Lambertian 0.9 ground under a homogeneous layer ``base_m`` .. ``base_m + height_m``
    above it, of vertical optical depth ``tau``."""
    return mi.load_dict({"type": "scene", "ground": _plate(),
                         "layer": {"type": "cube", "bsdf": {"type": "null"},
                                   "to_world": T().translate([0, 0, base_m + height_m / 2])
                                   .scale([150, 150, height_m / 2]),
                                   "interior": {"type": "homogeneous",
                                                "sigma_t": tau / height_m, "albedo": albedo,
                                                "phase": {"type": "hg", "g": g}}}})


def _trace(scene, *, shots, paths, seed, max_depth=8, **kw):
    integ = mi.load_dict({"type": "mediapathlength", "max_depth": max_depth, **kw})
    return integ.trace(scene, shot_x_m=np.zeros(shots), shot_y_m=np.zeros(shots),
                       paths_per_shot=paths, seed=seed)


def _mean_and_se(r, keep):
    """Mean return weight per path of the returns ``keep``, and its standard error over
    shots."""
    per_shot = np.bincount(r.shot[keep], weights=r.weight[keep], minlength=r.n_shots)
    per_shot /= r.paths_per_shot
    return per_shot.mean(), per_shot.std(ddof=1) / np.sqrt(r.n_shots)


@pytest.mark.parametrize("tau", [0.3, 1.0])
def test_ground_through_an_absorbing_layer_is_two_way_beer_lambert(tau):
    r = _trace(_layer_scene(tau=tau), shots=2000, paths=32, seed=1)
    mean, se = _mean_and_se(r, np.ones(r.weight.size, bool))
    closed = np.exp(-2 * tau)                        # a 0.9 plate weighs 1 in clear air
    assert abs(mean - closed) < 4 * se + 1e-6, (mean, se, closed)
    assert np.all(r.z_m < 1.0)                       # nothing comes back from the layer


@pytest.mark.parametrize("g", [0.0, 0.6])
def test_layer_single_scattering_is_the_lidar_equation(g):
    """The first vertex in a layer of extinction s_t, scattering s_s, thickness H:
    E[w] = s_s p(180 deg) (1 - exp(-2 s_t H)) / (2 s_t) pi / 0.9, with Henyey-Greenstein's
    backscatter p = (1 - g) / (4 pi (1 + g)^2)."""
    tau, h, alb = 0.5, 20.0, 0.9
    r = _trace(_layer_scene(tau=tau, albedo=alb, g=g, height_m=h), shots=3000, paths=32,
               seed=2)
    first_in_layer = (r.depth == 1) & (r.z_m > 5.0)
    mean, se = _mean_and_se(r, first_in_layer)
    st = tau / h
    p_back = (1 - g) / (4 * np.pi * (1 + g) ** 2)
    closed = alb * st * p_back * (1 - np.exp(-2 * tau)) / (2 * st) * np.pi / 0.9
    assert abs(mean - closed) < 4 * se, (mean, se, closed)
    # the ground's unscattered return is still Beer-Lambert's
    ground1 = (r.depth == 1) & (r.z_m < 1.0)
    gm, gse = _mean_and_se(r, ground1)
    assert abs(gm - np.exp(-2 * tau)) < 4 * gse + 1e-6


def test_forward_scattering_brings_late_ground_light():
    """Light scattered forward in a cloud reaches the ground late: the ground's returns after a
    scattering (depth > 1) add to Beer-Lambert's and all come later than the unscattered ones
    of the same ground (their path is longer)."""
    r = _trace(_layer_scene(tau=1.0, albedo=1.0, g=0.85, height_m=100.0, base_m=50.0),
               shots=1500, paths=32, seed=3, pulse_sigma_ns=0.0)
    ground = r.z_m < 1.0
    direct = ground & (r.depth == 1)
    scattered = ground & (r.depth > 1)
    assert _mean_and_se(r, scattered)[0] > 0.05
    t0 = np.median(r.time_ns[direct])
    assert np.all(r.time_ns[direct] - t0 < 1e-3)          # one plane, no pulse: one time
    assert np.min(r.time_ns[scattered]) > t0 - 1e-3
    assert np.average(r.time_ns[scattered], weights=r.weight[scattered]) > t0 + 0.01


def _lake(bsdf, *, depth_m=1.0, rho=0.5):
    return mi.load_dict({"type": "scene",
                         "surface": {"type": "rectangle", "bsdf": bsdf,
                                     "to_world": T().scale([200, 200, 1])},
                         "bottom": _plate(z=-depth_m, albedo=rho)})


def test_lake_bottom_at_group_index_times_depth_with_t2_rho_over_n2():
    """Under water the light travels at c / n_g: the bottom's returns lie n_g x depth below the
    surface's (Parrish et al. 2019; no pulse, so each return's range is exact). Brightness:
    T^2 rho / n^2 of a plate (in and out through the surface, the radiance's n^2 law),
    within the sampling error plus the roughness's effect (mss 0.01 against mss 4e-4 in
    this test's set-up: 1e-4 of the value; allowed 0.5 %). The bottom is the path's second
    vertex: its way out through the surface is sampled there."""
    n, n_g, depth, rho = 1.333, 1.35, 1.5, 0.5
    scene = _lake({"type": "water", "mss": 0.01, "int_ior": n, "group_index": n_g},
                  depth_m=depth, rho=rho)
    r = _trace(scene, shots=4000, paths=32, seed=4, max_depth=2, pulse_sigma_ns=0.0)
    bottom = r.depth == 2
    range_m = (r.time_ns[bottom] * C_M_PER_NS / 2) - ALT_M
    apparent = np.average(range_m, weights=r.weight[bottom])
    # the slant of the paths under a surface of rms slope 0.1 lengthens them by < 0.1 %
    assert apparent == pytest.approx(n_g * depth, rel=2e-3)
    mean, se = _mean_and_se(r, bottom)
    fresnel = ((n - 1) / (n + 1)) ** 2
    closed = (1 - fresnel) ** 2 * rho / n ** 2 / 0.9
    assert abs(mean - closed) < 4 * se + 0.005 * closed, (mean, se, closed)
    # the surface itself: Cox-Munk's nadir return F(0) / (4 s^2 0.9)
    smean, sse = _mean_and_se(r, r.depth == 1)
    assert abs(smean - fresnel / (4 * 0.01 * 0.9)) < 4 * sse + 0.01 * smean


def test_materials_sort_a_scene():
    fog = _layer_scene(tau=0.3, albedo=0.9)
    m = materials.inspect(fog)
    assert m.needs_media_tracer and m.air_layers and m.snow is None and m.min_depth(20.0) >= 3
    assert m.air_layers[0].optical_depth == pytest.approx(0.3, rel=1e-5)
    lake = materials.inspect(_lake({"type": "water"}))
    assert lake.interfaces and lake.min_depth(20.0) == 4 and not lake.mirrors
    assert lake.interfaces[0].group_index > lake.interfaces[0].phase_index > 1.3
    mirror = materials.inspect(_lake({"type": "dielectric", "int_ior": 1.333}))
    assert mirror.mirrors == ("surface",)
    plain = materials.inspect(mi.load_dict({"type": "scene", "g": _plate()}))
    assert not plain.needs_media_tracer and plain.min_depth(20.0) == 1


def test_simulate_picks_the_media_tracer_and_sees_the_ground_through_fog():
    """Default flags on the fog scene: mediapathlength, heights of the ground (not the layer's
    top), and the ground's photons reduced by about Beer-Lambert's two-way factor."""
    clear = simulate(scene_file="scenes/fog.xml", params={"tau": "0.0001"}, shots=400,
                     seed=5, progress=False)
    foggy = simulate(scene_file="scenes/fog.xml", params={"tau": "0.5"}, shots=400, seed=5,
                     progress=False)
    assert foggy.config["integrator"] == "mediapathlength"
    assert np.allclose(foggy.surface_z_m, 0.0, atol=1e-4)
    n_clear = clear.detections.is_signal.sum()
    n_fog = foggy.detections.is_signal.sum()
    # detected (dead time aside) ~ Poisson: exp(-1) = 0.37 direct plus forward-scattered light
    assert np.exp(-1.0) * 0.9 < n_fog / n_clear < 0.85
    assert any("layer in the air" in c for c in foggy.config["choices"])


def test_simulate_on_a_pond_finds_the_bottom_with_default_flags():
    res = simulate(scene_file="scenes/melt_pond.xml", params={"depth_m": "2"}, shots=300,
                   seed=6, progress=False)
    assert res.config["integrator"] == "mediapathlength" and res.config["max_depth"] >= 3
    dh = res.dh_m[res.detections.is_signal]
    n_g = float(materials.inspect(mi.load_file("scenes/melt_pond.xml", depth_m="2"))
                .interfaces[0].group_index)
    bottom = np.abs(dh + n_g * 2.0) < 0.3
    assert bottom.sum() > 50
    assert np.median(dh[bottom]) == pytest.approx(-n_g * 2.0, abs=0.03)


def test_a_perfect_mirror_under_the_track_is_refused_with_the_fix():
    scene = {"type": "scene", "lead": {"type": "rectangle", "to_world": T().scale([600] * 3),
                                       "bsdf": {"type": "dielectric", "int_ior": 1.333}}}
    with pytest.raises(ParameterError, match="water") as e:
        simulate(scene=scene, shots=100, progress=False)
    assert e.value.name == "scene" and "\n" not in str(e.value)


def _apparent_height_m(r):
    return ALT_M - r.time_ns * C_M_PER_NS / 2


@pytest.mark.parametrize("base_m,cheap", [(1000.0, True), (50.0, False)])
def test_attenuation_only_for_a_thin_cloud_high_above(base_m, cheap):
    """A cloud whose forward-scattered light lands outside the field of view needs one vertex
    (Beer-Lambert both ways): the materials choose it, and the full trace (8 vertices) puts
    what ``Layer.forward_share`` estimates (below 1 %) and no measurable delay on the
    ground's return within the range gate. The same layer low over the ground is where the
    cheap model fails: it misses more than 5 % of the ground's light."""
    tau, h = 0.3, 200.0
    scene = mi.load_dict({"type": "scene", "ground": _plate(size=3000.0),
                          "layer": {"type": "cube", "bsdf": {"type": "null"},
                                    "to_world": T().translate([0, 0, base_m + h / 2])
                                    .scale([5000, 5000, h / 2]),
                                    "interior": {"type": "homogeneous", "sigma_t": tau / h,
                                                 "albedo": 1.0,
                                                 "phase": {"type": "hg", "g": 0.85}}}})
    mats = materials.inspect(scene)
    fov_r = 20.65
    assert (mats.min_depth(fov_r) == 1) == cheap
    share = mats.air_layers[0].forward_share(fov_r)
    full = _trace(scene, shots=2000, paths=32, seed=7, max_depth=8, pulse_sigma_ns=0.0)
    one = _trace(scene, shots=2000, paths=32, seed=7, max_depth=1, pulse_sigma_ns=0.0)
    gate = [np.abs(_apparent_height_m(r)) < 15.0 for r in (full, one)]
    (w_full, se_full), (w_one, se_one) = (_mean_and_se(r, g) for r, g in zip((full, one), gate))
    assert abs(w_one - np.exp(-2 * tau)) < 4 * se_one                # Beer-Lambert
    missed = (w_full - w_one) / w_one
    if cheap:
        assert missed < share + 4 * se_full / w_one and share < 0.01
        h_full = np.average(_apparent_height_m(full)[gate[0]], weights=full.weight[gate[0]])
        assert abs(h_full) < 0.01
    else:
        assert missed > 0.05 and share > 0.01
