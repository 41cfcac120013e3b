"""The shade a broken deck casts on its clear gaps (``atmosphere/cloud_shade.py``): the layer
reflectance's Monte Carlo against closed forms, the shade factor's limits, and the night
floor's sunlight under it. Tolerances: three binomial standard errors of the Monte Carlo plus
the closed form's own error where it is an approximation."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from lidar_mitsuba import night
from lidar_mitsuba.atmosphere import cloud_shade
from lidar_mitsuba.atmosphere.cloud_layer import Cloud
from lidar_mitsuba.instrument import Instrument


def _delta_eddington(tau: float, g: float, mu0: float) -> float:
    """Reflectance of a conservative layer, delta-Eddington (Joseph, Wiscombe & Weinman 1976:
    tau' = (1 - g^2) tau, g' = g / (1 + g)), the Eddington conservative solution
    ``[(1 - g') tau' + (2/3 - mu0)(1 - exp(-tau' / mu0))] / [4/3 + (1 - g') tau']``."""
    tp, gp = (1 - g * g) * tau, g / (1 + g)
    return ((1 - gp) * tp + (2 / 3 - mu0) * (1 - math.exp(-tp / mu0))) / (4 / 3 + (1 - gp) * tp)


def test_layer_reflectance_at_normal_incidence_is_delta_eddingtons():
    """At normal incidence delta-Eddington is accurate to ~0.01 in reflectance for conservative
    layers (Joseph et al. 1976); the Monte Carlo within that plus three standard errors."""
    for tau in (1.1, 10.0):
        r = cloud_shade.layer_reflectance(optical_depth=tau, g=0.85, mu0=1.0, photons=1 << 14)
        se = math.sqrt(r * (1 - r) / (1 << 14))
        assert abs(r - _delta_eddington(tau, 0.85, 1.0)) < 0.015 + 3 * se


def test_a_thin_isotropic_layer_reflects_its_single_scattering():
    """A thin isotropic layer lit at normal incidence reflects
    ``(1/2) int_0^1 mu / (1 + mu) (1 - exp(-tau (1 + 1/mu))) dmu`` (single scattering, exact
    to O(tau^2), here < 1e-4) within three standard errors."""
    tau, n = 0.01, 1 << 17
    exact = 0.5 * quad(lambda m: m / (1 + m) * -math.expm1(-tau * (1 + 1 / m)), 0, 1)[0]
    r = cloud_shade.layer_reflectance(optical_depth=tau, g=0.0, mu0=1.0, photons=n)
    assert abs(r - exact) < 3 * math.sqrt(exact / n) + tau ** 2


def test_the_shade_factor_and_its_limits():
    """1 without cover or sun; ``1 - R(mu0)`` under full cover; grazing sun shades more than a
    high one (a layer reflects more of a slant beam); bad input refused."""
    kw = dict(optical_depth=1.1, g=0.85)
    assert cloud_shade.shade_factor(cover=0.0, solar_elevation_deg=4.0, **kw) == 1.0
    assert cloud_shade.shade_factor(cover=0.7, solar_elevation_deg=-1.0, **kw) == 1.0
    full = cloud_shade.shade_factor(cover=1.0, solar_elevation_deg=4.0, **kw)
    half = cloud_shade.shade_factor(cover=0.5, solar_elevation_deg=4.0, **kw)
    assert full == pytest.approx(2 * half - 1)
    assert 0.3 < full < 0.5                                # R(0.074) ~ 0.6 for tau 1.1
    assert cloud_shade.shade_factor(cover=1.0, solar_elevation_deg=60.0, **kw) > 0.9
    with pytest.raises(Exception, match="cover"):
        cloud_shade.shade_factor(cover=1.5, solar_elevation_deg=4.0, **kw)


def test_the_night_floors_sunlight_in_a_decks_gaps():
    """Over a clear gap the sunlight lies between the air above the deck alone and the clear
    sky's, at ``above + (clear - above) * factor``; no cover gives the clear sky's."""
    inst = Instrument.atlas("weak")
    deck = Cloud.water(1.1, 4000.0, 5000.0)
    kw = dict(delta_time_s=np.full(1, 4.9e6), z_m=np.zeros(1), albedo=0.83,
              solar_elevation_deg=np.full(1, 4.0), solar_azimuth_deg=np.full(1, 130.0))
    clear = night.background_terms(inst, **kw)["solar"]
    assert night.background_terms(inst, deck=deck, deck_cover=0.0, **kw)["solar"] == clear
    shaded = night.background_terms(inst, deck=deck, deck_cover=0.75, **kw)["solar"]
    factor = cloud_shade.shade_factor(cover=0.75, optical_depth=1.1, g=deck.g,
                                      solar_elevation_deg=4.0)
    assert factor * clear < shaded < clear


@pytest.mark.parametrize("tau, g, mu0, between", [(1.28, 0.85, 0.2, 0.0),
                                                  (3.620387, 0.75, 0.9, 0.0),
                                                  (1.1, 0.85, 0.074, 0.005),
                                                  (5.0, 0.75, 0.31, 0.005)])
def test_the_tables_reflectance_is_the_monte_carlos(tau, g, mu0, between):
    """``R = 1 - t`` from the shipped table (a conservative layer) against a fresh Monte Carlo
    (another seed than the table's): within four combined binomial standard errors (a 6e-5
    chance of a false failure for a normal error) on the table's nodes, and off them plus
    ``between`` for the table's linear interpolation (ESTIMATE, 0.005: its nodes are 0.02
    apart in mu0 and sqrt(2) in tau, and R bends little between them; the two off-node cases
    measured within 1.2 standard errors)."""
    from lidar_mitsuba.atmosphere import cloud_reflection_table as table
    n = 1 << 15
    mc = cloud_shade.layer_reflectance(optical_depth=tau, g=g, mu0=mu0, photons=n, seed=7)
    r, se = table.reflectance(optical_depth=tau, g=g, mu0=mu0)
    assert abs(float(r) - mc) < 4 * math.hypot(float(se), math.sqrt(mc * (1 - mc) / n)) + between


def test_the_shade_factor_reads_the_table_where_it_holds():
    """A water deck at a 4 deg sun: ``1 - cover R`` with the table's ``R`` at the apparent
    sun's ``mu0``; a sun below the table's lowest ``mu0`` (0.02) and a ``g`` it does not hold
    run the Monte Carlo at ``mu0`` in 0.001 steps."""
    from lidar_mitsuba import sky
    from lidar_mitsuba.atmosphere import cloud_reflection_table as table
    mu0 = float(sky.apparent_mu0(4.0))
    refraction = 1.02 / math.tan(math.radians(4.0 + 10.3 / 9.11)) / 60.0   # Saemundsson
    assert mu0 == pytest.approx(math.sin(math.radians(4.0 + refraction)), rel=1e-12)
    r = float(table.reflectance(optical_depth=1.1, g=0.85, mu0=mu0)[0])
    assert cloud_shade.shade_factor(cover=0.5, optical_depth=1.1, g=0.85,
                                    solar_elevation_deg=4.0) == 1.0 - 0.5 * r
    low = round(float(sky.apparent_mu0(0.3)), 3)
    assert low < 0.02
    for g, elev, m in [(0.85, 0.3, low), (0.8, 4.0, round(mu0, 3))]:
        assert cloud_shade.shade_factor(cover=1.0, optical_depth=1.1, g=g,
                                        solar_elevation_deg=elev) == (
            1.0 - cloud_shade.layer_reflectance(optical_depth=1.1, g=g, mu0=m))
    assert sky.apparent_mu0(-5.0) == 1e-3 and sky.apparent_mu0(90.0) == pytest.approx(1.0)
