"""The turbid and gap-probability canopies (lidar_mitsuba.vegetation.ross / gap / turbid, the
``canopy`` integrator): Ross's G and the leaf phase function against numerical integration,
the leaf sampler against the phase function (chi-square), the crown chords against brute
force, and the monostatic hot spot against the closed form P_gap = exp(-G Omega LAI / mu).

Monte Carlo tolerances: 4 standard errors of the estimate, from the binomial variance of an
analog count (a photon reaches the ground or not) or the sample variance of the weights
(fixed seeds: a failure is a bias of 4 sigma or a changed stream, not bad luck)."""
import math
from types import SimpleNamespace

import numpy as np
import pytest

import lidar_mitsuba
from lidar_mitsuba.vegetation import gap, ross, stand, turbid

mi = lidar_mitsuba.ensure_renderer()
dr = pytest.importorskip("drjit")

RHO, TAU = 0.12, 0.12        # a green leaf at 532 nm (PROSPECT, issue 42's range)


def _brute_g(mu: float, leaf_angle: str, n: int = 1500) -> float:
    """(1/2pi) int g_L |Omega . n| dn by the midpoint rule over inclination and azimuth."""
    t = (np.arange(n) + 0.5) * (np.pi / 2 / n)
    p = (np.arange(2 * n) + 0.5) * (np.pi / n)
    f = ross.leaf_angle_pdf(leaf_angle, t)[:, None]
    proj = np.abs(mu * np.cos(t)[:, None]
                  + math.sqrt(1 - mu * mu) * np.sin(t)[:, None] * np.cos(p)[None, :])
    return float((f * proj).mean(1) @ np.full(n, np.pi / 2 / n))


@pytest.mark.parametrize("leaf_angle", ross.LEAF_ANGLES)
def test_g_function_closed_forms_and_quadrature(leaf_angle):
    """G at nadir and horizon in closed form, Ross's int_0^1 G dmu = 1/2, spherical 1/2
    everywhere, and the kernel quadrature against a brute-force 2-D integral (midpoint rule:
    error ~1e-6 at 1500 nodes, tolerance 1e-5)."""
    assert ross.g_function(np.array(1.0), leaf_angle) == pytest.approx(
        ross.G_NADIR[leaf_angle], abs=1e-12)
    assert ross.g_function(np.array(0.0), leaf_angle) == pytest.approx(
        ross.G_HORIZON[leaf_angle], abs=1e-12)
    x, w = np.polynomial.legendre.leggauss(64)
    assert np.sum(w * ross.g_function((x + 1) / 2, leaf_angle)) / 2 == pytest.approx(0.5,
                                                                                    abs=1e-6)
    for mu in (0.2, 0.6, 0.9):
        assert float(ross.g_function(np.array(mu), leaf_angle)) == pytest.approx(
            _brute_g(mu, leaf_angle), abs=1e-5)
        # the stand's own G (midpoint rule, another implementation of the kernel)
        assert float(ross.g_function(np.array(mu), leaf_angle)) == pytest.approx(
            float(stand.ross_g(leaf_angle, math.acos(mu))), abs=1e-5)
    if leaf_angle == "spherical":
        np.testing.assert_allclose(ross.g_function(np.linspace(0, 1, 11), leaf_angle), 0.5,
                                   atol=1e-12)


def test_spherical_phase_function():
    """The closed form normalises to 1 over the sphere and equals Gamma / ((rho + tau) G)
    integrated over the leaf normals numerically (midpoint rule, 1e-4)."""
    rho, tau = 0.3, 0.1                     # unequal, so reflection and transmission differ
    x, w = np.polynomial.legendre.leggauss(200)
    gam = (x + 1) * np.pi / 2
    norm = 2 * np.pi * np.sum(w * np.pi / 2 * ross.phase_spherical(gam, rho=rho, tau=tau)
                              * np.sin(gam))
    assert norm == pytest.approx(1.0, abs=1e-10)
    n = 800                                   # leaf normals over the whole sphere
    ct = (np.arange(n) + 0.5) / n * 2 - 1
    ph = (np.arange(2 * n) + 0.5) * np.pi / n
    st = np.sqrt(1 - ct ** 2)
    nx, ny, nz = st[:, None] * np.cos(ph), st[:, None] * np.sin(ph), ct[:, None] + 0 * ph
    d_in = np.array([0.0, 0.0, -1.0])
    for g in (0.3, 1.5, 2.5, 3.1):
        d_out = np.array([math.sin(g), 0.0, -math.cos(g)])
        a = nx * d_in[0] + ny * d_in[1] + nz * d_in[2]
        b = nx * d_out[0] + ny * d_out[1] + nz * d_out[2]
        f = np.where(a * b < 0, rho, tau) / np.pi * np.abs(b)
        gamma = (np.abs(a) * f).mean()     # (1/2pi) int_hemisphere = (1/4pi) int_sphere
        assert gamma / ((rho + tau) * 0.5) == pytest.approx(
            float(ross.phase_spherical(np.array(g), rho=rho, tau=tau)), abs=1e-4)


