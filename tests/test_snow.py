"""Snow as a volume (lidar_mitsuba.ground.snow, the volpathlength integrator): checked against closed
forms, never against itself.

References:
- exact radiative transfer for isotropic scattering in a half-space (Chandrasekhar's
  H-function, tests/closed_forms.py): the nadir return pi f_r = omega H(1)^2 / 8 and the
  hemispherical albedo 1 - H(1) sqrt(1 - omega);
- single scattering in a layer of optical depth tau (exact when only the first interaction
  returns, and the limit of the full walk as tau -> 0);
- diffusion theory (lidar_mitsuba.ground.snow.DiffusionHalfSpace) for the hemispherical albedo and
  the mean and variance of the path length, where it holds (mu_a / mu_s' = 0.01);
- the grain-size law of diffusion: the mean path scales as sqrt(r) at fixed density.

Tolerances: Z = 4.5 sampling standard errors (per-photon sd / sqrt(N) for totals, batch
means over 20 blocks of shots for ratios such as the mean path), plus, for diffusion theory,
its own model error, stated where used.
"""
import math

import mitsuba as mi
import numpy as np
import pytest

from lidar_mitsuba.trace import scene as scn
from lidar_mitsuba.ground import snow
from lidar_mitsuba.constants import C_M_PER_NS, ParameterError, REFERENCE_ALBEDO

from closed_forms import Z, batch_se, chandrasekhar_h

ALT = 496e3


def flat_trace(vol: snow.SnowVolume, *, tally="receiver", max_depth=None, n_shots=100,
               pps=1000, seed=1):
    """Trace a flat snowpack (a 2 km square at z = 0) at nadir with a point footprint and a
    zero-width pulse. Returns per photon (n_shots * pps,) its weight (0 if none) and its
    path length inside the medium [m], and the shot of each photon."""
    v = np.array([[-1e3, -1e3, 0], [1e3, -1e3, 0], [-1e3, 1e3, 0], [1e3, 1e3, 0]], float)
    sc = scn.scene_from_mesh(v, np.array([[0, 1, 3], [0, 3, 2]]), bsdf=vol)
    params = {**vol.integrator_params(), "pulse_sigma_ns": 0.0, "footprint_sigma_m": 0.0,
              "tally": tally}
    if max_depth is not None:
        params["max_depth"] = int(max_depth)
    integ = mi.load_dict(params)
    r = integ.trace(sc, shot_x_m=np.zeros(n_shots), shot_y_m=np.zeros(n_shots),
                    paths_per_shot=pps, seed=seed)
    n = n_shots * pps
    w = np.zeros(n)
    L = np.zeros(n)
    # one record per photon, in photon order within its shot: place them by counting
    assert np.all(np.bincount(r.shot, minlength=n_shots) <= pps)
    idx = np.arange(len(r))
    first = np.searchsorted(r.shot, r.shot)
    slot = r.shot.astype(np.int64) * pps + (idx - first)
    w[slot] = r.weight
    L[slot] = r.time_ns * C_M_PER_NS - 2 * ALT
    return w, L, np.repeat(np.arange(n_shots), pps)


def mean_se(x):
    return float(np.mean(x)), float(np.std(x) / math.sqrt(x.size))


def weighted_moments(w, L):
    """Weighted mean and variance of L."""
    m = np.sum(w * L) / np.sum(w)
    return m, np.sum(w * (L - m) ** 2) / np.sum(w)


def batch_moments(w, L, shot):
    """Weighted mean and variance of L, and their batch-means standard errors (20 blocks of
    shots, closed_forms.batch_se)."""
    n_shots = int(shot.max()) + 1
    se = [batch_se(lambda sel, _n, i=i: weighted_moments(w[sel], L[sel])[i], shot, n_shots)
          for i in (0, 1)]
    return weighted_moments(w, L), se


