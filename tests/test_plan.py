"""A run is a plan and a stream (issue 33): ``lm.plan`` decides everything before a photon is
traced and returns a frozen, printable ``RunPlan``; ``lm.stream`` traces and detects it;
``lm.assemble`` makes the result; ``lm.simulate`` is exactly the three."""
import dataclasses

import h5py

import numpy as np
import pytest

import lidar_mitsuba as lm


def test_plan_stream_assemble_is_simulate_to_the_bit():
    kw = dict(surface=lm.SurfaceSpec(kind="fractal", p=1.8, size_m=256.0), shots=400, seed=3,
              progress=False)
    p = lm.plan(**kw)
    res = lm.assemble(p, lm.stream(p))
    ref = lm.simulate(**kw)
    assert np.array_equal(res.h_m, ref.h_m) and np.array_equal(res.detections.shot,
                                                               ref.detections.shot)
    assert res.config["max_depth"] == p.max_depth and res.config["plan"] == p.describe()


def test_the_plan_is_frozen_and_says_what_it_chose():
    p = lm.plan(scene="scenes/melt_pond.xml", params={"depth_m": "2"}, shots=200,
                progress=False)
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.max_depth = 1
    text = str(p)
    assert "mediapathlength" in text and "interfaces" in text and "200 shots" in text
    assert p.max_depth == 8 and p.paths_per_shot >= 8
    assert p.x_m.shape == p.z_ref_m.shape == (200,)


# --------------------------------------------------------------------------- materials as types
def test_each_material_chooses_its_own_tracer():
    """The planner asks the run's material, and nothing else, which integrator traces it, how
    many vertices a path needs and how many records a path leaves (issue 33)."""
    from lidar_mitsuba.ground.materials import Reflector, Snow
    from lidar_mitsuba.trace.materials import SceneMaterials
    flat = dict(surface=lm.SurfaceSpec(kind="flat"), shots=50, progress=False)
    p = lm.plan(**flat)
    assert isinstance(p.material, Reflector) and p.integrator_dict["type"] == "pathlength"
    assert p.max_depth == 1 and p.material.returns_per_path(2) == 2 and p.snow is None
    snow = lm.snow_from_grains(grain_radius_um=200)
    k = lm.plan(**flat, snow=snow)
    assert isinstance(k.material, Snow) and k.material.model == "kernel" and k.snow is snow
    assert k.integrator_dict["type"] == "snowkernel" and k.material.table is not None
    assert k.max_depth == snow.events_cap and k.material.returns_per_path(k.max_depth) == 1
    w = lm.plan(**flat, snow=snow, snow_model="walk", paths_per_shot=4)
    assert w.integrator_dict["type"] == "volpathlength"
    assert w.integrator_dict["max_depth"] == snow.events_cap
    pond = lm.plan(scene="scenes/melt_pond.xml", shots=50, progress=False, paths_per_shot=4)
    assert isinstance(pond.material, SceneMaterials) and pond.material.interfaces
    assert pond.integrator_dict["type"] == "mediapathlength" and not pond.material.volume
    fog = lm.plan(scene="scenes/fog.xml", shots=50, progress=False, paths_per_shot=4)
    assert fog.material.gated and not pond.material.gated
    # a result's config says what the material chose, whatever its kind
    assert Reflector({"type": "diffuse"}).config() == {"snow": None, "snow_model": None,
                                                      "snow_kernel": None}


# --------------------------------------------------------------------------- a plan's sections
@pytest.fixture(scope="module")
def dem_surface(tmp_path_factory):
    from lidar_mitsuba.ground import dem as dems
    path = dems.synthetic_ice_sheet(tmp_path_factory.mktemp("dem") / "ice.tif")
    return dems.DEMSurface(dems.DEM.open(path), tile_shots=256)


