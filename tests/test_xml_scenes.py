"""Users' own scenes and the Python API: the example scenes in scenes/ checked against their
geometry, and every way a scene or a call used to give a silently wrong answer.

Photon-height checks use an ideal detector (no dead time, so no first-photon bias) and compare
the mean of h - z_ref with 0 at 4 standard errors (SE = sample std / sqrt(n): a false alarm
once in ~16000 runs); heights computed by ray casts are compared with closed forms at the
precision of the quadrature (millimetres).
"""
import gc
import json
import math
import pathlib
import warnings

import mitsuba as mi
import numpy as np
import pytest

from lidar_mitsuba.ground import terrain
from lidar_mitsuba.constants import ParameterError, SimulationWarning
from lidar_mitsuba.instrument import Instrument
from lidar_mitsuba.run import simulate
from lidar_mitsuba.ground.surface import SurfaceSpec
from lidar_mitsuba.track import Track

SCENES = pathlib.Path(__file__).resolve().parents[1] / "scenes"
IDEAL = Instrument(beam="strong", ideal_detector=True)
SIGMA = IDEAL.footprint_sigma_m


@pytest.fixture(autouse=True)
def _one_scene_at_a_time():
    """Collect garbage before each test here: these tests mix scenes of several shape kinds
    (meshes, PLYs, rectangles, spheres), and stale ones left alive in reference cycles join
    every kernel's shape calls. With them drjit 1.5 twice aborted this module's tests in
    longer runs (test_flipped_ply_is_diagnosed, test_no_photons_come_with_their_likely_cause:
    one callable emitted twice, "invalid redefinition of function"; see conftest.py)."""
    gc.collect()
    yield


def run(**kw):
    kw.setdefault("progress", False)
    kw.setdefault("seed", 5)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = simulate(**kw)
    res.caught = [str(w.message) for w in caught if issubclass(w.category, SimulationWarning)]
    return res


def unbiased(dh, what):
    dh = np.asarray(dh)
    assert dh.size > 30, what
    se = dh.std(ddof=1) / math.sqrt(dh.size)
    assert abs(dh.mean()) < 4 * se + 1e-4, f"{what}: {dh.mean():.4f} m, 4 SE {4 * se:.4f} m"


def signal(res):
    d = res.detections
    return d.is_signal, res.h_m[d.is_signal], d.shot[d.is_signal]


def check_reference(res, profile, near):
    """The ray casts against the geometry: the height under each footprint centre is the
    profile's (float32 precision), and the reference elevation is exactly the documented
    quadrature of the profile (midpoint rule on a 0.25 sigma grid within 5 sigma,
    :func:`lidar_mitsuba.trace.scene.raycast_reference_elevation_m`; its accuracy on smooth terrain
    is tested in test_scene.py: across the kinks of these profiles it is a few mm from the
    continuous Gaussian mean)."""
    x0 = res.shot_x_m[near]
    np.testing.assert_allclose(res.surface_z_m[near], [profile(x) for x in x0], atol=1e-4)
    k = np.arange(-20, 21) * 0.25
    gx, gy = np.meshgrid(k, k)
    disc = gx ** 2 + gy ** 2 <= 25.0
    w = np.exp(-0.5 * (gx[disc] ** 2 + gy[disc] ** 2))
    vec = np.vectorize(profile)
    expect = [np.sum(w * vec(x + gx[disc] * SIGMA)) / w.sum() for x in x0]
    np.testing.assert_allclose(res.z_ref_m[near], expect, atol=2e-4)


# ------------------------------------------------------------------------- example scenes
def test_building_scene_roof_ground_and_ridge():
    """Shapes sharing one BSDF (merged by Mitsuba): the 15 m roof is seen (it was not, when
    bounds came from the merged mesh's stale bbox), ground and roof heights are unbiased,
    the ridge's reference elevation is the Gaussian mean of its 45-degree tent."""
    res = run(scene=SCENES / "building.xml", instrument=IDEAL, shots=600)
    sig, h, shot = signal(res)
    x = res.shot_x_m[shot]
    roof = np.abs(x + 80) < 20 - 5 * SIGMA           # whole footprint on the roof
    ground = np.abs(x) < 94 - 5 * SIGMA - 60         # between building (x <= -60) and ridge
    unbiased(h[roof] - 15.0, "roof")
    unbiased(h[ground], "ground")
    assert h.max() < 15.0 + 5 * IDEAL.ranging_sigma_m
    tent = lambda u: max(0.0, 6.0 - abs(u - 100.0))  # noqa: E731
    check_reference(res, tent, np.abs(res.shot_x_m - 100) < 8)
    assert res.config["surface"]["kind"] == "scene"