# --------------------------------------------------------------------------- coefficients
def test_coefficients_from_grain_size_and_density():
    s = snow.snow_from_grains(grain_radius_um=100, density_kg_m3=350)
    f = 350 / 917
    assert s.sigma_t_per_m == pytest.approx(1.5 * f / 100e-6, rel=1e-12)     # 5725 /m
    B = snow.absorption_enhancement()
    assert B == pytest.approx(1.2543, abs=2e-4)      # n = 1.3117, weak-absorption sphere
    assert s.sigma_a_per_m == pytest.approx(1.6 * f * 0.04, rel=1e-12)     # natural snow
    assert s.g == 0.80 and s.absorption_enhancement == 1.6
    spheres = snow.snow_from_grains(grain_radius_um=100, g=snow.G_ICE_SPHERES,
                                    absorption_enhancement_b=None)
    assert spheres.sigma_a_per_m == pytest.approx(B * f * 0.04, rel=1e-12)
    assert s.group_index == pytest.approx(1 + 0.3117 * f, rel=1e-12)
    # absorption does not depend on grain size, scattering goes as 1 / r
    big = snow.snow_from_grains(grain_radius_um=1000, density_kg_m3=350)
    assert big.sigma_a_per_m == pytest.approx(s.sigma_a_per_m)
    assert big.sigma_t_per_m == pytest.approx(s.sigma_t_per_m / 10)
    with pytest.raises(ParameterError) as e:
        snow.snow_from_grains(grain_radius_um=1, density_kg_m3=350)
    assert e.value.name == "snow_grain_um"
    with pytest.raises(ParameterError) as e:
        snow.snow_from_grains(grain_radius_um=100, density_kg_m3=950)
    assert e.value.name == "snow_density"


def test_diffusion_closed_forms_are_consistent():
    """The reference itself: its density integrates to its total, its CDF and moments agree
    with quadrature of the density (a slip in a closed form would show here)."""
    from scipy.integrate import quad
    d = snow.DiffusionHalfSpace(mu_s_prime_per_m=630.0, mu_a_per_m=0.02)
    tot = quad(lambda L: d.path_pdf(L), 0, np.inf, limit=400)[0]
    assert tot == pytest.approx(d.total_reflectance(), rel=1e-7)
    assert d.path_cdf(0.3) == pytest.approx(quad(lambda L: d.path_pdf(L), 0, 0.3,
                                                 limit=400)[0], rel=1e-7)
    m = quad(lambda L: L * d.path_pdf(L), 0, np.inf, limit=400)[0] / tot
    assert d.mean_path_m() == pytest.approx(m, rel=1e-6)
    v = quad(lambda L: (L - m) ** 2 * d.path_pdf(L), 0, np.inf, limit=400)[0] / tot
    assert d.var_path_m2() == pytest.approx(v, rel=1e-5)
    # small absorption: 1 - R -> (5/3) sqrt(3 mu_a / mu_s') (extrapolated boundary)
    d2 = snow.DiffusionHalfSpace(mu_s_prime_per_m=1.0, mu_a_per_m=1e-8)
    assert 1 - d2.total_reflectance() == pytest.approx(5 / 3 * math.sqrt(3e-8), rel=1e-3)


# --------------------------------------------------------------------------- exact transport
@pytest.mark.parametrize("omega", [0.9, 0.99])
def test_nadir_return_matches_chandrasekhar(omega):
    """Isotropic scattering, semi-infinite, index-matched: the nadir return of single and
    multiple scattering is pi f_r = omega H(1)^2 / 8 exactly (weight scale: / 0.9)."""
    sigma_t = 1000.0
    vol = snow.SnowVolume(sigma_s_per_m=omega * sigma_t, sigma_a_per_m=(1 - omega) * sigma_t,
                          g=0.0, max_events=5000)
    w, _, _ = flat_trace(vol, n_shots=100, pps=1000)
    mean, se = mean_se(w)
    exact = omega * chandrasekhar_h(omega, 1.0) ** 2 / 8 / REFERENCE_ALBEDO
    assert abs(mean - exact) < Z * se, (mean, se, exact)


