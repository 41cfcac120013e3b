"""The path-length integrator and the pipeline on surfaces with closed forms.

Monte Carlo tolerances: Z = 4.5 standard errors computed from the sample (sigma/sqrt(n) for a
mean, sigma/sqrt(2n) for the standard deviation of Gaussian residuals, binomial for fractions).
"""
import math
import pathlib

import mitsuba as mi
import numpy as np
import pytest

from lidar_mitsuba.constants import C_M_PER_NS
from lidar_mitsuba.instrument import Instrument
from lidar_mitsuba.run import simulate
from lidar_mitsuba.ground.surface import SurfaceSpec

Z = 4.5
SCENES = pathlib.Path(__file__).resolve().parents[1] / "scenes"


def plate(z0=0.0, half=200.0, bsdf=None):
    bsdf = bsdf or {"type": "diffuse", "reflectance": 0.9}
    return mi.load_dict({"type": "scene", "plate": {
        "type": "rectangle", "bsdf": bsdf,
        "to_world": mi.ScalarTransform4f().translate([0, 0, z0]).scale(half)}})


def integrator(**kw):
    return mi.load_dict({"type": "pathlength", **kw})


def test_lambertian_plate_weighs_one_and_ward_closed_form():
    xs = np.linspace(-50, 50, 11)
    out = integrator().trace(plate(), shot_x_m=xs, shot_y_m=np.zeros(11), paths_per_shot=64)
    assert out.weight.size == 11 * 64
    assert np.allclose(out.weight, 1.0, atol=1e-5)
    rho_d, rho_s, alpha = 0.8, 0.1, 0.25
    ward = {"type": "ward", "rho_d": rho_d, "rho_s": rho_s, "alpha": alpha}
    out = integrator().trace(plate(bsdf=ward), shot_x_m=xs, shot_y_m=np.zeros(11), paths_per_shot=64)
    expect = math.pi * (rho_d / math.pi + rho_s / (4 * math.pi * alpha ** 2)) / 0.9   # eq. 9, h = n
    assert np.allclose(out.weight, expect, rtol=1e-4)


@pytest.mark.parametrize("z0", [0.0, 0.0005, 1234.567, -85.25])
def test_path_length_exact_at_orbit(z0):
    """496 km range to sub-millimetre: zero footprint and pulse -> c t / 2 == H - z0, and with a
    footprint the two legs equal the float64 distance to the hit point."""
    H = 496e3
    xs = np.array([-100.0, -3.3, 0.0, 7.77, 150.0])
    out = integrator(footprint_sigma_m=0.0, pulse_sigma_ns=0.0, altitude_m=H).trace(
        plate(z0), shot_x_m=xs, shot_y_m=xs[::-1], paths_per_shot=4)
    z_exact = np.float64(np.float32(z0))       # the plate sits at z0 rounded to float32
    err_m = C_M_PER_NS * out.time_ns / 2 - (H - z_exact)
    assert np.max(np.abs(err_m)) < 1e-3
    # in fact the error is one float32 rounding of the hit point's scene coordinates
    assert np.max(np.abs(err_m)) < 2 * np.spacing(np.float32(abs(z0) + 150.0)) + 1e-6
    out = integrator(footprint_sigma_m=2.5, pulse_sigma_ns=0.0, altitude_m=H).trace(
        plate(z0), shot_x_m=xs, shot_y_m=xs[::-1], paths_per_shot=256)
    sx = xs[out.shot]
    sy = xs[::-1][out.shot]
    leg = np.sqrt((out.x_m - sx) ** 2 + (out.y_m - sy) ** 2 + (H - z_exact) ** 2)
    assert np.max(np.abs(C_M_PER_NS * out.time_ns / 2 - leg)) < 1e-3


def test_footprint_and_pulse_are_gaussian():
    """Hit offsets ~ N(0, sigma_fp) per axis; times ~ N(2H/c, sigma_t): sample mean and sd."""
    out = integrator().trace(plate(), shot_x_m=np.zeros(2000), shot_y_m=np.zeros(2000),
                             paths_per_shot=64, seed=3)
    n = out.x_m.size
    for v, sd in ((out.x_m, 2.5), (out.y_m, 2.5),
                  (out.time_ns - 2 * 496e3 / C_M_PER_NS, 1 / 2.3548200450309493)):
        assert abs(v.mean()) < Z * sd / math.sqrt(n)
        assert abs(v.std() - sd) < Z * sd / math.sqrt(2 * n)