def test_building_scene_parameters_from_the_api():
    """params= sets the XML's <default> values (the CLI's -D)."""
    res = run(scene=SCENES / "building.xml", params={"roof_m": 25}, instrument=IDEAL, shots=600)
    sig, h, shot = signal(res)
    roof = np.abs(res.shot_x_m[shot] + 80) < 20 - 5 * SIGMA
    unbiased(h[roof] - 25.0, "raised roof")


def test_crevasse_ply_scene():
    """A PLY mesh: the plain's photons are unbiased, the crevasses' reference elevation is the
    Gaussian mean of the V profile, and auto traces two bounces between the walls."""
    res = run(scene=SCENES / "crevasses.xml", instrument=IDEAL, shots=500)
    sig, h, shot = signal(res)
    x = res.shot_x_m[shot]
    plain = (np.abs(np.abs(x) - 60) > 5 + 5 * SIGMA) & (np.abs(x) < 200 - 5 * SIGMA)
    unbiased(h[plain], "ice plain")
    vee = lambda u: -8.0 * max(0.0, 1 - abs(abs(u) - 60.0) / 5.0)  # noqa: E731
    check_reference(res, vee, np.abs(np.abs(res.shot_x_m) - 60) < 8)
    assert res.config["max_depth"] == 2 and res.config["bounce_pilot"]["depth2_weight_fraction"] > 0


def test_textured_scene_8bit_albedo():
    """An 8-bit bitmap as rho_d (refused before: its raw 0..255 values failed the range
    check). Over a flat plate every path of a shot returns the same weight,
    (rho_d + rho_s / (4 alpha^2)) / 0.9 at nadir, so the Poisson mean of photons per shot is
    exact: 0.2 and 0.8 albedo on the two halves."""
    res = run(scene=SCENES / "textured.xml", instrument=IDEAL, shots=600)
    mu = res.detections.mean_photons_per_shot / IDEAL.signal_photons
    spec = 0.05 / (4 * 0.3 ** 2)
    left, right = res.shot_x_m < -5 * SIGMA, res.shot_x_m > 5 * SIGMA
    np.testing.assert_allclose(mu[left], (0.2 + spec) / 0.9, rtol=1e-5)
    np.testing.assert_allclose(mu[right], (0.8 + spec) / 0.9, rtol=1e-5)
    sig, h, _ = signal(res)
    unbiased(h, "textured plate")


def test_fractal_ply_scene_matches_its_heightfield():
    """scenes/fractal.xml is a strip of the p = 1.8 tile (rows y = 492 .. 532 m placed at
    y = 0 .. 40 m): its ray-cast heights are the heightfield's (the mesh is the bilinear grid
    triangulated: the footprint means differ by the triangulation, ~1 mm)."""
    hf = terrain.fractal(p=1.8, size_m=1024.0, grid_m=1.0, relief_m=10.0, seed=0)
    res = run(scene=SCENES / "fractal.xml", instrument=IDEAL, shots=800, max_depth=1)
    np.testing.assert_allclose(res.surface_z_m, hf.height_m(res.shot_x_m, 512.0), atol=1e-4)
    np.testing.assert_allclose(res.z_ref_m, hf.reference_elevation_m(
        res.shot_x_m, np.full(res.n_shots, 512.0), sigma_m=SIGMA), atol=5e-3)
    sig, h, shot = signal(res)
    unbiased(h - res.z_ref_m[shot], "fractal strip")


# ------------------------------------------------------------------------- silent wrong answers
def test_ground_plus_large_plane_fits(tmp_path):
    """An 800 m plane and a cube sharing a BSDF: 'does not fit' before (stale merged bbox)."""
    p = tmp_path / "g.xml"
    p.write_text('<scene version="3.0.0"><bsdf type="ward" id="w"/>'
                 '<shape type="rectangle"><transform name="to_world"><scale value="400"/>'
                 '</transform><ref id="w"/></shape><shape type="cube"><transform name="to_world">'
                 '<scale value="5"/><translate x="300" y="300"/></transform><ref id="w"/></shape>'
                 '</scene>')
    res = run(scene_file=str(p), instrument=IDEAL, shots=1000)
    assert res.config["surface"]["bounds_m"][1][0] == pytest.approx(400.0)
    unbiased(signal(res)[1], "800 m plane")


