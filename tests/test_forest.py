"""Forests as scenes (lidar_mitsuba/vegetation): the explicit representation traced by the
``pathlength`` integrator against the closed-form gap probability, the hot spot, and the
front door (``lm.forest``, ``simulate``, the CLI's ``--forest``).
"""
import math

import numpy as np
import pytest

import lidar_mitsuba as lm
from lidar_mitsuba.constants import ParameterError
from lidar_mitsuba.vegetation import stand as st
from lidar_mitsuba.vegetation.forest import ForestSurface, forest_from_spec
from lidar_mitsuba.vegetation.optics import Optics

#: one cylinder crown over flat ground: radius 6 m, from 2 to 6 m above the ground, leaf area
#: density 0.4 m^2/m^3: a vertical path crosses 4 m of crown, a leaf area index of 1.6
CROWN = dict(radius_m=6.0, base_m=2.0, top_m=6.0, lad=0.4, leaf_width_m=0.05)
LEAF_AREA_INDEX = CROWN["lad"] * (CROWN["top_m"] - CROWN["base_m"])
PHOTONS = 20_000


def one_crown(leaf_angle="spherical", clumping=1.0, **optics):
    s = st.Stand(x_m=[20.0], y_m=[20.0], ground_z_m=[0.0], height_m=[CROWN["top_m"]],
                 crown_base_m=[CROWN["base_m"]], crown_radius_m=[CROWN["radius_m"]],
                 crown_shape="cylinder", leaf_area_density_m2_m3=CROWN["lad"],
                 leaf_angle=leaf_angle, clumping=clumping, species="broadleaf",
                 bounds_m=((0.0, 0.0), (40.0, 40.0)), leaf_width_m=CROWN["leaf_width_m"],
                 stem_radius_m=1e-3, seed=5)
    leaf = Optics("test leaf", optics.get("r", 0.0), optics.get("t", 0.0), "test")
    return ForestSurface(ground=lm.Plane(size_m=40.0), stand=s, leaf=leaf,
                         floor=Optics("test floor", 0.5, 0.0, "test"), classes=1)


def trace_vertical(surface, *, max_depth, seed=2):
    """PHOTONS vertical photons (footprint sigma 0: one path per shot) at points uniform over
    the crown's disc, 0.3 m inside its edge and clear of the 1 mm stem."""
    mi = lm.ensure_renderer()
    rng = np.random.default_rng(seed)
    r = (CROWN["radius_m"] - 0.3) * np.sqrt(rng.uniform(1e-4, 1.0, PHOTONS))
    a = 2 * np.pi * rng.random(PHOTONS)
    scene, _ = surface.mitsuba_scene(bsdf=surface.default_bsdf(), margin_m=0.0,
                                     bounds_m=(10.0, 30.0, 10.0, 30.0))
    integ = mi.load_dict({"type": "pathlength", "max_depth": max_depth,
                          "footprint_sigma_m": 0.0})
    ret = integ.trace(scene, shot_x_m=20.0 + r * np.cos(a), shot_y_m=20.0 + r * np.sin(a),
                      paths_per_shot=1, seed=seed)
    ret.sector = (16 * a / (2 * np.pi)).astype(int)        # each photon's sector of the disc
    return scene, ret


def batch_sd(ret, ground) -> float:
    """Standard deviation of the gap fraction measured from its spread between the disc's 16
    sectors (batch means; each sector, 2 m^2 and up, is far wider than a leaf cluster): the
    photons' binomial error and the leaf layout's spread together."""
    hit = np.zeros(PHOTONS, bool)
    hit[ret.shot[ground]] = True
    means = np.array([hit[ret.sector == k].mean() for k in range(16)])
    return float(means.std(ddof=1) / math.sqrt(16))


def gap_tolerance(p: float) -> float:
    """5 standard deviations of the measured gap fraction: the photons' binomial error
    p (1 - p) / N, plus the spread of one leaf realisation's gap fraction over the crown's
    disc (area A): var <= (1/A) int C(h) dh with C the gap indicator's covariance of a
    Boolean model of leaf shadows, C(h) = p^2 (exp(lambda gamma(h)) - 1) <= p^2 (e^L - 1)
    gamma(h) / a (convexity; L = lambda a the layer's LAI of face-on leaves, gamma the
    shadows' set covariance, int gamma = E[a_shadow^2] <= a^2), so var <= p^2 (e^L - 1) a / A
    with a the leaf's area."""
    a = CROWN["leaf_width_m"] ** 2
    area = math.pi * (CROWN["radius_m"] - 0.3) ** 2
    var = p * (1 - p) / PHOTONS + p * p * math.expm1(LEAF_AREA_INDEX) * a / area
    return 5 * math.sqrt(var)