def test_hemispherical_albedo_matches_chandrasekhar():
    """Isotropic scattering: the albedo under a normal beam is 1 - H(1) sqrt(1 - omega)."""
    omega = 0.99
    vol = snow.SnowVolume(sigma_s_per_m=990.0, sigma_a_per_m=10.0, g=0.0, max_events=5000)
    w, _, _ = flat_trace(vol, tally="hemisphere", n_shots=100, pps=1000)
    mean, se = mean_se(w)
    exact = 1 - chandrasekhar_h(omega, 1.0) * math.sqrt(1 - omega)
    assert abs(mean - exact) < Z * se, (mean, se, exact)


# --------------------------------------------------------------------------- single scattering
@pytest.mark.parametrize("g", [0.0, 0.89])
def test_first_interaction_return_is_single_scattering(g):
    """Only the first interaction returning (max_depth 1) over a black base under a layer
    of optical depth 0.5: pi omega p(180 deg) (1 - e^{-2 tau}) / 2 exactly."""
    sigma_t, depth = 1000.0, 5e-4
    vol = snow.SnowVolume(sigma_s_per_m=0.95 * sigma_t, sigma_a_per_m=0.05 * sigma_t, g=g,
                          depth_m=depth, max_events=1)
    w, _, _ = flat_trace(vol, n_shots=100, pps=1000)
    mean, se = mean_se(w)
    p_back = (1 - g * g) / (4 * math.pi * (1 + g) ** 3)           # HG at 180 degrees
    tau = sigma_t * depth
    exact = math.pi * 0.95 * p_back * (1 - math.exp(-2 * tau)) / 2 / REFERENCE_ALBEDO
    assert abs(mean - exact) < Z * se, (mean, se, exact)


def test_layer_over_a_lambertian_base():
    """A purely absorbing layer (tau = 0.5, next to no scattering) over a Lambertian base of
    albedo 0.6: the return is the base's, 0.6 / 0.9 e^{-2 tau} (down and up through the
    layer), and its delay is exactly twice the thickness times the group index."""
    depth, sigma_a = 5e-4, 1000.0
    vol = snow.SnowVolume(sigma_s_per_m=1e-9, sigma_a_per_m=sigma_a, g=0.0, depth_m=depth,
                          base_albedo=0.6, group_index=1.3)
    w, L, _ = flat_trace(vol, n_shots=100, pps=1000)
    mean, se = mean_se(w)
    exact = 0.6 / REFERENCE_ALBEDO * math.exp(-2 * sigma_a * depth)
    assert abs(mean - exact) < Z * se, (mean, se, exact)
    base = w > 1e-3            # (collisions in the layer leave weights of order 1e-12)
    assert base.mean() > 0.3
    np.testing.assert_allclose(L[base], 2 * depth * 1.3, atol=2e-6)   # float64 legs


def test_thin_layer_tends_to_single_scattering():
    """The full walk in an optically thin layer (tau = 0.01, black base): single scattering,
    plus multiple scattering of relative size O(tau) (bounded here by 2 tau)."""
    sigma_t, depth = 1000.0, 1e-5
    vol = snow.SnowVolume(sigma_s_per_m=sigma_t, sigma_a_per_m=0.0, g=0.0, depth_m=depth)
    w, _, _ = flat_trace(vol, n_shots=200, pps=1000)
    mean, se = mean_se(w)
    tau = sigma_t * depth
    single = math.pi / (4 * math.pi) * (1 - math.exp(-2 * tau)) / 2 / REFERENCE_ALBEDO
    assert abs(mean - single) < Z * se + 2 * tau * single, (mean, se, single)