def test_nonperiodic_heightfield_refuses_a_longer_track_and_says_what_it_is():
    hf = terrain.fractal(p=2.0, size_m=128.0, grid_m=1.0, relief_m=2.0, seed=3)
    grid = terrain.Heightfield(z_m=hf.z_m, grid_m=1.0, periodic=False)
    with pytest.raises(ParameterError) as e:
        simulate(surface=grid, shots=300, progress=False)        # 210 m on a 127 m grid
    assert e.value.name == "shots" and "of its 300 shots" in e.value.message
    res = run(surface=grid, shots=100, instrument=IDEAL)         # 70 m fits
    cfg = res.config["surface"]
    assert cfg["kind"] == "heightfield" and cfg["periodic"] is False and "p" not in cfg
    assert np.isfinite(res.z_ref_m).all() and (res.detections.arrivals_per_shot > 0).mean() > 0.9


@pytest.mark.parametrize("kind", ["flat", "fractal"])
def test_truth_positions_share_the_track_frame(kind):
    """A 1400 m track on a 1024 m tile: every photon's scattering point lies within the
    footprint of its own shot (it was reported in tile coordinates, 26 % more than 20 m off)."""
    res = run(surface=SurfaceSpec(kind=kind, size_m=1024.0 if kind == "flat" else 256.0),
              shots=2000, max_depth=1)
    d = res.detections
    s = d.is_signal
    r = np.hypot(d.hit_xyz_m[s, 0] - res.shot_x_m[d.shot[s]],
                 d.hit_xyz_m[s, 1] - res.shot_y_m[d.shot[s]])
    assert r.max() < 6 * SIGMA


def test_scene_integrator_settings_are_honoured_or_refused(tmp_path):
    p = tmp_path / "i.xml"
    p.write_text('<scene version="3.0.0"><integrator type="pathlength">'
                 '<integer name="max_depth" value="1"/><float name="altitude_m" value="100000"/>'
                 '<float name="footprint_sigma_m" value="1.25"/></integrator>'
                 '<shape type="rectangle"><transform name="to_world"><scale value="200"/>'
                 '</transform><bsdf type="ward"/></shape></scene>')
    res = run(scene=p, instrument=IDEAL, shots=300)
    assert res.instrument.altitude_m == 1e5 and res.instrument.footprint_diameter_m == 5.0
    assert res.config["max_depth"] == 1 and res.config["scene_integrator"]["altitude_m"] == 1e5
    unbiased(signal(res)[1], "100 km altitude")             # heights use the honoured altitude
    r = np.hypot(*(res.detections.hit_xyz_m[:, :2] - np.column_stack(
        [res.shot_x_m, res.shot_y_m])[res.detections.shot]).T)
    assert r.std() < 1.5                                     # the 1.25 m footprint, not 2.5 m
    with pytest.raises(ParameterError) as e:
        simulate(scene=p, instrument=Instrument(altitude_m=2e5), shots=10, progress=False)
    assert e.value.name == "altitude_m" and "one place" in e.value.message
    with pytest.raises(ParameterError) as e:
        simulate(scene=p, max_depth=2, shots=10, progress=False)
    assert e.value.name == "max_depth"
    with pytest.raises(ParameterError) as e:
        simulate(scene=p, bsdf={"type": "diffuse"}, shots=10, progress=False)
    assert e.value.name == "bsdf"


def test_api_refuses_a_scene_object_as_a_file_name():
    s = mi.load_dict({"type": "scene", "r": {"type": "rectangle", "to_world":
                                              mi.ScalarTransform4f().scale(100)}})
    with pytest.raises(ParameterError) as e:
        simulate(scene_file=s, shots=10, progress=False)
    assert e.value.name == "scene_file" and len(str(e.value)) < 200 and "scene=" in str(e.value)
    res = run(scene=s, instrument=IDEAL, shots=200)             # the right way
    assert res.config["surface"]["scene_file"] == "mi.Scene"


FACE_DOWN = ('<shape type="rectangle"><transform name="to_world"><scale value="100"/>'
             '<rotate x="1" angle="180"/></transform><bsdf type="ward"/></shape>')