def _table(*, shape="cylinder", leaf_angle="spherical", lad=0.2, crowns=None):
    """A canopy table: by default one wide cylinder crown 5-20 m over the origin (a
    horizontally homogeneous layer of LAI = 15 lad)."""
    cx, cy, zb, zt, r = crowns if crowns is not None else ([0.0], [0.0], [5.0], [20.0], [150.0])
    mu = np.linspace(0, 1, turbid.G_NODES)
    g = ross.g_function(mu, leaf_angle)
    return {"cx": np.array(cx), "cy": np.array(cy), "zb": np.array(zb), "zt": np.array(zt),
            "r": np.array(r), "shape": shape, "leaf_angle": leaf_angle, "g": g, "lad": lad,
            "clumping": 1.0, "rho": RHO, "tau": TAU}


def _integrator(table, **props):
    integ = mi.load_dict({"type": "canopy", "footprint_sigma_m": 2.5, **props})
    integ.set_table(table)
    return integ


def _ground(albedo: float = 0.5):
    return mi.load_dict({"type": "scene", "ground": {
        "type": "rectangle", "to_world": mi.ScalarTransform4f().scale([400.0, 400.0, 1.0]),
        "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": albedo}}}})


def test_leaf_sampler_chi2_and_backscatter():
    """Spherical leaves: the directions the leaf sampler scatters into follow the closed-form
    phase function (chi-square over 30 bins of the scattering angle's cosine); for every leaf
    angle distribution the backscatter estimate (a sampled leaf's pi f_L cos / 0.9 toward
    the way back) averages pi Gamma_b / (G 0.9) within 4 standard errors."""
    from scipy import stats
    n = 100_000
    d = mi.Vector3f(0.0, 0.0, -1.0)
    for leaf_angle in ross.LEAF_ANGLES:
        integ = _integrator(_table(leaf_angle=leaf_angle))
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(7, n)
        value, d_new = integ._leaf(d, -d, sampler, mi.Bool(True))
        v = value.numpy()
        want = ross.leaf_return_weight(leaf_angle, rho=RHO)
        assert abs(v.mean() - want) < 4 * v.std() / math.sqrt(n), leaf_angle
        if leaf_angle == "spherical":
            cos_g = -d_new.z.numpy()                   # cos of the angle to the way in
            edges = np.linspace(-1, 1, 31)
            x, w = np.polynomial.legendre.leggauss(40)
            expect = []
            for a, b in zip(edges[:-1], edges[1:]):
                c = (a + b) / 2 + (b - a) / 2 * x
                expect.append(2 * np.pi * np.sum(w * (b - a) / 2 * ross.phase_spherical(
                    np.arccos(c), rho=RHO, tau=TAU)))
            obs = np.histogram(cos_g, edges)[0]
            expect = np.array(expect) * n
            assert expect.sum() == pytest.approx(n, rel=1e-9)
            assert stats.chisquare(obs, expect).pvalue > 1e-3