def test_energy_conservation():
    """No absorption: the albedo is 1 less the light still inside after max_depth
    interactions (diffusion's path-length tail beyond max_depth free paths); with absorption
    it is below that, and it falls as absorption grows."""
    vol = snow.SnowVolume(sigma_s_per_m=1000.0, sigma_a_per_m=0.0, g=0.0, max_events=20000)
    w, _, _ = flat_trace(vol, tally="hemisphere", n_shots=20, pps=1000)
    r0, se0 = mean_se(w)
    assert np.all(w <= 1.0 + 1e-6)
    lost = vol.diffusion().total_reflectance() - vol.diffusion().path_cdf(20000 / 1000.0)
    assert abs(r0 - (1 - lost)) < Z * se0 + 0.005, (r0, lost)
    albedos = []
    for mu_a in (1.0, 10.0):
        v = snow.SnowVolume(sigma_s_per_m=1000.0, sigma_a_per_m=mu_a, g=0.0, max_events=5000)
        albedos.append(mean_se(flat_trace(v, tally="hemisphere", n_shots=20, pps=1000)[0])[0])
    assert r0 > albedos[0] > albedos[1]


# --------------------------------------------------------------------------- diffusion theory
@pytest.mark.parametrize("g, sigma_s", [(0.0, 1000.0), (0.89, 1000.0 / 0.11)])
def test_hemisphere_matches_diffusion_theory(g, sigma_s):
    """mu_a / mu_s' = 0.01 (mu_s' = 1000 /m for both g, the similarity principle): total,
    mean and variance of the path length against the extrapolated-boundary dipole. Model
    error allowed on top of Z standard errors: 2 % on the total, 8 % on the moments
    (diffusion's error at this absorption; an independent numpy random walk of the same
    medium differs from it by 1 % and 7 %)."""
    vol = snow.SnowVolume(sigma_s_per_m=sigma_s, sigma_a_per_m=10.0, g=g, max_events=20000)
    w, L, shot = flat_trace(vol, tally="hemisphere", n_shots=40, pps=1000)
    d = vol.diffusion()
    r, se = mean_se(w)
    assert abs(r - d.total_reflectance()) < Z * se + 0.02 * d.total_reflectance()
    (m, v), (m_se, v_se) = batch_moments(w, L, shot)
    assert abs(m - d.mean_path_m()) < Z * m_se + 0.08 * d.mean_path_m(), (m, d.mean_path_m())
    assert abs(v - d.var_path_m2()) < Z * v_se + 0.08 * d.var_path_m2(), (v, d.var_path_m2())


def test_mean_path_grows_as_sqrt_of_grain_size():
    """Diffusion: mean path = sqrt(3) / (2 sqrt(mu_s' mu_a)) up to the boundary term, and
    mu_s' ~ 1/r at fixed density: four times the grain radius doubles the mean extra path.
    (Ice absorption raised to 4 /m here so that paths stay short; the law is the same.)"""
    means = []
    for r_um in (50, 200):
        vol = snow.snow_from_grains(grain_radius_um=r_um, density_kg_m3=350,
                                    ice_absorption_per_m=4.0, group_index=1.0,
                                    max_events=50000)
        w, L, shot = flat_trace(vol, tally="hemisphere", n_shots=20, pps=500)
        (m, _), (m_se, _) = batch_moments(w, L, shot)
        means.append((m, m_se, vol.diffusion().mean_path_m()))
    ratio = means[1][0] / means[0][0]
    ratio_se = ratio * math.hypot(means[0][1] / means[0][0], means[1][1] / means[1][0])
    theory = means[1][2] / means[0][2]
    assert 1.9 < theory < 2.0                       # sqrt(4) less the boundary term
    assert abs(ratio - theory) < Z * ratio_se + 0.05 * theory, (ratio, theory)


