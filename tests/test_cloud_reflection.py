"""The nadir reflectance factor of a cloud over a surface (atmosphere.cloud_reflection): its
Monte Carlo against closed forms, and what it does to the background under a cloud.

Tolerances: the Monte Carlo returns its own standard error (the per-photon scores' standard
deviation over sqrt(photons)); the checks allow 4 of them (a 6e-5 chance of a false failure
for a normal error), fixed seeds."""
import math

import numpy as np
import pytest

from lidar_mitsuba.atmosphere.cloud_reflection import (direct_sun_factor, h_function, hg_phase,
                                                       nadir_reflectance_factor,
                                                       semi_infinite_isotropic_rho)
from lidar_mitsuba.constants import ParameterError


def test_h_function_matches_chandrasekhars_table():
    # Chandrasekhar 1960, ch. V's table (conservative isotropic): H(0.5) 2.0128, H(1) 2.9078
    h = h_function(np.array([0.0, 0.5, 1.0]))
    assert h[0] == pytest.approx(1.0, abs=1e-9)
    assert h[1] == pytest.approx(2.0128, abs=1e-3)
    assert h[2] == pytest.approx(2.9078, abs=1e-3)


@pytest.mark.parametrize("g, mu0, tau", [(0.85, 0.07, 0.3), (0.85, 0.5, 1.0), (0.0, 0.5, 0.5)])
def test_single_scattering_matches_closed_form(g, mu0, tau):
    """First-order scattering only: a p(-mu0) (1 - exp(-tau (1 + 1/mu0))) / (4 (1 + mu0))."""
    rho, se = nadir_reflectance_factor(optical_depth=tau, g=g, mu0=mu0, surface_albedo=0.0,
                                       max_collisions=1)
    exact = hg_phase(-mu0, g) * (1 - math.exp(-tau * (1 + 1 / mu0))) / (4 * (1 + mu0))
    assert abs(rho - exact) < 4 * se


@pytest.mark.parametrize("mu0", [0.1, 1.0])
def test_semi_infinite_layer_matches_chandrasekhar(mu0):
    """An isotropic layer of albedo 0.9, 60 deep (exp(-60 sqrt(3 x 0.1)) of the diffusion
    field reaches its bottom: semi-infinite), against a H(1) H(mu0) / 4 (1 + mu0)."""
    rho, se = nadir_reflectance_factor(optical_depth=60.0, g=0.0, mu0=mu0, surface_albedo=0.0,
                                       single_scattering_albedo=0.9)
    exact = semi_infinite_isotropic_rho(mu=1.0, mu0=mu0, single_scattering_albedo=0.9)
    assert abs(rho - exact) < 4 * se


def test_no_layer_is_the_lambertian_surface_and_a_cloud_at_grazing_sun_is_not():
    assert nadir_reflectance_factor(optical_depth=0.0, g=0.85, mu0=0.3,
                                    surface_albedo=0.83) == (0.83, 0.0)
    from lidar_mitsuba.atmosphere.cloud_layer import Cloud
    cloud = Cloud(optical_depth=1.1, base_m=4000.0, top_m=5000.0)
    grazing, se = nadir_reflectance_factor(optical_depth=1.1, g=cloud.g, mu0=0.07,
                                           surface_albedo=0.83)
    overhead, _ = nadir_reflectance_factor(optical_depth=1.1, g=cloud.g, mu0=1.0,
                                           surface_albedo=0.83)
    # forward scattering: little of a grazing beam goes to the nadir, more than the
    # Lambertian system albedo of an overhead one does (it is sent back up)
    assert grazing + 4 * se < 0.6 < cloud.system_albedo(0.83) < overhead


def test_direct_sun_factor_lowers_a_low_sun_and_leaves_the_night():
    from lidar_mitsuba.atmosphere.cloud_layer import Cloud
    from lidar_mitsuba.radiometry import Atmosphere
    cloud = Cloud(optical_depth=1.1, base_m=4000.0, top_m=5000.0)
    f = direct_sun_factor(cloud, surface_albedo=0.83, solar_elevation_deg=[-3.0, 4.0, 4.05],
                          z_m=0.0, atmosphere=Atmosphere())
    assert f[0] == 1.0
    assert 0.7 < f[1] < 1.0 and f[2] == pytest.approx(f[1], abs=2e-3)
    with pytest.raises(ParameterError):
        nadir_reflectance_factor(optical_depth=1.0, g=0.85, mu0=0.0, surface_albedo=0.5)