def test_occlusion_first_surface_wins():
    """A raised ledge over x > 0 hides the ground beneath it."""
    ledge = {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": 0.9},
             "to_world": mi.ScalarTransform4f().translate([50, 0, 5]).scale([50, 50, 1])}
    scene = mi.load_dict({"type": "scene", "ground": {
        "type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": 0.9},
        "to_world": mi.ScalarTransform4f().scale(100)}, "ledge": ledge})
    out = integrator().trace(scene, shot_x_m=np.zeros(500), shot_y_m=np.zeros(500), paths_per_shot=64)
    x, z = out.x_m, out.z_m
    assert np.all(np.isclose(z[x > 1e-3], 5.0))
    assert np.all(np.isclose(z[x < -1e-3], 0.0))
    frac = np.mean(z > 2.5)
    assert abs(frac - 0.5) < Z * math.sqrt(0.25 / z.size)


def test_max_depth_adds_only_real_bounces():
    """On a plane nothing bounces twice: max_depth 3 equals max_depth 1. In a V-trench,
    second bounces exist, arrive later and are shadow-tested toward the receiver."""
    xs = np.zeros(300)
    a = integrator(max_depth=1).trace(plate(), shot_x_m=xs, shot_y_m=xs, paths_per_shot=64, seed=5)
    b = integrator(max_depth=3).trace(plate(), shot_x_m=xs, shot_y_m=xs, paths_per_shot=64, seed=5)
    assert np.array_equal(a.time_ns, b.time_ns) and b.depth.max() == 1
    v = {"type": "scene"}
    for name, angle in (("left", 60), ("right", -60)):
        v[name] = {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": 0.9},
                   "to_world": mi.ScalarTransform4f().rotate([0, 1, 0], angle).translate(
                       [0, 0, 0]).scale([20, 50, 1])}
    v["left"]["to_world"] = mi.ScalarTransform4f().translate([-10, 0, 17.32]).rotate([0, 1, 0], 60).scale([20, 50, 1])
    v["right"]["to_world"] = mi.ScalarTransform4f().translate([10, 0, 17.32]).rotate([0, 1, 0], -60).scale([20, 50, 1])
    trench = mi.load_dict(v)
    out = integrator(max_depth=2).trace(trench, shot_x_m=xs, shot_y_m=xs, paths_per_shot=64, seed=5)
    d1, d2 = out.depth == 1, out.depth == 2
    assert d1.any() and d2.any()
    assert np.all(np.isfinite(out.weight)) and np.all(out.weight >= 0)
    assert np.median(out.time_ns[d2]) > np.median(out.time_ns[d1])


def test_any_mitsuba_bsdf_and_seeds():
    xs = np.zeros(50)
    for bsdf in ({"type": "roughplastic"}, {"type": "roughconductor"}, {"type": "diffuse"}):
        out = integrator().trace(plate(bsdf=bsdf), shot_x_m=xs, shot_y_m=xs, paths_per_shot=32)
        assert out.weight.size > 0 and np.all(np.isfinite(out.weight))
    a = integrator().trace(plate(), shot_x_m=xs, shot_y_m=xs, paths_per_shot=32, seed=1)
    b = integrator().trace(plate(), shot_x_m=xs, shot_y_m=xs, paths_per_shot=32, seed=1)
    c = integrator().trace(plate(), shot_x_m=xs, shot_y_m=xs, paths_per_shot=32, seed=2)
    assert np.array_equal(a.time_ns, b.time_ns)
    assert not np.array_equal(a.time_ns, c.time_ns)


def test_chunking_matches_one_launch():
    xs = np.arange(100.0) - 50
    one = integrator().trace(plate(), shot_x_m=xs, shot_y_m=0 * xs, paths_per_shot=16, seed=4)
    many = integrator(max_lanes=16 * 7).trace(plate(), shot_x_m=xs, shot_y_m=0 * xs,
                                                paths_per_shot=16, seed=4)
    assert np.array_equal(one.shot, many.shot)
    assert many.shot.max() == 99


