"""A forest over a DEM (issue 42): the stand wraps along a corridor of any length, the
``canopy`` integrator holds the stand's crowns and each corridor tile hands it the ground
under them, and a granule over the forest writes ATL03, ATL06 and ATL08 together, from
Python and from the CLI (``simulate --dem ... --forest``)."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

import lidar_mitsuba as lm
from lidar_mitsuba.ground import dem as dems


@pytest.fixture(scope="module")
def small_dem(tmp_path_factory):
    """A 3 x 3 km slice of the synthetic ice sheet at 70 N (no hole)."""
    path = tmp_path_factory.mktemp("forest_dem") / "dem.tif"
    return dems.synthetic_ice_sheet(path, width_m=3000.0, length_m=3000.0, hole=False)


def test_the_stand_wraps_along_the_corridor_on_the_ground_where_it_is(small_dem):
    """A 200 m periodic stand seen by a corridor tile 1.1 km away (tiles of a 100 km track
    see the same stand): the tile's ground under the stand's crowns
    (:func:`~lidar_mitsuba.vegetation.turbid.tile_crowns`) places, in a window one period
    on a side, anywhere, exactly one image of every tree (the count is exact, not
    statistical), each crown standing on the DEM where its image is (its base
    ``crown_base`` above the DEM's height at its axis, to float32 rounding of ~2000 m
    heights: 1 mm). The ``canopy`` integrator's gap layer through the stand's crowns
    (:func:`~lidar_mitsuba.vegetation.turbid.stand_crowns`: one grid for every tile, the
    tile's photons wrapped into it) and that tile's ground gives each photon's line the
    gap probability that numpy computes over the same crowns placed in the tile
    (:func:`~lidar_mitsuba.vegetation.gap.gap_probability`: an independent
    implementation), across the period's edge: to float32 rounding of the ~2000 m heights
    (1.2e-4 m at each of a chord's ends, a few chords a line, times the extinction,
    ~0.3 /m here: 5e-4)."""
    from lidar_mitsuba.vegetation import gap, turbid
    mi = lm.ensure_renderer()
    ground = dems.DEMSurface(dems.DEM.open(small_dem))
    (cx, cy) = ground.centre_xy_m()
    f = lm.forest(species="conifer", height_m=12.0, cover=0.5, lai=2.0, ground=ground,
                  representation="gap", seed=5,
                  bounds_m=((cx - 100.0, cy - 100.0), (cx + 100.0, cy + 100.0)))
    s, period = f.stand, 200.0
    x0, y0 = cx + 1100.0 + 17.3, cy - 900.0 + 3.1         # not on the period's lattice
    origin = (x0 - 40.0, y0 + 25.0)                         # the tile's origin in the frame
    shots_x, shots_y = np.full(50, x0 + 100.0), y0 + np.linspace(0.0, 200.0, 50)
    t = turbid.tile_crowns(f, x_m=shots_x, y_m=shots_y, reach_m=100.0, origin_m=origin)
    (mx, _), n = t["images"], t["trees"]
    k = np.flatnonzero(np.isfinite(t["ground_z_m"]))
    (j, i), tree = np.divmod(k // n, mx), k % n
    (sx0, sy0) = s.bounds_m[0]
    tx = s.x_m[tree] - sx0 + (i - t["image0"][0]) * period - t["shift_m"][0]
    ty = s.y_m[tree] - sy0 + (j - t["image0"][1]) * period - t["shift_m"][1]
    ax, ay = tx + origin[0], ty + origin[1]
    inside = (ax >= x0) & (ax < x0 + 200.0) & (ay >= y0) & (ay < y0 + 200.0)
    assert inside.sum() == s.n_trees > 100
    zb = t["ground_z_m"][k] + s.crown_base_m[tree]
    above = zb - ground.height_m(ax, ay)
    assert s.crown_base_m.min() - 1e-3 <= above.min() and above.max() <= (
        s.crown_base_m.max() + 1e-3)
    # the gap layer over the tile (a flat ground below every crown) against numpy
    integ = mi.load_dict({"type": "canopy", "mode": "gap", "footprint_sigma_m": 2.5})
    integ.set_stand(turbid.stand_crowns(f, pad_m=2.0 * integ.fov_radius_m + 1.0))
    integ.set_tile(t)
    floor = float(np.min(t["ground_z_m"][k])) - 30.0
    scene = mi.load_dict({"type": "scene", "ground": {
        "type": "rectangle", "to_world": mi.ScalarTransform4f().translate(
            [100.0, -25.0, floor]).scale([400.0, 400.0, 1.0]),
        "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}}})
    ret = integ.trace(scene, shot_x_m=shots_x - origin[0], shot_y_m=shots_y - origin[1],
                      paths_per_shot=32, seed=2)
    table = turbid.crowns_table(s, cx=tx, cy=ty, zb=zb, zt=zb - s.crown_base_m[tree]
                                + s.height_m[tree], r=s.crown_radius_m[tree], rho=0.1, tau=0.1)
    on_ground = ret.z_m < floor + 0.5
    p_num = gap.gap_probability(table, ret.x_m[on_ground], ret.y_m[on_ground], floor)
    np.testing.assert_allclose(ret.weight[on_ground] / (0.5 / 0.9), p_num, atol=5e-4)
    assert 0.05 < p_num.mean() < 0.95 and p_num.min() < 0.1     # canopy and gaps both seen
    # the stand moved into a granule's frame is the same forest on the same ground
    g = f.with_origin((cx - 1234.0, cy + 567.0))
    assert np.allclose(g.stand.x_m + g.origin_m[0], f.stand.x_m)
    assert np.allclose(g.ground.height_m(g.stand.x_m, g.stand.y_m), f.stand.ground_z_m)


def test_cli_forest_over_a_dem_writes_atl03_atl06_and_atl08(small_dem, tmp_path, capsys):
    """``simulate --dem --forest`` (docs/guide/forests.md) at a small size: one strong beam,
    300 shots (two 100 m land segments) over a turbid conifer stand (a 300 m periodic square
    at the DEM's centre, 0.4 km north of the track: seen through its images); ATL03, ATL06
    and our ATL08 are written, the ATL08 photons are classed ground and canopy, and its
    terrain lies on the DEM's: within 0.25 m (~100 ground photons a segment
    spread ~0.2 m by the pulse and the footprint's slope: a mean good to ~2 cm; the bound
    leaves the ground classifier a decimetre or two of its own)."""
    from lidar_mitsuba.cli import main
    a3, a6, a8 = tmp_path / "f3.h5", tmp_path / "f6.h5", tmp_path / "f8.h5"
    assert main(["simulate", "--dem", str(small_dem), "--track", "69.995,-45,0",
                 "--beams", "gt2l", "--instrument", "atlas", "--range-gate-m", "40",
                 "--forest", "conifer:height=12,cover=0.5,lai=2,size=300,seed=1,"
                 "representation=turbid", "--shots", "300", "--seed", "2",
                 "--out", str(a3), "--atl06", str(a6), "--atl08", str(a8),
                 "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "turbid conifer forest over" in text and a3.is_file() and a6.is_file()
    with h5py.File(a8) as f:
        flags = f["gt2l/signal_photons/classed_pc_flag"][()]
        counts = np.bincount(flags, minlength=4)
        assert counts[1] > 20 and counts[2] + counts[3] > 20, counts   # ground, canopy
        h = f["gt2l/land_segments/terrain/h_te_best_fit"][()].astype(float)
        truth = f["truth/gt2l/land_segments/h_surface_true"][()]
        ok = h < 1e30
        assert ok.sum() >= 2 and np.abs(h - truth)[ok].max() < 0.25, h - truth
    with h5py.File(a3) as f:
        assert f["gt2l/heights/h_ph"].size > 100


@pytest.mark.parametrize("spec", ["conifer:height=abc", "palm", "conifer:cover=1.5"])
def test_cli_forest_over_a_dem_bad_spec_exit_2(small_dem, tmp_path, capsys, spec):
    from cli_checks import bad_call
    err = bad_call(["simulate", "--dem", str(small_dem), "--track", "69.995,-45,0",
                    "--forest", spec, "--out", str(tmp_path / "x.h5")], capsys)
    assert "--forest" in err
    assert not (tmp_path / "x.h5").exists()


def test_a_campaign_over_a_forest_writes_atl08_and_its_numbers(small_dem, tmp_path):
    """A campaign spec with ``[forest]`` (ATL08 by default): one spec track, one beam, 300
    shots in this process; the granule's ATL08 is in ``granules/ATL08`` and the task table
    holds its land segments' terrain error (within 0.25 m: as the CLI test above) and canopy
    height (below the stand's tallest tree, ~12 m x 1.3 at 10 % height spread); a bad
    ``[forest]`` key is one line naming it."""
    from lidar_mitsuba import campaign
    from lidar_mitsuba.sweep import SpecError
    spec = {"campaign": {"name": "forest", "seed": 3},
            "dem": {"path": str(small_dem)},
            "instrument": {"preset": "atlas", "beams": "gt2l",
                           "options": {"range_gate_m": 40.0}},
            "run": {"shots": 300, "max_depth": 1},
            "epochs": {"dates": ["2019-06-01T00:00:00Z"]},
            "tracks": [{"start": [69.995, -45.0], "azimuth_deg": 0.0}],
            "forest": {"species": "conifer", "representation": "turbid", "height_m": 12.0,
                       "cover": 0.8, "lai": 4.0, "size_m": 300.0, "seed": 1}}
    res = campaign.run(spec, out=tmp_path / "out", workers=0, plot=False)
    row = res.tasks.iloc[0]
    assert row["status"] == "ok", row["error"]
    assert (tmp_path / "out" / "granules" / row["atl08"]).is_file()
    assert row["n_land_segments"] >= 2 and row["n_terrain"] >= 2
    assert abs(row["terrain_bias_m"]) < 0.25
    assert row["n_canopy"] >= 1 and 0 < row["h_canopy_m"] < 1.3 * 12.0 + 1
    with pytest.raises(SpecError) as e:
        campaign.load_spec({**spec, "forest": {"species": "conifer", "cover": 2.0}})
    assert "[forest] cover" in str(e.value)
