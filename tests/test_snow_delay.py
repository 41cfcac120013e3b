"""The snowpack's delay of the surface return (lidar_mitsuba.ground.snow.delay): its closed
form against its own sampler and against diffusion theory's long-path asymptote, the pack
average, and the leak it adds to the night floor (lidar_mitsuba.studies.realism).

Tolerances: sampled survival fractions within five binomial standard errors
``sqrt(p (1 - p) / n)`` plus the sampler's interpolation error (log-spaced nodes, 1200 over
eight decades: a relative step of 1.6 %, which moves a survival fraction falling as
``d^-1/2`` by < 1 % of itself)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from lidar_mitsuba.ground import snow
from lidar_mitsuba.ground.snow import delay
from lidar_mitsuba.studies import realism


def test_apparent_depths_drawn_follow_the_closed_form():
    vol = snow.snow_from_grains(grain_radius_um=130.0, density_kg_m3=350.0)
    rng = np.random.default_rng(2021)
    n = 200_000
    d = delay.sample_apparent_depth_m(vol, n, rng)
    depths = np.array([0.01, 0.2, 0.5, 3.0, 20.0])
    sf = delay.apparent_depth_sf(vol, depths)
    got = np.array([np.mean(d > x) for x in depths])
    se = np.sqrt(sf * (1 - sf) / n)
    assert np.all(np.abs(got - sf) <= 5 * se + 0.01 * sf)
    assert sf[2] == pytest.approx(0.045, abs=0.01)     # wind slab: ~4 % from > 0.5 m down


def test_the_tail_falls_as_diffusions_inverse_square_root():
    """Without absorption the share returned from more than ``d`` below tends to
    ``(a1 + a2) / (2 sqrt(pi L))``, ``L = 2 d / n_g`` (the two inverse-Gaussian laws of the
    extrapolated boundary, ``a_i`` their shapes): within 1 % at L >= 1e4 transport paths."""
    vol = snow.SnowVolume(sigma_s_per_m=2000.0, sigma_a_per_m=0.0, g=0.8, group_index=1.1)
    half = vol.diffusion()
    a = half._a
    for d in (5.0, 50.0):
        L = 2 * d / vol.group_index
        asymptote = float(np.sum(a)) / (2 * math.sqrt(math.pi * L))
        assert delay.apparent_depth_sf(vol, d) == pytest.approx(asymptote, rel=0.01)


def test_a_pack_with_a_crust_is_averaged_over_its_depth():
    vol = snow.snow_from_grains(grain_radius_um=330.0, density_kg_m3=250.0, depth_m=0.18,
                                crust_m=0.05, crust_grain_um=130.0, crust_density_kg_m3=350.0)
    one = delay.averaged_pack(vol)
    w = 0.05 / 0.18
    assert one.reduced_scattering_per_m == pytest.approx(
        w * vol.crust.reduced_scattering_per_m + (1 - w) * vol.reduced_scattering_per_m)
    assert one.sigma_a_per_m == pytest.approx(
        w * vol.crust.sigma_a_per_m + (1 - w) * vol.sigma_a_per_m)
    plain = snow.snow_from_grains(grain_radius_um=130.0)
    assert delay.averaged_pack(plain) is plain
    # Ward snow's nadir weights: diffuse 0.9 / pi against specular 0.05 / (4 pi 0.3^2)
    assert delay.volume_share(rho_d=0.9, rho_s=0.05, alpha=0.3) == pytest.approx(
        0.9 / (0.9 + 0.05 / 0.36))


def test_the_snows_leak_is_in_the_lidar_equations_night_floor():
    """Without a simulation the leak's outside fraction is the pulse's and the snow's
    together, ``1 - (1 - f_pulse)(1 - share SF(w / 2))``."""
    from lidar_mitsuba import night
    from lidar_mitsuba.constants import C_M_PER_NS
    from lidar_mitsuba.instrument import Instrument
    inst = Instrument.atlas("weak")
    span = 0.9
    f = realism.equation_outside_fraction(inst, span, surface=realism.PRODUCT_SURFACES["sea ice"])
    pack, share = realism.snow_delay(realism.PRODUCT_SURFACES["sea ice"])
    f_pulse = night.gaussian_outside_fraction(span, C_M_PER_NS * inst.pulse_sigma_ns / 2.0)
    assert f == pytest.approx(1 - (1 - f_pulse) * (1 - share * delay.apparent_depth_sf(
        pack, span / 2)))
    assert 0.03 < f < 0.12 and f > 10 * f_pulse
    water = realism.equation_outside_fraction(inst, span,
                                              surface=realism.PRODUCT_SURFACES["ocean"])
    assert water == pytest.approx(f_pulse)