def test_flat_plate_ideal_detector_unbiased():
    """Ideal detector over a flat plate: unbiased, spread c sigma_t / 2 = 6.37 cm."""
    inst = Instrument(beam="weak", ideal_detector=True)
    res = simulate(instrument=inst, surface=SurfaceSpec(kind="flat"), shots=20000, seed=11,
                   progress=False)
    st = res.report().overall
    sd = inst.ranging_sigma_m
    assert abs(sd - 0.06366) < 1e-4
    assert abs(st.bias_m) < Z * sd / math.sqrt(st.n_photons)
    assert abs(st.std_m - sd) < Z * sd / math.sqrt(2 * st.n_photons)


@pytest.mark.parametrize("slope_deg", [5.0, 10.0])
def test_slope_spread_closed_form(slope_deg):
    """Plane of slope theta: sqrt((c sigma_t / 2)^2 + (sigma_fp tan theta)^2), unbiased."""
    inst = Instrument(beam="strong", ideal_detector=True)
    res = simulate(instrument=inst, surface=SurfaceSpec(kind="slope", slope_deg=slope_deg),
                   shots=4000, seed=12, progress=False)
    st = res.report().overall
    sd = math.hypot(inst.ranging_sigma_m, inst.footprint_sigma_m * math.tan(math.radians(slope_deg)))
    assert abs(st.bias_m) < Z * sd / math.sqrt(st.n_photons)
    assert abs(st.std_m - sd) < Z * sd / math.sqrt(2 * st.n_photons)


def test_long_sloped_track_wraps_exactly():
    """A track longer than the tile folds into it; photon heights follow the unwrapped plane."""
    res = simulate(instrument=Instrument(ideal_detector=True),
                   surface=SurfaceSpec(kind="slope", slope_deg=3.0, size_m=100.0),
                   shots=1000, seed=2, progress=False)       # 700 m track over a 100 m tile
    assert np.ptp(res.z_ref_m) > 30
    st = res.report().overall
    sd = math.hypot(0.06366, 2.5 * math.tan(math.radians(3.0)))
    assert abs(st.bias_m) < Z * sd / math.sqrt(st.n_photons)


@pytest.mark.parametrize("name", ["flat", "slope", "fractal"])
def test_xml_scenes_load_and_simulate(name):
    scene = mi.load_file(str(SCENES / f"{name}.xml"))
    assert isinstance(scene.integrator(), mi.Integrator)
    res = simulate(scene_file=str(SCENES / f"{name}.xml"), shots=200, seed=1, progress=False)
    st = res.report().overall
    assert st.n_photons > 100 and np.isfinite(st.bias_m)
    assert np.all(np.isfinite(res.z_ref_m))


def test_chunked_run_keeps_statistics_and_bounds_memory():
    """Shots traced and detected in chunks: every chunk has its own photons, the closed form
    still holds, and the traced returns can be dropped."""
    inst = Instrument(beam="weak", ideal_detector=True)
    res = simulate(instrument=inst, surface=SurfaceSpec(kind="flat"), shots=6000, seed=4,
                   chunk_shots=700, keep_returns=False, progress=False)
    assert res.returns is None
    st = res.report().overall
    sd = inst.ranging_sigma_m
    assert abs(st.bias_m) < Z * sd / math.sqrt(st.n_photons)
    assert abs(st.std_m - sd) < Z * sd / math.sqrt(2 * st.n_photons)
    # chunks do not repeat each other's photons
    d = res.detections
    first, second = d.time_ns[d.shot < 700], d.time_ns[(d.shot >= 700) & (d.shot < 1400)]
    assert not np.intersect1d(first, second).size
    assert np.all(np.isfinite(res.detections.hit_xyz_m[d.is_signal]))
    kept = simulate(instrument=inst, surface=SurfaceSpec(kind="flat"), shots=300, seed=4,
                    chunk_shots=100, keep_returns=True, progress=False)
    assert kept.returns.shot.max() == 299
    assert np.array_equal(kept.returns.z_m[kept.detections.return_index], kept.detections.hit_xyz_m[:, 2])


