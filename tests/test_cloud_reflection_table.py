"""The walker both cloud Monte Carlos share (atmosphere.hg_walk) and the cloud's nadir
reflectance table (atmosphere.cloud_reflection_table) against fresh Monte Carlo.

Tolerances: 4 combined standard errors (the fresh Monte Carlo's own, the per-photon scores'
spread over sqrt(photons); the table's from its nodes', propagated to first order): a 6e-5
chance of a false failure for a normal error. Fixed seeds, seeds other than the table's."""
import math

import numpy as np
import pytest

from lidar_mitsuba.atmosphere import cloud_reflection_table as table
from lidar_mitsuba.atmosphere.cloud_layer import Cloud
from lidar_mitsuba.atmosphere.cloud_reflection import (direct_sun_factor,
                                                       nadir_reflectance_factor)
from lidar_mitsuba.atmosphere.hg_walk import Escape, LocalEstimate, collimated, walk
from lidar_mitsuba.constants import ParameterError
from lidar_mitsuba.radiometry import Atmosphere


def test_one_walk_scores_both_ways_and_loses_no_photon():
    """A conservative layer over nothing: every photon leaves by the top or the bottom (the
    walk ends long before its last event); the local estimate scored in the same walk is
    the one ``nadir_reflectance_factor`` gives over a black surface within its error."""
    n = 1 << 12
    escape = Escape()
    local = LocalEstimate(n, optical_depth=2.0, g=0.85, surface_albedo=0.0,
                          single_scattering_albedo=1.0)
    walk(optical_depth=2.0, g=0.85, d=collimated(n, 0.4), rng=np.random.default_rng(5),
         scorings=(escape, local), max_events=4000)
    assert escape.top + escape.bottom == n
    rho, se = nadir_reflectance_factor(optical_depth=2.0, g=0.85, mu0=0.4, surface_albedo=0.0,
                                       photons=n)
    assert abs(local.score.mean() - rho) < 4 * math.hypot(se, local.score.std() / math.sqrt(n))


@pytest.mark.parametrize("tau_index, g, mu0, albedo", [(14, 0.85, 0.2, 0.83),
                                                       (7, 0.75, 0.5, 0.96),
                                                       (18, 0.85, 0.9, 0.3)])
def test_table_nodes_agree_with_fresh_monte_carlo(tau_index, g, mu0, albedo):
    """On the table's nodes (tau 1.28, 0.113, 3.62): its rho over a Lambertian surface
    (the adding rule, eq. (1) of the module) against the Monte Carlo over that surface."""
    tau = float(table.load()["optical_depths"][tau_index])
    mc, mc_se = nadir_reflectance_factor(optical_depth=tau, g=g, mu0=mu0,
                                         surface_albedo=albedo, photons=1 << 14, seed=21)
    tb, tb_se = table.rho(optical_depth=tau, g=g, mu0=mu0, surface_albedo=albedo)
    assert abs(float(tb) - mc) < 4 * math.hypot(mc_se, float(tb_se))


def test_table_limits_and_what_it_covers():
    """No layer is the Lambertian surface exactly; the table covers the run's water and ice
    clouds only, and direct_sun_factor falls back to the Monte Carlo elsewhere."""
    rho, se = table.rho(optical_depth=0.0, g=0.85, mu0=np.array([0.1, 0.7]), surface_albedo=0.83)
    assert np.all(rho == 0.83) and np.all(se == 0.0)
    assert table.covers(optical_depth=20.0, g=Cloud.ice(1, 0, 1).g, single_scattering_albedo=1)
    assert not table.covers(optical_depth=1.0, g=0.6, single_scattering_albedo=1.0)
    assert not table.covers(optical_depth=1.0, g=0.85, single_scattering_albedo=0.9)
    with pytest.raises(ParameterError, match="cloud"):
        table.rho(optical_depth=1.0, g=0.6, mu0=0.5, surface_albedo=0.5)
    odd = Cloud(optical_depth=1.1, base_m=4000.0, top_m=5000.0, g=0.8)
    kw = dict(surface_albedo=0.83, solar_elevation_deg=[12.0], z_m=0.0,
              atmosphere=Atmosphere())
    assert direct_sun_factor(odd, **kw)[0] == direct_sun_factor(odd, tabulated=False, **kw)[0]


def test_both_monte_carlos_give_what_they_gave_before_the_shared_walker():
    """The walker draws its random numbers in the order each of the two loops it replaced
    did: the same seeds give the same numbers (values from the code before it, main at
    66a00ab, 2^13 photons; equal to the bit here, compared to 1e-12 so that another CPU's
    numpy ``exp``/``log`` kernels, a few ulp apart, do not fail it)."""
    from lidar_mitsuba.atmosphere.cloud_shade import layer_reflectance
    assert layer_reflectance(optical_depth=1.1, g=0.85, mu0=0.074,
                             photons=1 << 13) == 0.5906982421875
    for kw, before in [(dict(optical_depth=1.1, g=0.85, mu0=0.07, surface_albedo=0.83),
                        (0.4674619661377736, 0.013545087938262194)),
                       (dict(optical_depth=2.0, g=0.75, mu0=0.5, surface_albedo=1.0,
                             single_scattering_albedo=0.95),
                        (0.6431914248402948, 0.010767196763596864))]:
        assert nadir_reflectance_factor(photons=1 << 13, **kw) == pytest.approx(before,
                                                                                rel=1e-12)