def clustered_tolerance(p: float, omega: float, ret, ground) -> float:
    """For leaves in clusters: 5 standard deviations from the sectors' spread
    (:func:`batch_sd`), plus 5 times the Monte Carlo error of the Omega the cluster radius
    was solved for (2 %, explicit.cluster_radius_per_width), which moves P_gap by
    0.02 Omega G LAI p."""
    return 5 * batch_sd(ret, ground) + 5 * 0.02 * omega * 0.5 * LEAF_AREA_INDEX * p


@pytest.mark.parametrize("leaf_angle,omega", [("spherical", 1.0), ("planophile", 1.0),
                                              ("spherical", 0.6)])
def test_ground_return_is_the_gap_probability(leaf_angle, omega):
    """Black leaves (R = T = 0): the ground's share of the photons is Nilson's
    P_gap = exp(-G(0) Omega LAI / cos 0) through the crown (G 0.5 spherical, 8/(3 pi)
    planophile; Omega 1: leaves placed independently; 0.6: leaves in clusters of 16 whose
    radius is solved for it), within :func:`gap_tolerance`; each ground return weighs the
    floor's rho / 0.9 at nadir, so the ground return scales as P_gap, far from P_gap^2 (the
    error of a way back drawn independently)."""
    surface = one_crown(leaf_angle, clumping=omega)
    _, ret = trace_vertical(surface, max_depth=1)
    ground = ret.z_m < 0.05
    p = ground.sum() / PHOTONS
    expect = st.gap_probability(leaf_angle=leaf_angle, lai=LEAF_AREA_INDEX, clumping=omega)
    tol = gap_tolerance(expect) if omega == 1 else \
        clustered_tolerance(expect, omega, ret, ground)
    assert abs(p - expect) < tol, (p, expect, tol)
    assert abs(p - expect ** 2) > 4 * tol           # >= 4 tolerances (20 sigma) away
    assert np.allclose(ret.weight[ground], 0.5 / 0.9, rtol=1e-5)
    assert ret.weight[~ground].size == 0          # black leaves return nothing


def test_hot_spot_from_the_geometry():
    """Leaves that scatter (R 0.12, T 0.125) and two vertices per path: the first-vertex
    ground returns are still P_gap of the photons (the light returns along its own way
    in), and the way back to the receiver from each ground hit is clear (shadow rays along
    it: none blocked), while the same rays moved 1 m aside are blocked as often as a fresh
    path is, 1 - P_gap: ground returns scale as P_gap, not P_gap^2."""
    mi = lm.ensure_renderer()
    surface = one_crown("spherical", r=0.12, t=0.125)
    scene, ret = trace_vertical(surface, max_depth=2)
    expect = st.gap_probability(leaf_angle="spherical", lai=LEAF_AREA_INDEX)
    first_ground = (ret.z_m < 0.05) & (ret.depth == 1)
    p = first_ground.sum() / PHOTONS
    assert abs(p - expect) < gap_tolerance(expect)
    # multiply scattered light reaches the ground too (through leaves): depth-2 returns
    assert np.any((ret.z_m < 0.05) & (ret.depth == 2))
    x, y = ret.x_m[first_ground], ret.y_m[first_ground]
    n = x.size

    def blocked(dx):
        o = mi.Point3f(x.astype(np.float32) + dx, y.astype(np.float32),
                       np.full(n, 1e-3, np.float32))
        return np.asarray(scene.ray_test(mi.Ray3f(o, mi.Vector3f(0, 0, 1)))).mean()

    assert blocked(0.0) == 0.0
    moved = blocked(1.0)
    assert abs((1 - moved) - expect) < 5 * math.sqrt(expect * (1 - expect) / n) + \
        gap_tolerance(expect)