@pytest.mark.parametrize("shots,size_m", [(400, 1024.0), (1500, 256.0)])
def test_corridor_crop_gives_the_full_tiles_photons(shots, size_m):
    """Meshing only the track corridor changes nothing the photons see: the same photons as the
    full tile (to float32 rounding of the ray start), from far fewer triangles. The second case
    is a track longer than the tile (it wraps)."""
    kw = dict(instrument=Instrument(beam="strong"), shots=shots, seed=9, progress=False,
              surface=SurfaceSpec(kind="fractal", p=1.7, size_m=size_m))
    full = simulate(crop_to_track=False, **kw)
    crop = simulate(crop_to_track=True, **kw)
    assert crop.config["surface"]["mesh_triangles"] <= full.config["surface"]["mesh_triangles"]
    assert np.array_equal(full.detections.shot, crop.detections.shot)
    assert np.allclose(full.h_m, crop.h_m, atol=1e-4)


def _square(z0, tilt=0.0, half=300.0):
    """Two triangles, ``half`` [m] about the origin, at height ``z0`` [m], sloped by ``tilt``."""
    v = np.array([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]], float)
    v[:, 2] = z0 + tilt * v[:, 0]
    return v, np.array([[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("kind", ["single", "two_bounces", "snow"])
def test_new_terrain_reuses_the_compiled_trace(kind):
    """A long DEM track is traced tile by tile, each tile a new scene at its own height: the
    trace must compile once, not once per tile (an orbit has thousands of tiles, ~0.2 s of
    LLVM each), and a BRDF or snow study changes only the material's numbers. Tracing a
    second and a third mesh, at other heights and slopes, the third with another Ward BRDF
    or a shallower, lighter snowpack, launches no kernel the first trace did not (Dr.Jit's kernel history: kernels are named by the hash
    of their code, so a value baked in as a constant would show as a new hash)."""
    import gc

    import drjit as dr
    from lidar_mitsuba.ground import snow
    from lidar_mitsuba.ground.brdf import ward_bsdf_dict
    from lidar_mitsuba.trace.scene import scene_from_mesh
    vol = snow.snow_from_grains(grain_radius_um=200) if kind == "snow" else None
    other = (snow.snow_from_grains(grain_radius_um=200, density_kg_m3=250, depth_m=0.5)
             if vol is not None else ward_bsdf_dict(rho_d=0.6, rho_s=0.1, alpha=0.2))
    xs = np.linspace(-40, 40, 64)
    runs = []
    for z0, tilt, bsdf in ((0.0, 0.0, vol), (37.25, 0.0, vol), (-812.5, 0.1, other)):
        gc.collect()            # one terrain alive at a time, as tile after tile of a track
        sc = scene_from_mesh(*_square(z0, tilt), bsdf=bsdf)
        integ = (mi.load_dict(bsdf.integrator_params()) if vol is not None else
                 integrator(max_depth=2 if kind == "two_bounces" else 1))
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory):
            out = integ.trace(sc, shot_x_m=xs, shot_y_m=np.zeros(64), paths_per_shot=8, seed=3)
            hist = dr.kernel_history([dr.KernelType.JIT])
        assert len(out) > 0
        runs.append({h["hash"] for h in hist})
        del sc, out, integ
    assert runs[1] <= runs[0] and runs[2] <= runs[0], (runs[1] - runs[0], runs[2] - runs[0])


@pytest.mark.parametrize("divisor", [1, 3, 16, 255, 1000, 12345, 2 ** 20 - 1, 2 ** 20])
def test_shot_index_without_integer_division_is_exact(divisor):
    """The float64 quotient that gives a lane its shot equals integer division over the whole
    uint32 range it can meet (the lanes of one launch, and the top of the range)."""
    import lidar_mitsuba_plugins
    _quotient = lidar_mitsuba_plugins.module("pathlength")._quotient
    i = np.concatenate([np.arange(0, 2 ** 21), np.arange(2 ** 30 - 2 ** 20, 2 ** 30),
                        np.arange(2 ** 32 - 2 ** 20, 2 ** 32)]).astype(np.uint32)
    np.testing.assert_array_equal(_quotient(mi.UInt32(i), divisor).numpy(), i // divisor)
