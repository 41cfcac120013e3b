"""The forest stand generator (lidar_mitsuba/vegetation/stand.py): pure numpy, no renderer.

* cover and LAI reproduce the requested values: LAI exactly (it sets the leaf area density
  of the realised crowns), cover within the sampling error of the Boolean model (below);
* the leaf angle distributions: their inverse-CDF samples against the densities, Ross's
  G-function against its closed forms (0.5 spherical at every angle; at nadir
  G(0) = E[cos theta_L]);
* crown geometry: volumes against Monte Carlo of ``inside_crown``, periodic wrap;
* bad inputs raise ParameterError naming the argument.
"""
import math

import numpy as np
import pytest

from lidar_mitsuba.constants import ParameterError
from lidar_mitsuba.vegetation import stand as st

BOX = ((0.0, 0.0), (150.0, 150.0))


def boolean_cover_sd(*, cover: float, radius_m: float, area_m2: float) -> float:
    """Standard deviation of the covered fraction of a window of ``area_m2`` [m^2] under a
    Poisson Boolean model of discs of radius ``radius_m`` [m] and mean cover ``cover``:
    var = (1/|W|) int (1 - c)^2 (exp(lambda gamma(h)) - 1) d^2h, gamma(h) the discs' set
    covariance (the area two discs h apart share; Serra 1982, "Image analysis and
    mathematical morphology", ch. XIII; Chiu, Stoyan, Kendall & Mecke 2013, "Stochastic
    geometry and its applications", 3rd ed., sec. 3.1). A fixed number of stems (ours) only
    lowers it: this bounds our spread from above."""
    r, q = radius_m, 1.0 - cover
    lam = -math.log(q) / (math.pi * r * r)
    h = np.linspace(0.0, 2.0 * r, 4001)
    gamma = 2 * r * r * np.arccos(h / (2 * r)) - 0.5 * h * np.sqrt(4 * r * r - h * h)
    integrand = 2 * np.pi * h * q * q * np.expm1(lam * gamma)
    return math.sqrt(np.trapezoid(integrand, h) / area_m2)


@pytest.mark.parametrize("species,cover,lai", [("conifer", 0.6, 3.0), ("broadleaf", 0.3, 4.0),
                                               ("shrub", 0.8, 2.0)])
def test_cover_and_lai_reproduce_the_request(species, cover, lai):
    """LAI is exact (it sets the leaf area density of the realised crowns). Cover: stems
    uniform on the torus, so the covered fraction of the tile estimates the Boolean model's
    1 - exp(-lambda E[A]) (a fixed count: its mean (1 - E[A]/|W|)^n is within 1e-4 of the
    exponential here); the tolerance is 5 of the Boolean model's standard deviations
    (:func:`boolean_cover_sd`, at the mean crown radius) plus 0.003 for the lattice
    sampling of the discs and the spread of the radii. Three seeds must all pass."""
    for seed in range(3):
        s = st.stand(species=species, cover=cover, lai=lai, bounds_m=BOX, seed=seed)
        assert s.lai() == pytest.approx(lai, rel=1e-12)
        r = math.sqrt(float(np.mean(s.crown_radius_m ** 2)))
        sd = boolean_cover_sd(cover=cover, radius_m=r, area_m2=s.area_m2)
        assert abs(s.canopy_cover() - cover) < 5 * sd + 0.003, (seed, s.canopy_cover(), sd)


def test_cover_test_can_fail():
    """The same check rejects a stand drawn for another cover (0.5 asked, 0.6 checked)."""
    s = st.stand(species="conifer", cover=0.5, bounds_m=BOX, seed=0)
    sd = boolean_cover_sd(cover=0.6, radius_m=float(s.crown_radius_m.mean()),
                          area_m2=s.area_m2)
    assert abs(s.canopy_cover() - 0.6) > 5 * sd + 0.003