def test_forest_spec_and_errors():
    f = forest_from_spec("shrub:height=1.5,cover=0.4,lai=2,size=30,seed=3")
    assert isinstance(f, ForestSurface) and f.stand.species == "shrub"
    assert f.stand.lai() == pytest.approx(2.0)
    assert f.stand.bounds_m == ((0.0, 0.0), (30.0, 30.0))
    for bad, words in (("palm", "species"), ("conifer:height=x", "not a number"),
                       ("conifer:cover=2", "cover"), ("conifer:colour=3", "expected key"),
                       ("conifer:size=0", "size")):
        with pytest.raises(ParameterError) as e:
            forest_from_spec(bad)
        assert e.value.name == "forest" and words in e.value.message
    with pytest.raises(ParameterError) as e:
        ForestSurface(ground=lm.Plane(size_m=30.0), stand=f.stand, representation="voxels")
    assert e.value.name == "representation"
    # a range gate that cuts the canopy is said
    tall = forest_from_spec("conifer:height=18,size=30")
    assert any("range gate" in w for w in tall.warnings(instrument=lm.Instrument()))
    assert not tall.warnings(instrument=lm.Instrument(range_gate_m=60.0))


@pytest.mark.parametrize("argv,option", [
    (["--forest", "conifer:cover=1.5"], "--forest"),
    (["--forest", "palm"], "--forest"),
    (["--forest", "conifer:size=100", "--surface", "flat"], "--forest"),
    (["--forest", "conifer", "--snow-grain-um", "100"], "--snow-grain-um"),
    (["--forest", "conifer", "--scene", "scenes/slope.xml"], "--scene"),
])
def test_cli_forest_bad_values_exit_2(argv, option, tmp_path, capsys):
    from cli_checks import bad_call
    err = bad_call(["simulate", "--shots", "10", "--out", str(tmp_path / "x.h5"), *argv],
                   capsys)
    assert option in err
    assert not (tmp_path / "x.h5").exists()


def test_cli_forest_runs(tmp_path, capsys):
    """The guide's command (docs/guide/forests.md) at a small size: a conifer stand over a
    60 m plane, coarse facets, 30 shots; photons come back from the canopy and the ground,
    the config says what was traced."""
    from lidar_mitsuba.cli import main
    out = tmp_path / "forest.h5"
    assert main(["simulate", "--forest",
                 "conifer:height=18,cover=0.6,lai=3,size=60,leaf_width=0.3,seed=2",
                 "--beam", "strong", "--range-gate-m", "60", "--shots", "20", "--out",
                 str(out), "--explain",
                 "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "forest (explicit): " in text and "conifer" in text
    assert out.is_file()
    beam = lm.read_atl03(out)
    assert beam["config"]["surface"]["kind"] == "forest"
    assert beam["config"]["surface"]["stand"]["species"] == "conifer"
    h = beam["h_m"][beam["is_signal"]]
    assert np.any(np.abs(h) < 1.0) and np.any(h > 5.0)       # ground and canopy photons


def test_long_track_over_a_folded_sloped_plane():
    """150 shots (105 m) over a 30 m sloped plane tile: the track folds into the tile three
    times and runs in three corridor tiles (chunks of 60 shots); the traced returns, put
    back on the track by each tile's offsets, never lie below the plane where they are, and
    the ground's (most of them at cover 0.3) lie on it to float32 precision (1 cm): a wrong
    fold would move them by metres."""
    plane = lm.Plane(slope_deg=5.0, size_m=30.0)
    f = lm.forest(species="shrub", height_m=1.0, cover=0.3, lai=1.0, leaf_width_m=0.2,
                  ground=plane, seed=4)
    res = lm.simulate(surface=f, shots=150, seed=3, max_depth=1, paths_per_shot=8,
                      chunk_shots=60, progress=False)
    assert res.config["surface"]["tiles"] == 3
    r = res.returns
    dz = r.z_m - plane.height_m(r.x_m, r.y_m)
    assert dz.min() > -0.01
    assert np.mean(np.abs(dz) < 0.01) > 0.5
    # the surface climbs 104 m x tan 5 deg = 9.1 m along the track: no fold left in it
    assert np.ptp(res.surface_z_m) == pytest.approx(149 * 0.7 * math.tan(math.radians(5)),
                                                    rel=0.05)