def test_a_section_of_a_plan_is_the_plan_of_its_shots(dem_surface):
    """``plan.section(track, ...)``: the next shots laid out with the plan's model; their
    positions, heights, references, tiles and radiometry are those a plan of those shots alone
    would have (to the bit), and streamed, they trace the same photons."""
    from lidar_mitsuba import granule
    track = lm.GeoTrack(start_lat_deg=69.97, start_lon_deg=-45.0, azimuth_deg=0.0)
    ctx = granule._Context(dem_surface, track, None, "atlas")
    beam = lm.geotrack.select_beams("gt2r", 0)[0]
    first = ctx.plan(beam, 300, seed=1, progress=False)
    part = first.section(ctx.projected(beam, 300, 400), shots=400, seed=9)
    alone = lm.plan(instrument=ctx.instrument(beam), surface=ctx.surface,
                    track=ctx.projected(beam, 300, 400), shots=400, seed=9, progress=False,
                    max_depth=first.max_depth, paths_per_shot=first.paths_per_shot)
    assert part.shots == 400 and part.track.to_dict()["first_shot"] == 300
    assert part.integrator is first.integrator and part.bounce_pilot == first.bounce_pilot
    for f in ("x_m", "along_m", "x_local_m", "surface_z_m", "z_ref_m", "gate_z_m", "reach_m",
              "max_depth", "paths_per_shot", "chunk_shots", "triangles"):
        np.testing.assert_array_equal(getattr(part, f), getattr(alone, f), err_msg=f)
    np.testing.assert_array_equal(part.radiometry.background_mhz,
                                  alone.radiometry.background_mhz)
    a, b = lm.stream(part), lm.stream(alone)
    np.testing.assert_array_equal(a.detections["run"].time_ns, b.detections["run"].time_ns)


def test_a_streamed_granule_plans_each_beam_once(dem_surface, tmp_path, monkeypatch):
    """Three sections of two beams: two plans (one per beam, on its first section), the
    other sections laid out with them; memory is a section's."""
    from lidar_mitsuba import granule, planning
    calls, sections = [], []
    real, real_section = planning.plan, planning.RunPlan.section
    monkeypatch.setattr(planning, "plan", lambda **kw: calls.append(kw["shots"]) or real(**kw))
    monkeypatch.setattr(planning.RunPlan, "section", lambda self, track, **kw: (
        sections.append(kw["shots"]) or real_section(self, track, **kw)))
    track = lm.GeoTrack(start_lat_deg=69.97, start_lon_deg=-45.0, azimuth_deg=0.0)
    out = granule.stream_granule(surface=dem_surface, track=track, shots=1200,
                                 beams="gt1l,gt1r", atl03_path=tmp_path / "a3.h5",
                                 seed=2, progress=False, section_shots=400)
    bounds = granule.section_bounds(1200, spacing_m=0.7, section_shots=400)
    assert len(bounds) == 3 and calls == [bounds[0][1]] * 2
    assert sorted(sections) == sorted([b - a for a, b in bounds[1:]] * 2)
    assert [s.shots for s in out] == [1200, 1200]


def test_snow_that_changes_along_a_beam_is_planned_anew_where_it_changes(dem_surface, tmp_path,
                                                                         monkeypatch):
    """``snow(beam, k)``: a section whose snow differs from the section before gets a plan
    of its own (a new material: the snow kernel); equal snow keeps the plan."""
    from lidar_mitsuba import granule, planning
    snow = lm.snow_from_grains(grain_radius_um=200)
    calls = []
    real = planning.plan
    monkeypatch.setattr(planning, "plan", lambda **kw: calls.append(
        kw.get("snow") is not None) or real(**kw))
    track = lm.GeoTrack(start_lat_deg=69.97, start_lon_deg=-45.0, azimuth_deg=0.0)
    out = granule.stream_granule(surface=dem_surface, track=track, shots=1200, beams="gt1r",
                                 atl03_path=tmp_path / "a3.h5", seed=2, progress=False,
                                 section_shots=400,
                                 snow=lambda beam, k: None if k == 0 else snow)
    assert calls == [False, True] and out[0].shots == 1200
    with h5py.File(tmp_path / "a3.h5", "r") as f:
        h = (f["truth/gt1r/photons/h_m"][()]
             - f["truth/gt1r/shots/z_ref_m"][()][f["truth/gt1r/photons/shot"][()]])
        sig = f["truth/gt1r/photons/is_signal"][()] == 1
        first = f["truth/gt1r/photons/shot"][()] < granule.section_bounds(
            1200, spacing_m=0.7, section_shots=400)[0][1]
    # the snow section's photons come from under the surface: lower than the bare one's
    assert np.median(h[sig & ~first]) < np.median(h[sig & first]) - 0.02