def test_seeded_and_stems_per_ha():
    a = st.stand(species="conifer", stems_per_ha=400, bounds_m=BOX, seed=7)
    b = st.stand(species="conifer", stems_per_ha=400, bounds_m=BOX, seed=7)
    c = st.stand(species="conifer", stems_per_ha=400, bounds_m=BOX, seed=8)
    assert a.n_trees == round(400 * 2.25) == c.n_trees
    assert np.array_equal(a.x_m, b.x_m) and np.array_equal(a.height_m, b.height_m)
    assert not np.array_equal(a.x_m, c.x_m)
    # the preset's shape and foliage, heights about the preset's mean (cv 0.1, n = 1600)
    assert a.crown_shape == "cone" and a.leaf_angle == "spherical" and a.species == "conifer"
    assert abs(a.height_m.mean() - 18.0) < 5 * 0.1 * 18.0 / math.sqrt(a.n_trees)
    assert np.all(a.crown_base_m == pytest.approx(0.5 * a.height_m))


def test_stems_stand_on_the_surface():
    import lidar_mitsuba as lm
    plane = lm.Plane(slope_deg=10.0, size_m=100.0)
    s = st.stand(species="shrub", cover=0.5, surface=plane, seed=1)
    assert s.bounds_m == ((0.0, 0.0), (100.0, 100.0))
    assert np.allclose(s.ground_z_m, plane.height_m(s.x_m, s.y_m))
    with pytest.raises(ParameterError) as e:
        st.stand(species="shrub", cover=0.5, seed=1)
    assert e.value.name == "bounds_m"


@pytest.mark.parametrize("shape", st.CROWN_SHAPES)
def test_crown_volume_and_inside_crown(shape):
    """crown_volume_m3 against the Monte Carlo volume of inside_crown over one lone tree's
    bounding box (binomial error: 5 sigma); the periodic image of a crown across the edge."""
    s = st.Stand(x_m=[1.0], y_m=[5.0], ground_z_m=[2.0], height_m=[10.0], crown_base_m=[4.0],
                 crown_radius_m=[2.0], crown_shape=shape, leaf_area_density_m2_m3=0.5,
                 leaf_angle="spherical", clumping=1.0, species="conifer",
                 bounds_m=((0.0, 0.0), (20.0, 10.0)))
    rng = np.random.default_rng(3)
    n = 50_000
    x = 1.0 + rng.uniform(-2, 2, n)
    y = 5.0 + rng.uniform(-2, 2, n)
    z = 6.0 + rng.uniform(0, 6, n)
    frac = s.inside_crown(x, y, z).mean()
    box = 4 * 4 * 6
    expect = s.crown_volume_m3()[0] / box
    assert abs(frac - expect) < 5 * math.sqrt(expect * (1 - expect) / n)
    assert s.leaf_area_m2()[0] == pytest.approx(0.5 * s.crown_volume_m3()[0])
    # x = 19.8 is 1.2 m from the stem through the periodic edge at x = 20
    assert s.inside_crown(19.8, 5.0, 8.0) and not s.inside_crown(17.5, 5.0, 8.0)
    assert not s.inside_crown(1.0, 5.0, 5.9) and not s.inside_crown(1.0, 5.0, 12.1)


@pytest.mark.parametrize("leaf_angle", st.LEAF_ANGLES)
def test_leaf_angle_sampling_and_g_function(leaf_angle):
    """Inverse-CDF samples against the density (histogram, 5 sigma per bin); G(0) =
    E[cos theta_L] by the samples (5 standard errors) and by the closed forms
    (spherical 1/2, uniform 2/pi, planophile 8/(3 pi), erectophile 4/(3 pi));
    the normalisation int G(theta) sin theta dtheta = 1/2 (Ross 1981) to 1e-4."""
    rng = np.random.default_rng(11)
    n = 40_000
    t = st.sample_leaf_inclination(leaf_angle, rng.random(n))
    edges = np.linspace(0, np.pi / 2, 19)
    counts, _ = np.histogram(t, edges)
    mid = np.linspace(edges[0], edges[-1], 1801)
    p = np.array([np.trapezoid(st.leaf_angle_pdf(leaf_angle, mid[(mid >= a) & (mid <= b)]),
                               mid[(mid >= a) & (mid <= b)]) for a, b in zip(edges, edges[1:])])
    assert np.all(np.abs(counts - n * p) < 5 * np.sqrt(n * p * (1 - p)) + 1)
    closed = {"spherical": 0.5, "uniform": 2 / np.pi, "planophile": 8 / (3 * np.pi),
              "erectophile": 4 / (3 * np.pi)}[leaf_angle]
    c = np.cos(t)
    assert abs(c.mean() - closed) < 5 * c.std() / math.sqrt(n)
    assert st.ross_g(leaf_angle, 0.0) == pytest.approx(closed, abs=1e-5)
    th = (np.arange(900) + 0.5) * (np.pi / 2) / 900
    assert (st.ross_g(leaf_angle, th) * np.sin(th)).sum() * (np.pi / 2) / 900 == \
        pytest.approx(0.5, abs=1e-4)
    if leaf_angle == "spherical":
        assert np.allclose(st.ross_g("spherical", th), 0.5, atol=1e-5)