def test_return_path_lengths_and_a_gamma_law():
    """Hu et al. (2022) describe the lidar return of snow by a Gamma law of path length.
    Fitted by maximum likelihood it stays within 0.15 of the return's cumulative
    distribution (Kolmogorov distance; 0.115 measured), and diffusion theory's law (the
    dipole, normalised) as well, while a Gamma law with the return's mean and variance
    does not (0.30): the L^-3/2 tail makes moments a poor way to fit it."""
    from scipy import stats
    vol = snow.snow_from_grains(grain_radius_um=200, density_kg_m3=350,
                                ice_absorption_per_m=4.0, group_index=1.0, max_events=50000)
    w, L, _ = flat_trace(vol, n_shots=20, pps=1000)
    keep = w > 0
    w, L = w[keep], np.maximum(L[keep], 1e-9)
    order = np.argsort(L)
    cdf = np.cumsum(w[order]) / np.sum(w)
    x = L[order]
    k, theta = snow.gamma_fit(L, w)
    assert 0.3 < k < 1.5                             # a skewed law, not a Gaussian
    dist = np.max(np.abs(cdf - stats.gamma.cdf(x, k, scale=theta)))
    assert dist < 0.15, dist
    d = vol.diffusion()
    assert np.max(np.abs(cdf - d.path_cdf(x) / d.total_reflectance())) < 0.15
    m, v = weighted_moments(w, L)
    moments = np.max(np.abs(cdf - stats.gamma.cdf(x, m * m / v, scale=v / m)))
    assert moments > dist + 0.1, (moments, dist)


# --------------------------------------------------------------------------- plumbing
def test_pathlength_refuses_a_medium_and_xml_medium_runs(tmp_path):
    from lidar_mitsuba.run import simulate
    vol = snow.snow_from_grains(grain_radius_um=200, density_kg_m3=350)
    xml = tmp_path / "snow.xml"
    xml.write_text(f"""<scene version="3.0.0">
  <shape type="rectangle">
    <transform name="to_world"><scale value="500"/><translate x="500" y="500"/></transform>
    {vol.xml()}
  </shape>
</scene>""")
    sc = mi.load_file(str(xml))
    plain = mi.load_dict({"type": "pathlength"})
    with pytest.raises(ValueError, match="volpathlength"):
        plain.trace(sc, shot_x_m=np.array([500.0]), shot_y_m=np.array([500.0]))
    res = simulate(scene_file=str(xml), shots=150, seed=2, progress=False)
    assert res.config["integrator"] == "volpathlength"
    rep = res.report().overall
    # the snow delays the return: photons appear below the surface, beyond 3 of the run's
    # own standard errors (150 shots: -9.2 +- 1.7 cm, 5.5 SE; 300 shots, 18 s CPU against
    # 9 s: -11.9 +- 1.4 cm, 8.6 SE)
    assert rep.bias_m < -3 * rep.bias_se_m
    with pytest.raises(ParameterError) as e:
        simulate(scene_file=str(xml), snow=vol, shots=10, progress=False)
    assert e.value.name == "snow"


def test_cli_snow_options(tmp_path, capsys):
    """--snow-* run through the whole chain; bad values: one line naming the option, exit 2,
    no file (in process, as the run itself: tests/cli_checks.py; a process each cost seconds
    of start-up, and tests/test_cli.py starts the command's own process)."""
    from cli_checks import bad_call
    from lidar_mitsuba.cli import main
    out = tmp_path / "s.h5"
    code = main(["simulate", "--surface", "flat", "--snow-grain-um", "100",
                 "--snow-max-events", "2000", "--shots", "200", "--out", str(out),
                 "--explain", "--no-progress"])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "snow volume on (grains r = 100 um" in printed.out and out.is_file()
    for args, flag in ((["--snow-grain-um", "2"], "--snow-grain-um"),
                       (["--snow-density", "300"], "--snow-density"),
                       (["--snow-grain-um", "100", "--snow-density", "2000"], "--snow-density"),
                       (["--snow-grain-um", "100", "--snow-max-events", "0"],
                        "--snow-max-events")):
        bad = tmp_path / "bad.h5"
        err = bad_call(["simulate", "--surface", "flat", "--shots", "10", "--out", str(bad)]
                       + args, capsys)
        assert flag in err and not bad.exists(), err