@pytest.mark.parametrize("shape", ["cone", "ellipsoid", "cylinder"])
def test_crown_chords_against_brute_force(shape):
    """The kernel's ray-crown intervals (any direction) against points sampled along each
    ray and tested inside the crown (step 2 mm: error <= 2 steps, tolerance 5 mm)."""
    canopy = lidar_mitsuba_plugins_module()
    rng = np.random.default_rng(3)
    m = 150
    o = np.column_stack([rng.uniform(-4, 4, m), rng.uniform(-4, 4, m), rng.uniform(-2, 14, m)])
    d = rng.normal(size=(m, 3))
    d[: m // 3] = [0.0, 0.0, -1.0]                       # vertical lines as the first leg
    d /= np.linalg.norm(d, axis=1)[:, None]
    t0, t1 = canopy.crown_chord(shape, mi.Point3f(*o.T), mi.Vector3f(*d.T), 0.5, -0.3, 2.0,
                                10.0, 3.0)
    got = np.clip(t1.numpy() - np.maximum(t0.numpy(), 0.0), 0.0, None)
    s = np.arange(0.0, 25.0, 2e-3)[None, :]
    p = o[:, None, :] + s[..., None] * d[:, None, :]
    rr = np.hypot(p[..., 0] - 0.5, p[..., 1] + 0.3)
    z = p[..., 2]
    u = (z - 2.0) / 8.0
    rad = {"cone": 3.0 * (1 - u), "cylinder": 3.0 + 0 * u,
           "ellipsoid": 3.0 * np.sqrt(np.clip(1 - (2 * u - 1) ** 2, 0, None))}[shape]
    inside = (u >= 0) & (u <= 1) & (rr <= rad)
    np.testing.assert_allclose(got, inside.sum(1) * 2e-3, atol=5e-3)
    assert (got > 0).sum() > m // 5                   # a fair share of the rays cross it


def lidar_mitsuba_plugins_module():
    import lidar_mitsuba_plugins
    return lidar_mitsuba_plugins.module("canopy")


def _fractions(ret, *, n_photons, albedo):
    """Ground and canopy return per photon, the ground's in units of its bare return."""
    ground = ret.z_m < 1.0
    first = ret.depth == 1
    return (ret.weight[ground & first].sum() / n_photons / (albedo / 0.9),
            ret.weight[~ground & first].sum() / n_photons, ret)


def test_hot_spot_against_closed_form():
    """A homogeneous layer of LAI 3 (spherical leaves, G = 1/2): the ground returns P_gap =
    exp(-G LAI) of the bare ground's weight at nadir, the canopy (1 - P_gap) pi Gamma_b /
    (G 0.9), in the gap layer (exact to float32) and the turbid medium (an analog count: 4
    binomial standard errors); without the hot spot the ground's share is P_gap^2 (4.5x
    less: the test fails if the way back is sampled independently)."""
    table, albedo = _table(), 0.5
    p_gap = ross.gap_probability(lai=3.0, leaf_angle="spherical")
    w_leaf = ross.leaf_return_weight("spherical", rho=RHO)
    scene = _ground(albedo)
    shots = np.zeros(64), np.zeros(64)
    n = 64 * 256
    for mode in ("gap", "turbid"):
        for hot in (True, False):
            integ = _integrator(table, mode=mode, hot_spot=hot, max_depth=1)
            ret = integ.trace(scene, shot_x_m=shots[0], shot_y_m=shots[1], paths_per_shot=256,
                              seed=11)
            g, c, ret = _fractions(ret, n_photons=n, albedo=albedo)
            want_g = p_gap if hot else p_gap ** 2
            want_c = w_leaf * ((1 - p_gap) if hot else (1 - p_gap ** 2) / 2)
            # the canopy's first-collision heights: sigma e^(-k sigma s) (k = 1, or 2 without the
            # hot spot) truncated to the layer's 15 m, mean depth below its top 1/a -
            # H e^(-aH) / (1 - e^(-aH)), a = k sigma; 4 standard errors of the weighted mean
            a = (1.0 if hot else 2.0) * 0.5 * 0.2
            depth_m = 20.0 - ret.z_m[ret.z_m >= 1.0].astype(float)
            w_c = ret.weight[ret.z_m >= 1.0].astype(float)
            mean = np.average(depth_m, weights=w_c)
            se = math.sqrt(np.average((depth_m - mean) ** 2, weights=w_c) / w_c.size)
            assert abs(mean - (1 / a - 15.0 * math.exp(-15 * a) / (1 - math.exp(-15 * a)))) \
                < 4 * se, (mode, hot, mean)
            if mode == "gap":
                assert g == pytest.approx(want_g, rel=1e-4), (mode, hot)
                assert c == pytest.approx(want_c, rel=1e-4), (mode, hot)
            else:
                sd = math.sqrt(p_gap * (1 - p_gap) / n) * (1.0 if hot else p_gap)
                assert abs(g - want_g) < 4 * sd, (mode, hot, g, want_g)
                w_c = ret.weight[ret.z_m >= 1.0]             # one canopy record per photon
                sd_c = math.sqrt((np.sum(w_c.astype(float) ** 2) / n - c * c) / n)
                assert abs(c - want_c) < 4 * sd_c, (mode, hot, c, want_c)


def test_gap_layer_matches_numpy_over_a_stand():
    """A periodic conifer stand (cones, overlapping, crossing the tile's edges): the gap
    layer's ground weight on each photon's line, over the bare ground's, is the numpy gap
    probability of that line (an independent implementation of the vertical chords; float32
    rounding, 1e-4); the canopy's share per line is 1 - P_gap."""
    st = stand.stand(species="conifer", cover=0.7, lai=4.0, bounds_m=((0.0, 0.0), (40.0, 40.0)),
                     seed=3)
    table = turbid.canopy_table(st, rho=RHO, tau=TAU, pad_m=30.0)
    integ = _integrator(table, mode="gap")
    xs = np.linspace(0.0, 40.0, 24)                  # through both edges of the tile
    ret = integ.trace(_ground(0.5), shot_x_m=xs, shot_y_m=np.full(24, 39.0), paths_per_shot=32,
                      seed=2)
    ground = ret.z_m < 0.5
    p_num = gap.gap_probability(table, ret.x_m[ground], ret.y_m[ground], 0.0)
    np.testing.assert_allclose(ret.weight[ground] / (0.5 / 0.9), p_num, atol=1e-4)
    assert 0.05 < p_num.mean() < 0.9 and p_num.min() < 0.05       # canopy and gaps both seen
    # every canopy return lies in a crown (drawn on its line's chords)
    canopy = ~ground & (ret.weight > 0)
    assert st.inside_crown(ret.x_m[canopy], ret.y_m[canopy], ret.z_m[canopy]).mean() > 0.999


def test_forest_front_door_gap_and_turbid():
    """``lm.forest(representation="gap" | "turbid")`` is traced by the ``canopy`` integrator
    over the bare ground's scene (no crown shapes), with the forest's leaf optics; its returns
    come from the crowns and the ground; an unknown representation is refused by name (over
    a DEM: tests/test_forest_dem.py)."""
    import lidar_mitsuba as lm
    from lidar_mitsuba.constants import ParameterError
    f = lm.forest(species="conifer", height_m=10.0, ground=lm.Plane(size_m=60.0), seed=1,
                  representation="gap")             # under the range gate (+-15 m)
    d = f.integrator_dict(lm.Instrument().integrator_dict(max_depth=1))
    assert d["type"] == "canopy" and d["mode"] == "gap"
    assert f.mitsuba_scene(bsdf=None, margin_m=10.0, bounds_m=None)[1] == 2   # the ground only
    res = lm.simulate(surface=f, shots=40, seed=1, progress=False)
    assert res.config["integrator"] == "canopy"
    z = res.returns.z_m
    assert (z > 3.0).any() and (np.abs(z) < 0.1).any()          # canopy and ground returns
    t = dataclasses_replace(f, representation="turbid")
    assert t.integrator_dict({"type": "pathlength", "max_depth": 2})["max_depth"] == 2
    with pytest.raises(ParameterError) as e:
        dataclasses_replace(t, representation="voxels")
    assert e.value.name == "representation"


def dataclasses_replace(obj, **kw):
    import dataclasses
    return dataclasses.replace(obj, **kw)


def test_a_stands_crowns_are_built_once_per_process():
    """Two forests of one spec (a campaign's granules each make the spec's forest again) get
    the same crowns' table, the very object, equal to the bit to one built afresh; another
    seed or pad builds its own; at most ``_STANDS_MAX`` are kept."""
    from lidar_mitsuba.ground.surface import Plane

    def make(seed):
        return lidar_mitsuba.forest(species="conifer", ground=Plane(size_m=80.0),
                                    representation="turbid", seed=seed)
    first = turbid.stand_crowns(make(1), pad_m=20.0)
    again = turbid.stand_crowns(make(1), pad_m=20.0)
    assert again is first
    f = make(1)
    (x0, y0), (x1, y1) = f.stand.bounds_m
    fresh = turbid._build_stand_crowns(f, (f.stand.x_m - x0, f.stand.y_m - y0, x1 - x0,
                                           y1 - y0), pad_m=20.0)
    for k, v in fresh.items():
        if k != "grid":
            assert np.array_equal(np.asarray(v), np.asarray(first[k])), k
    assert all(np.array_equal(a, b) for a, b in zip(fresh["grid"], first["grid"]))
    assert turbid.stand_crowns(make(2), pad_m=20.0) is not first
    assert turbid.stand_crowns(make(1), pad_m=25.0) is not first
    assert len(turbid._STANDS) <= turbid._STANDS_MAX