def test_gap_probability_closed_form():
    assert st.gap_probability(leaf_angle="spherical", lai=2.0) == pytest.approx(math.exp(-1.0))
    assert st.gap_probability(leaf_angle="spherical", lai=2.0, clumping=0.5,
                              theta_rad=math.radians(60)) == pytest.approx(math.exp(-1.0))


@pytest.mark.parametrize("kwargs,name", [
    (dict(species="palm"), "species"), (dict(cover=1.2), "cover"),
    (dict(cover=0.5, stems_per_ha=100), "cover"), (dict(stems_per_ha=-1), "stems_per_ha"),
    (dict(lai=-1), "lai"), (dict(leaf_angle="flat"), "leaf_angle"),
    (dict(clumping=0.0), "clumping"), (dict(crown_ratio=1.5), "crown_ratio"),
    (dict(crown_shape="sphere"), "crown_shape"), (dict(height_m=0.0), "height_m"),
    (dict(seed=-1), "seed"), (dict(bounds_m=((0, 0), (0, 10))), "bounds_m"),
    (dict(bounds_m="x"), "bounds_m"), (dict(lai=15, cover=0.01), "lai"),
])
def test_bad_inputs_raise_parameter_error(kwargs, name):
    kw = dict(bounds_m=BOX, seed=0)
    kw.update(kwargs)
    with pytest.raises(ParameterError) as e:
        st.stand(**kw)
    assert e.value.name == name


def test_periodic_copies_list_every_copy_that_reaches_a_box():
    """The copies of a periodic square whose crowns reach into a box, against brute force
    over 13 x 13 periods: every copy with a crown in the box (closed edges) is listed, each
    listed copy's square widened by the largest crown touches the box (to the millimetre the
    helper adds), in i-then-j order; a non-periodic stand lists itself only."""
    rng = np.random.default_rng(4)
    bounds = ((-30.0, 5.0), (20.0, 45.0))                     # 50 x 40 m
    x, y = rng.uniform(-30.0, 20.0, 300), rng.uniform(5.0, 45.0, 300)
    r = rng.uniform(0.5, 4.0, 300)
    reach = float(r.max()) + 1e-3
    for _ in range(40):
        bx0, by0 = rng.uniform(-200.0, 200.0, 2)
        box = (bx0, bx0 + rng.uniform(0.0, 120.0), by0, by0 + rng.uniform(0.0, 90.0))
        got = st.periodic_copies(bounds, box, reach_m=float(r.max()))
        assert got == sorted(got)
        for i in range(-6, 7):
            for j in range(-6, 7):
                cx, cy = x + 50.0 * i, y + 40.0 * j
                hit = np.any((cx + r >= box[0]) & (cx - r <= box[1])
                             & (cy + r >= box[2]) & (cy - r <= box[3]))
                near = (bounds[1][0] + 50.0 * i + reach >= box[0]
                        and bounds[0][0] + 50.0 * i - reach <= box[1]
                        and bounds[1][1] + 40.0 * j + reach >= box[2]
                        and bounds[0][1] + 40.0 * j - reach <= box[3])
                assert ((i, j) in got) == near
                assert near or not hit
    assert st.periodic_copies(bounds, (500.0, 600.0, 0.0, 1.0), reach_m=4.0,
                              periodic=False) == [(0, 0)]