CONDUCTOR = ('<shape type="rectangle"><transform name="to_world"><scale value="100"/></transform>'
             '<bsdf type="conductor"/></shape>')
GAP = ''.join(f'<shape type="rectangle"><transform name="to_world"><scale x="100" y="5"/>'
              f'<translate y="{y}"/></transform><bsdf type="ward"/></shape>' for y in (-40, 40))


def test_a_smooth_conductor_under_the_track_is_refused_naming_water(tmp_path):
    """A perfect mirror's glint is not traced (lidar_mitsuba.trace.materials): refused, one line."""
    p = tmp_path / "m.xml"
    p.write_text(f'<scene version="3.0.0">{CONDUCTOR}</scene>')
    with pytest.raises(ParameterError, match="perfect mirror.*water"):
        run(scene=p, shots=100)


@pytest.mark.parametrize("body,cause", [
    (FACE_DOWN, "face down"), (GAP, "misses the geometry")])
def test_no_photons_come_with_their_likely_cause(tmp_path, body, cause):
    p = tmp_path / "z.xml"
    p.write_text(f'<scene version="3.0.0">{body}</scene>')
    res = run(scene=p, shots=100, instrument=Instrument(background_mhz=20.0))
    assert not res.detections.is_signal.any()
    assert any(cause in w for w in res.caught), res.caught
    assert res.config["warnings"] == res.caught
    # the shots still record background noise in their range gate
    assert (~res.detections.is_signal).sum() > 0


def test_flipped_ply_is_diagnosed(tmp_path):
    import trimesh
    tm = trimesh.load(SCENES / "crevasses.ply", process=False)
    tm.faces = tm.faces[:, ::-1]
    tm.export(tmp_path / "flipped.ply", file_type="ply", encoding="binary")
    (tmp_path / "f.xml").write_text('<scene version="3.0.0"><shape type="ply"><string '
                                    'name="filename" value="flipped.ply"/><bsdf type="ward"/>'
                                    '</shape></scene>')
    res = run(scene=tmp_path / "f.xml", shots=100)
    assert any("face down" in w for w in res.caught), res.caught


def test_shots_without_surface_record_noise_and_are_counted():
    """Half of a track runs off a scene's geometry (inside its bounding box): those shots
    record only background, whose rate matches the closed form, and a warning counts them."""
    s = mi.load_string('<scene version="3.0.0"><shape type="rectangle"><transform name="to_world">'
                       '<scale x="50" y="50"/><translate x="-50"/></transform><bsdf type="ward"/>'
                       '</shape><shape type="rectangle"><transform name="to_world"><scale value="1"/>'
                       '<translate x="95" y="49"/></transform><bsdf type="ward"/></shape></scene>')
    inst = Instrument(background_mhz=50.0, ideal_detector=True)
    res = run(scene=s, instrument=inst, shots=200, track=Track(start_xy_m=(-60.0, 0.0)))
    off = ~np.isfinite(res.surface_z_m)
    assert 0.3 < off.mean() < 0.7
    assert any(f"{int(off.sum())} of the 200 shots have no surface" in w for w in res.caught)
    d = res.detections
    noise_off = np.isin(d.shot, np.nonzero(off)[0]).sum()
    expect = off.sum() * inst.noise_per_shot[0] * inst.fill_factor * inst.pde
    assert abs(noise_off - expect) < 4 * math.sqrt(expect)      # Poisson count, 4 sigma


def test_track_control_heading_offset_and_start():
    res = run(scene=SCENES / "building.xml", instrument=IDEAL, shots=120,
              track=Track(heading_deg=90.0, offset_m=80.0))    # along +y, 80 m left: x = -80
    np.testing.assert_allclose(res.shot_x_m, -80.0, atol=1e-9)
    np.testing.assert_allclose(np.diff(res.shot_y_m), 0.7)
    assert res.shot_y_m.mean() == pytest.approx(0.0, abs=1e-9)
    sig, h, shot = signal(res)
    on_roof = np.abs(res.shot_y_m[shot]) < 20 - 5 * SIGMA
    unbiased(h[on_roof] - 15.0, "roof, across the track")
    res = run(surface=SurfaceSpec(kind="flat"), shots=50, track=Track(start_xy_m=(10.0, 20.0)))
    assert (res.shot_x_m[0], res.shot_y_m[0]) == (10.0, 20.0)
    assert json.loads(json.dumps(res.config))["track"]["start_xy_m"] == [10.0, 20.0]
