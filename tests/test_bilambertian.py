"""Validation of the bi-Lambertian leaf BSDF (plugins/bilambertian.py), as Mitsuba validates
its BSDFs and as tests/test_ward.py does Ward's:

* chi-square goodness of fit of ``sample`` against ``pdf`` over the whole sphere
  (``mitsuba.chi2``), lit from the front and from the back, and the test's power (a pdf with
  R and T swapped is rejected);
* the directional albedo against the closed form R + T (sample weights: exactly; ``eval``
  by quadrature over each hemisphere: R reflected, T transmitted);
* two-sidedness and reciprocity of ``eval``; bad parameters refused; a leaf seen at nadir
  through the ``pathlength`` integrator returns R / 0.9.

Fixed seeds; tolerances derived next to each check.
"""
import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import lidar_mitsuba

mi_ = lidar_mitsuba.ensure_renderer()


def leaf(r=0.12, t=0.125):
    return mi.load_dict({"type": "bilambertian", "reflectance": r, "transmittance": t})


def local_dir(theta_deg, phi_deg=0.0):
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return (math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t))


CHI2_CASES = [(0.12, 0.125, 0), (0.12, 0.125, 50), (0.12, 0.125, 170), (0.3, 0.0, 80),
              (0.0, 0.3, 120)]
CHI2_TEST_COUNT = len(CHI2_CASES)       # Sidak: a 1 % chance of a false rejection in all


def chi2_test(params, theta_i_deg, seed, pdf_params=None):
    wi = mi.ScalarVector3f(*local_dir(theta_i_deg))
    sample_func, _ = mi.chi2.BSDFAdapter("bilambertian", {"type": "bilambertian", **params},
                                         wi=wi)
    _, pdf_func = mi.chi2.BSDFAdapter("bilambertian",
                                      {"type": "bilambertian", **(pdf_params or params)}, wi=wi)
    # 2e5 samples over (phi, cos theta) cells of the whole sphere; cells with < 5 expected
    # samples are pooled by the test
    test = mi.chi2.ChiSquareTest(domain=mi.chi2.SphericalDomain(), sample_func=sample_func,
                                 pdf_func=pdf_func, sample_dim=3, sample_count=200_000,
                                 res=32, ires=4, seed=seed)
    ok = test.run(significance_level=0.01, test_count=CHI2_TEST_COUNT, quiet=True)
    return ok, test


@pytest.mark.parametrize("r,t,theta_i", CHI2_CASES)
def test_chi2_sample_matches_pdf(r, t, theta_i):
    """theta_i > 90 deg: lit from the back face (the leaf is two-sided)."""
    ok, test = chi2_test(dict(reflectance=r, transmittance=t), theta_i,
                         seed=CHI2_CASES.index((r, t, theta_i)))
    assert ok, test.messages
    # the whole sphere is covered: histogram and pdf both integrate to 1 (binomial error of
    # 2e5 samples is 0, the trapezoid rule of a cosine lobe on 32 x 64 cells ~1e-3)
    assert abs(test.histogram_sum[0] - 1.0) < 1e-6
    assert abs(test.pdf_sum[0] - 1.0) < 3e-3


def test_chi2_detects_a_wrong_pdf():
    """Power: samples of R 0.2 / T 0.1 against the pdf of R 0.1 / T 0.2 (the lobes' odds
    swapped) are rejected, lit from either face."""
    for theta_i in (30, 150):
        ok, test = chi2_test(dict(reflectance=0.2, transmittance=0.1), theta_i, seed=7,
                             pdf_params=dict(reflectance=0.1, transmittance=0.2))
        assert not ok and test.p_value < 1e-6


def make_si(wi, n):
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    si.wi = mi.Vector3f(*(float(c) for c in wi))
    return si


