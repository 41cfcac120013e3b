"""Ridge sails on sea ice (lidar_mitsuba/ground/sea_ice_ridges.py): the synthesised ridge
heights against the shot-noise closed forms (Campbell's theorem: mean, variance, third
central moment; the Boolean model's covered fraction), the rough surface's total rms and
skewness with ridges, and the surface spec's option. Tolerances: each seed's tile is one
estimate, their mean within 4 standard errors of the seeds' spread."""
import math

import numpy as np
import pytest
from scipy import integrate

from lidar_mitsuba.constants import ParameterError
from lidar_mitsuba.ground import sea_ice_ridges as sr
from lidar_mitsuba.ground import sea_ice_surface as sis
from lidar_mitsuba.ground.surface import SurfaceSpec

ARCTIC = sr.RIDGES["arctic_obstacles"]
#: short sails on a small tile (~130 independent sails a tile) and a narrower spread of heights
#: above a higher cutoff: a tile's third moment is otherwise dominated by its one or two
#: tallest sails (its estimate heavy-tailed, the seeds' spread no measure of its error); the
#: published heights on 1024 m tiles agree as well (docs/physics/sea-ice-surface.md)
TEST_RIDGES = {**ARCTIC, "length_m": 10.0, "cutoff_m": 0.35}
N, GRID_M, SEEDS = 256, 0.5, range(16)


def _mean_and_se(values):
    v = np.asarray(values, np.float64)
    return float(v.mean()), float(v.std(ddof=1) / math.sqrt(v.size))


@pytest.fixture(scope="module")
def fields():
    return [sr.ridge_field(n=N, grid_m=GRID_M, rng=np.random.default_rng(s), **TEST_RIDGES)
            for s in SEEDS]


def test_height_moments_against_direct_integration():
    """E[H^k] of the shifted exponential, closed form against quadrature."""
    c, b = ARCTIC["cutoff_m"], ARCTIC["mean_height_m"] - ARCTIC["cutoff_m"]
    for k in (1, 2, 3, 4):
        want = integrate.quad(lambda x: (c + x) ** k * math.exp(-x / b) / b, 0, math.inf)[0]
        got = sr.height_moment(k, mean_height_m=ARCTIC["mean_height_m"], cutoff_m=c)
        assert got == pytest.approx(want, rel=1e-9)
    assert sr.height_moment(1, mean_height_m=0.45, cutoff_m=0.2) == pytest.approx(0.45)


def test_ridge_cumulants_match_campbell(fields):
    """Mean, variance and third central moment of the tiles' heights against kappa_1..3
    (independent of the sails' length)."""
    want = sr.cumulants(**TEST_RIDGES)
    est = [(z.mean(), z.var(), np.mean((z - z.mean()) ** 3)) for z in fields]
    for i in range(3):
        m, se = _mean_and_se([e[i] for e in est])
        assert abs(m - want[i]) < 4 * se, (i, m, se, want[i])
    assert min(z.min() for z in fields) >= 0.0


def test_covered_fraction_is_the_boolean_models(fields):
    """The share of the tile under a sail: 1 - exp(-L_A E[2 w]) (Poisson sails of area
    l 2w each, overlaps included), w = H / tan(alpha): checks the spacing's conversion to a
    line density (Buffon) and the sails' width."""
    t = math.tan(math.radians(TEST_RIDGES["sail_angle_deg"]))
    want = 1.0 - math.exp(-sr.line_density_per_m(TEST_RIDGES["spacing_m"])
                          * 2.0 * TEST_RIDGES["mean_height_m"] / t)
    m, se = _mean_and_se([np.mean(z > 0) for z in fields])
    assert abs(m - want) < 4 * se, (m, se, want)


def test_rough_sea_ice_with_ridges_keeps_the_rms_and_gains_the_skew():
    """With ridges the Gaussian is the ridge-free surface scaled to sqrt(sigma^2 - kappa_2)
    (same seed, to rounding) plus the sails; over seeds the total rms is sigma and the height
    skewness kappa_3 / sigma^3 (~3 for the Fram Strait preset)."""
    rms, corr, size, grid = 0.16, 10.0, 128.0, 0.5
    k = sr.cumulants(**ARCTIC)
    rms2, skew = [], []
    for s in range(8):
        z = sis.rough_sea_ice(rms_m=rms, corr_length_m=corr, size_m=size, grid_m=grid, seed=s,
                              ridges="arctic_obstacles").z_m
        rms2.append(np.mean(z * z))
        skew.append(np.mean(z ** 3) / rms ** 3)
        if s == 0:
            plain = sis.rough_sea_ice(rms_m=rms, corr_length_m=corr, size_m=size, grid_m=grid,
                                      seed=s).z_m
            rng = np.random.default_rng(s)
            rng.standard_normal(plain.shape)
            r = sr.ridge_field(n=plain.shape[0], grid_m=grid, rng=rng, **ARCTIC)
            g = plain * math.sqrt(rms ** 2 - k[1]) / rms + r
            np.testing.assert_allclose(z, g - g.mean(), atol=1e-12)
    m, se = _mean_and_se(rms2)
    assert abs(m - rms ** 2) < 4 * se, (m, se)
    m, se = _mean_and_se(skew)
    assert abs(m - k[2] / rms ** 3) < 4 * se and m > 1.0, (m, se, k[2] / rms ** 3)


def test_the_spec_option_and_its_checks():
    spec = SurfaceSpec(kind="sea_ice", size_m=128.0, grid_m=0.5, surface_corr_m=8.0)
    assert spec.surface_ridges == sis.PRESETS[sis.DEFAULT_PRESET]["ridges"] == "arctic_obstacles"
    assert spec.config()["surface_ridges"] == "arctic_obstacles"
    assert "surface_ridges" not in SurfaceSpec(kind="flat").config()
    z = spec.build().hf.z_m
    assert np.mean(z ** 3) > 0                         # positively skewed
    for kw, name in (({"surface_ridges": "alps"}, "surface_ridges"),
                     ({"surface_rms_m": 0.09}, "surface_ridges"),     # ridges' own 0.129 m
                     ({"size_m": 64.0}, "size_m")):                    # 50 m sails
        with pytest.raises(ParameterError) as e:
            SurfaceSpec(**{"kind": "sea_ice", "grid_m": 0.5, "size_m": 128.0,
                           "surface_corr_m": 8.0, **kw})
        assert e.value.name == name
    with pytest.raises(ParameterError) as e:           # not silently ignored elsewhere
        SurfaceSpec(kind="fractal", surface_ridges="none")
    assert e.value.name == "surface_ridges"
    # the smoother published ice has no ridges; its preset builds
    p = sis.PRESETS["nansen_basin"]
    SurfaceSpec(kind="sea_ice", surface_rms_m=p["rms_m"], surface_ridges=p["ridges"])
