"""Rough sea ice of published roughness (lidar_mitsuba/ground/sea_ice_surface.py): the
synthesised surface has the exponential autocorrelation and the segment-scale rms of its
closed forms, within the sampling error of a few tiles; the built-in surface spec."""
import math

import numpy as np
import pytest

from lidar_mitsuba.constants import ParameterError
from lidar_mitsuba.ground import sea_ice_surface as sis
from lidar_mitsuba.ground.surface import HeightfieldSurface, SurfaceSpec

RMS_M, CORR_M, SIZE_M, GRID_M = 0.16, 10.0, 256.0, 0.5
SEEDS = range(8)


@pytest.fixture(scope="module")
def tiles():
    return [sis.rough_sea_ice(rms_m=RMS_M, corr_length_m=CORR_M, size_m=SIZE_M,
                              grid_m=GRID_M, seed=s).z_m for s in SEEDS]


def _mean_and_se(values):
    v = np.asarray(values, np.float64)
    return float(v.mean()), float(v.std(ddof=1) / math.sqrt(v.size))


def test_rms_over_the_tile_is_the_input(tiles):
    for z in tiles:
        assert z.shape == (512, 512)
        assert abs(z.mean()) < 1e-12 and np.sqrt(np.mean(z * z)) == pytest.approx(RMS_M, 1e-12)


def test_autocorrelation_is_exponential(tiles):
    """The sample autocorrelation at lags L/2, L and 2L (along both axes) against
    exp(-lag / L): each seed's tile is one estimate, their mean within 4 standard errors
    (the seeds' spread) plus the tile's finite-size bias (its mean removed: a few 0.01 at
    L / size = 1/25, ESTIMATE bounded by 0.03)."""
    for lag_m in (0.5 * CORR_M, CORR_M, 2.0 * CORR_M):
        k = int(round(lag_m / GRID_M))
        est = [0.5 * (np.mean(z * np.roll(z, k, 0)) + np.mean(z * np.roll(z, k, 1)))
               / np.mean(z * z) for z in tiles]
        m, se = _mean_and_se(est)
        assert abs(m - math.exp(-lag_m / CORR_M)) < 4 * se + 0.03, (lag_m, m, se)


def test_rms_within_a_segment_matches_the_closed_form(tiles):
    """What a segment's reference leaves of the relief: the rms height about the mean of
    each 20 m stretch of every row, against sigma sqrt(1 - rho_bar(20 m)); the seeds' spread
    gives the standard error."""
    n = int(round(20.0 / GRID_M))
    est = []
    for z in tiles:
        seg = z[:, : z.shape[1] // n * n].reshape(z.shape[0], -1, n)
        est.append(np.sqrt(np.mean((seg - seg.mean(axis=-1, keepdims=True)) ** 2)))
    m, se = _mean_and_se(est)
    want = sis.segment_rms_m(rms_m=RMS_M, corr_length_m=CORR_M, segment_m=20.0)
    assert abs(m - want) < 4 * se + 0.02 * want, (m, se, want)
    # the closed form's limits: nothing inside a point, all of it over a long segment
    assert sis.segment_rms_m(rms_m=1.0, corr_length_m=1.0, segment_m=0.0) == pytest.approx(0.0)
    assert sis.segment_rms_m(rms_m=1.0, corr_length_m=1.0, segment_m=1e6) == \
        pytest.approx(1.0, abs=1e-3)


def test_the_built_in_spec_and_its_record():
    spec = SurfaceSpec(kind="sea_ice", size_m=64.0, grid_m=0.5, surface_corr_m=4.0,
                       surface_ridges="none")
    surf = spec.build()
    assert isinstance(surf, HeightfieldSurface) and surf.hf.periodic
    assert np.std(surf.hf.z_m) == pytest.approx(sis.PRESETS["fram_strait"]["rms_m"])
    assert spec.config()["surface_rms_m"] == 0.16
    # the other kinds' records are as before: no sea-ice fields
    assert "surface_rms_m" not in SurfaceSpec(kind="flat").config()
    assert "surface_corr_m" not in SurfaceSpec().config()
    for kw, name in (({"surface_rms_m": -0.1}, "surface_rms_m"),
                     ({"surface_corr_m": 0.5}, "surface_corr_m"),
                     ({"surface_corr_m": 200.0}, "surface_corr_m")):
        with pytest.raises(ParameterError) as e:
            SurfaceSpec(kind="sea_ice", **kw)
        assert e.value.name == name
    with pytest.raises(ParameterError) as e:          # not silently ignored elsewhere
        SurfaceSpec(kind="fractal", surface_rms_m=0.09)
    assert e.value.name == "surface_rms_m"


def test_which_ice_gets_a_preset():
    """One rule for validate's sea-ice twin and the realism matrix's sea-ice rows: the
    central Arctic pack (the shipped subset, 87.3 N) gets the Fram Strait preset, the spec
    ``validate`` always ran (so its twin is the same to the bit); seasonal ice (Baffin Bay's
    ATL07, 69 N; the Southern Ocean) stays flat."""
    from lidar_mitsuba import twin
    assert sis.site_preset(lat_deg=87.3)[0] == sis.DEFAULT_PRESET == "fram_strait"
    assert sis.site_preset(lat_deg=sis.CENTRAL_ARCTIC_LAT_DEG)[0] == "fram_strait"
    for lat in (69.3, 79.9, -65.0, float("nan")):
        preset, why = sis.site_preset(lat_deg=lat)
        assert preset is None and "first-year" in why
    spec, why = twin.sea_ice_surface(lat_deg=87.3)
    assert spec == SurfaceSpec(kind="sea_ice") and "Fram Strait" in why
    assert twin.sea_ice_surface(lat_deg=87.3, size_m=256.0)[0] == SurfaceSpec(kind="sea_ice",
                                                                               size_m=256.0)
    assert twin.sea_ice_surface(lat_deg=69.3)[0] is None