@pytest.mark.parametrize("theta_i", [0, 60, 89, 120])
def test_albedo_closed_form(theta_i):
    """Directional albedo = R + T at every incidence, from either face: every sample's
    weight is exactly R + T (float32: 1e-6); eval integrated over each hemisphere
    (midpoint rule in (cos theta, phi), 512 x 8 nodes: a cosine lobe integrates exactly
    in cos theta) gives R on the lit side and T on the other (1e-5)."""
    r, t = 0.12, 0.125
    b = leaf(r, t)
    n = 4096
    si = make_si(local_dir(theta_i), n)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(3, n)
    bs, w = b.sample(mi.BSDFContext(), si, sampler.next_1d(), sampler.next_2d())
    w = np.asarray(w[0])
    assert np.allclose(w, r + t, rtol=1e-6)
    lit = np.sign(np.cos(np.radians(theta_i)))
    frac_r = np.mean(np.sign(np.asarray(bs.wo.z)) == lit)     # binomial, 5 sigma
    assert abs(frac_r - r / (r + t)) < 5 * math.sqrt(0.25 / n)
    nc, nphi = 512, 8
    mu = (np.arange(nc) + 0.5) / nc
    phi = (np.arange(nphi) + 0.5) / nphi * 2 * np.pi
    M, P = np.meshgrid(mu, phi)
    for side, expect in ((lit, r), (-lit, t)):
        s = np.sqrt(1 - M ** 2)
        wo = mi.Vector3f((s * np.cos(P)).ravel(), (s * np.sin(P)).ravel(),
                         (side * M).ravel())
        si = make_si(local_dir(theta_i), M.size)
        val = np.asarray(b.eval(mi.BSDFContext(), si, wo)[0])
        # int f |cos| dOmega = sum val / |cos| * |cos| dmu dphi ... eval includes |cos|
        integral = val.sum() * (1.0 / nc) * (2 * np.pi / nphi)
        assert integral == pytest.approx(expect, abs=1e-5)


def test_eval_two_sided_and_reciprocal():
    b = leaf(0.2, 0.1)
    rng = np.random.default_rng(5)
    n = 1000
    a = rng.normal(size=(n, 3))
    c = rng.normal(size=(n, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    c /= np.linalg.norm(c, axis=1, keepdims=True)

    def f(wi, wo):        # eval / |cos theta_o|: the BSDF value itself
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
        si.wi = mi.Vector3f(*wi.T.astype(np.float32))
        v = np.asarray(b.eval(mi.BSDFContext(), si, mi.Vector3f(*wo.T.astype(np.float32)))[0])
        return v / np.abs(wo[:, 2])

    fab = f(a, c)
    assert np.allclose(fab, f(c, a), rtol=1e-5)                    # reciprocity
    flip = np.array([1.0, 1.0, -1.0])
    assert np.allclose(fab, f(a * flip, c * flip), rtol=1e-5)      # the same from the back
    same = np.sign(a[:, 2]) == np.sign(c[:, 2])
    assert np.allclose(fab, np.where(same, 0.2, 0.1) / np.pi, rtol=1e-5)


@pytest.mark.parametrize("params,message", [
    (dict(reflectance=-0.1), "reflectance must be >= 0"),
    (dict(transmittance=-0.1), "transmittance must be >= 0"),
    (dict(reflectance=0.6, transmittance=0.5), r"\+ transmittance must be <= 1"),
])
def test_bad_parameters_refused(params, message):
    with pytest.raises(RuntimeError, match=message):
        mi.load_dict({"type": "bilambertian", **params})


def test_leaf_plate_through_pathlength():
    """A horizontal leaf plate at nadir: the first-surface return weight is
    pi f cos / 0.9 = R / 0.9 (the integrator's reference plate has albedo 0.9), whichever
    face is up; a black leaf returns nothing."""
    from lidar_mitsuba.trace.scene import mitsuba_mesh
    v = np.array([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]], float)
    for faces in (np.array([[0, 1, 2], [0, 2, 3]]), np.array([[0, 2, 1], [0, 3, 2]])):
        scene = mi.load_dict({"type": "scene", "leaf": mitsuba_mesh(
            v, faces, bsdf={"type": "bilambertian", "reflectance": 0.12,
                            "transmittance": 0.125})})
        integ = mi.load_dict({"type": "pathlength", "max_depth": 1})
        ret = integ.trace(scene, shot_x_m=np.zeros(4), shot_y_m=np.zeros(4),
                          paths_per_shot=256, seed=1)
        assert ret.weight.size == 4 * 256
        assert np.allclose(ret.weight, 0.12 / 0.9, rtol=1e-5)