def test_snow_over_a_dem_granule_across_sections(tmp_path):
    """The streamed granule path (DEM corridor tiles, sections, ATL03 + ATL06 files) with a
    snow volume: each section keeps the snow, and the segments sit lower than without it."""
    import h5py
    import json
    from lidar_mitsuba.ground import dem as dems
    from lidar_mitsuba import geotrack, granule
    dem = dems.DEM.open(dems.synthetic_ice_sheet(tmp_path / "ice.tif"))
    track = geotrack.GeoTrack(start_lat_deg=69.97, start_lon_deg=-45.0, azimuth_deg=0.0)
    vol = snow.snow_from_grains(grain_radius_um=1000, density_kg_m3=350).similar(0.0)
    h_li = {}
    for name, kw in (("bare", {"max_depth": 1}), ("snow", {"snow": vol})):
        a3, a6 = tmp_path / f"{name}3.h5", tmp_path / f"{name}6.h5"
        out = granule.stream_granule(surface=dems.DEMSurface(dem, tile_shots=512), track=track,
                                     shots=1400, beams="gt1l", atl03_path=a3, atl06_path=a6,
                                     seed=4, progress=False, section_shots=700, **kw)
        assert out[0].shots == 1400
        with h5py.File(a3, "r") as f3, h5py.File(a6, "r") as f6:
            cfg = json.loads(f3.attrs["config"])
            assert cfg["sections"] == 2
            li = f6["gt1l/land_ice_segments"]
            h, q = li["h_li"][()], li["atl06_quality_summary"][()]
            z = li["dem/h_ref_m"][()]              # the reference under each segment
            good = q == 0
            h_li[name] = h[good] - z[good]
    bare, wet = h_li["bare"], h_li["snow"]
    diff = wet.mean() - bare.mean()
    se = math.hypot(wet.std() / math.sqrt(wet.size), bare.std() / math.sqrt(bare.size))
    assert diff < -0.05 and diff < -Z * se, (diff, se)


# --------------------------------------------------------------------------- wind crust
def test_crust_limits_and_energy():
    """A two-layer pack (a denser crust over the pack) against its limits: a crust with the
    pack's own optics is the single layer; a crust far thicker than the paths is the crust's
    own half-space; with white layers and a white base every photon comes back (exactly)."""
    import dataclasses
    lower = snow.SnowVolume(sigma_s_per_m=1000.0, sigma_a_per_m=10.0, g=0.5, max_events=20000)
    top = snow.SnowVolume(sigma_s_per_m=3000.0, sigma_a_per_m=10.0, g=0.7, group_index=1.2)
    pairs = ((dataclasses.replace(lower, crust_m=0.01, crust=lower), lower),
             (dataclasses.replace(lower, crust_m=1.0, crust=top), top))
    for two, one in pairs:
        for tally in ("hemisphere", "receiver"):
            res = []
            for v in (two, one):
                w, L, shot = flat_trace(v, tally=tally, n_shots=40, pps=1000)
                res.append((mean_se(w), batch_moments(w, L, shot)))
            ((r2, se2), ((m2, _), (ms2, _))), ((r1, se1), ((m1, _), (ms1, _))) = res
            assert abs(r2 - r1) < Z * math.hypot(se1, se2), (tally, r1, r2)
            assert abs(m2 - m1) < Z * math.hypot(ms1, ms2), (tally, m1, m2)
    white = dataclasses.replace(
        snow.SnowVolume(sigma_s_per_m=500.0, sigma_a_per_m=0.0, g=0.3, max_events=200000),
        crust_m=0.003, crust=snow.SnowVolume(sigma_s_per_m=3000.0, sigma_a_per_m=0.0, g=0.7),
        depth_m=0.05, base_albedo=1.0)
    w, _, _ = flat_trace(white, tally="hemisphere", n_shots=20, pps=1000)
    assert abs(w.mean() - 1.0) < 1e-5
    with pytest.raises(ParameterError) as e:
        dataclasses.replace(lower, crust_m=0.01)              # a crust needs its optics
    assert e.value.name == "snow_crust_m"
