"""The sun and sky model (lidar_mitsuba/sky.py) against independent references: numerical
integration, published formulas and models (SPECTRL2, Bennett's refraction, Kasten & Young),
published twilight illuminance, and the Mitsuba renders tabulated once in
lidar_mitsuba/data/sky_table.json. All closed-form: no rendering here."""
import math

import numpy as np
import pytest

from lidar_mitsuba import radiometry, sky
from lidar_mitsuba.instrument import Instrument

TAU_R = float(radiometry.rayleigh_optical_depth(532.0))


def _sky(elev, **kw):
    args = dict(z_m=0.0, albedo=0.2, tau_rayleigh=TAU_R, aerosol_optical_depth=0.05)
    args.update(kw)
    return sky.sky(solar_elevation_deg=np.atleast_1d(np.asarray(elev, float)), **args)


def test_chapman_column_matches_numerical_integration():
    """The asymptotic Chapman function, above and below the local horizontal, against a
    trapezoid integral along the straight ray (0.6 M steps of 5 m: error < 1e-5); the
    asymptotic form is good to 0.2 % for r / H > 300 (Rees 1989)."""
    h_m = 8000.0
    for z, elev in [(0.0, 0.0), (0.0, 4.0), (0.0, 30.0), (5000.0, -1.0), (10000.0, -3.0),
                    (50000.0, -6.0)]:
        s = np.linspace(0.0, 3.0e6, 600001)
        r = sky.EARTH_RADIUS_M + z
        rr = np.sqrt(r * r + 2 * r * s * math.sin(math.radians(elev)) + s * s)
        numeric = np.trapezoid(np.exp(-(rr - sky.EARTH_RADIUS_M) / h_m) / h_m, s)
        closed = sky.chapman_column(math.exp(-z / h_m), z, elev, h_m)
        assert closed == pytest.approx(numeric, rel=2e-3), (z, elev)


def test_air_mass_and_refraction_published_values():
    """Kasten & Young (1989): their formula within 0.5 % of their numerically integrated
    38.0868 air masses at the horizon (the formula's stated accuracy); Saemundsson's
    refraction is the inverse of Bennett's (1982) formula ``R = cot(h_a + 7.31 / (h_a + 4.4))``
    arcmin of the apparent elevation to within 0.1 arcmin (Meeus 1998, ch. 16, says 4'')."""
    assert float(sky.kasten_young_air_mass(0.0)) == pytest.approx(38.0868, rel=5e-3)
    assert float(sky.kasten_young_air_mass(90.0)) == pytest.approx(1.0, abs=1e-3)
    for h0 in (-0.5, 0.0, 1.0, 4.0, 10.0, 45.0):
        r = float(sky.saemundsson_refraction_deg(h0))
        ha = h0 + r
        bennett = 1.0 / math.tan(math.radians(ha + 7.31 / (ha + 4.4))) / 60.0
        assert abs(r - bennett) * 60.0 < 0.1, h0


def test_single_scattering_matches_plane_parallel_at_high_sun():
    """At a high sun the Earth is flat: the first-order radiance straight up from a pure
    Rayleigh atmosphere is ``mu0 P / (4 pi (mu0 + 1)) (1 - exp(-tau (1 / mu0 + 1)))``
    (Chandrasekhar 1960); the 48 layers' midpoint rule is good to 0.5 %."""
    for elev in (30.0, 60.0, 90.0):
        mu0 = math.sin(math.radians(elev))
        got = _sky(elev, albedo=0.0, aerosol_optical_depth=0.0, ozone_optical_depth=0.0,
                   refraction=False, multiple_scattering=False).path_radiance[0]
        p = 0.75 * (1.0 + mu0 ** 2)
        want = mu0 * p / (4 * math.pi * (mu0 + 1)) * (1 - math.exp(-TAU_R * (1 / mu0 + 1)))
        assert got == pytest.approx(want, rel=5e-3), elev


def test_against_spectrl2_at_high_sun():
    """SPECTRL2 (Bird & Riordan 1986, pvlib.spectrum.spectrl2), an independent clear-sky
    spectral model, at 532 nm (interpolated between its 530 and 540 nm), the same aerosol
    optical depth at 532 nm (Angstrom 1.14 from 500 nm), 0.3 atm cm of ozone, albedo 0.2:
    the direct beam's transmittance within 1 % (both Beer's law through the same columns;
    Rayleigh by Bird's fit against Bodhaine's), the diffuse irradiance within 20 % (SPECTRL2's
    diffuse is Bird & Hulstrom's parameterisation, stated good to ~10 % against rigorous
    transfer codes; we find 9-12 % more)."""
    pvlib = pytest.importorskip("pvlib")
    from pvlib.spectrum import spectrl2
    zen = np.array([20.0, 40.0, 60.0, 20.0, 40.0, 60.0])
    aod = np.array([0.05, 0.05, 0.05, 0.15, 0.15, 0.15])
    r = spectrl2(apparent_zenith=zen, aoi=zen, surface_tilt=0.0, ground_albedo=0.2,
                 surface_pressure=101325.0,
                 relative_airmass=pvlib.atmosphere.get_relative_airmass(zen, "kastenyoung1989"),
                 precipitable_water=0.5, ozone=0.3,
                 aerosol_turbidity_500nm=aod * (532 / 500) ** 1.14, dayofyear=1,
                 aerosol_asymmetry_factor=0.65)
    w = np.asarray(r["wavelength"]).ravel()
    k = np.searchsorted(w, 532.0)
    t = (532.0 - w[k - 1]) / (w[k] - w[k - 1])
    at = {key: (1 - t) * np.asarray(r[key])[k - 1] + t * np.asarray(r[key])[k]
          for key in ("dni", "dhi", "dni_extra")}
    direct = np.ravel(at["dni"] / at["dni_extra"])
    diffuse = np.ravel(at["dhi"] / at["dni_extra"])
    for i in range(zen.size):
        s = _sky(90.0 - zen[i], aerosol_optical_depth=aod[i], aerosol_ssa=0.945,
                 refraction=False)
        mu = math.cos(math.radians(zen[i]))
        assert s.direct[0] / mu == pytest.approx(direct[i], rel=0.01)
        assert s.diffuse[0] == pytest.approx(diffuse[i], rel=0.2)


def test_twilight_illuminance_ratio_published():
    """The AMS Glossary of Meteorology ("civil twilight", 2024): on a clear evening the
    horizontal illuminance falls from ~585-410 lux at 0 deg to ~3.5-2 lux at -6 deg, a ratio
    of 0.0034-0.0085. Ours at 532 nm (global irradiance, sea level, AOD 0.05) must fall inside
    that range widened by 1.5x each way: illuminance is weighted by the eye over 450-650 nm,
    where ozone's Chappuis band (peak 600 nm) darkens the twilight more than at 532 nm."""
    s = _sky([0.0, -6.0])
    ratio = s.global_irradiance[1] / s.global_irradiance[0]
    assert 0.0034 / 1.5 < ratio < 0.0085 * 1.5, ratio


def test_high_surface_sees_the_sun_longer():
    """With the sea-level horizon, a point 2 km up sees the sun 1.44 deg (the dip,
    sqrt(2 z / R)) plus refraction below its horizontal; one at sea level only refraction's
    0.48 deg."""
    col = sky.Column.build(z_m=0.0, tau_rayleigh=TAU_R, aerosol_optical_depth=0.05,
                           aerosol_scale_height_m=2000.0, aerosol_ssa=0.95,
                           ozone_optical_depth=0.02)

    def sun(z, elev, refraction=True):
        return float(col.sun_transmittance(z, elev, horizon_height_m=0.0,
                                           refraction=refraction)[0])
    assert sun(2000.0, -1.3, refraction=False) > 0.0 and sun(2000.0, -1.5, refraction=False) == 0.0
    assert sun(2000.0, -1.5) > 0.0
    assert sun(2000.0, -2.2) == 0.0
    assert sun(0.0, -0.3) > 0.0 and sun(0.0, -0.3, refraction=False) == 0.0
    assert sun(0.0, -0.6) == 0.0


def test_table_of_renders_against_closed_form():
    """Mitsuba's multiple-scattering renders (spherical shells, straight rays; the table's
    own standard errors from 8 seeds) against the closed form in the same conditions: within
    3 standard errors plus 10 % from -4 to +30 deg (the isotropic estimate of orders >= 2)
    over snow and bright ground, 20 % over dark ground (albedo 0: the path radiance alone, 18 %
    high in hazy air at a high sun, where the isotropic estimate sends the aerosol's forward
    peak upward); below -4 deg the closed form is corrected by the renders themselves
    (test_twilight_correction_from_the_renders)."""
    from lidar_mitsuba.studies import sky_table
    doc = sky_table.load()
    e = np.asarray(doc["elevations_deg"])
    keep = e >= -4.0
    for i, aod in enumerate(doc["aerosol_optical_depths"]):
        for j, alb in enumerate(doc["albedos"]):
            cf = sky_table.closed_form(aerosol_optical_depth=aod, albedo=alb,
                                       elevations_deg=e[keep])
            ren = doc["radiance_per_sr"][i, j][keep]
            se = doc["standard_error_per_sr"][i, j][keep]
            tol = 0.10 if alb > 0 else 0.20
            assert np.all(np.abs(cf - ren) < 3 * se + tol * ren), (aod, alb, cf / ren)


def test_rendered_diffuse_irradiance_against_closed_form():
    """The diffuse irradiance at the surface, rendered (an irradiancemeter at the surface
    point; albedo 0 and 0.9) against the closed form: within 3 standard errors plus 20 % from
    -4 to +30 deg (found: 0.83-1.17; the isotropic higher orders too strong over snow in hazy
    air at a high sun, +17 %, as SPECTRL2 also finds +9-12 %; the twilight's onset, -4 to
    -3 deg, 10-17 % low). The nadir radiance ATLAS sees is held to 10 % (the test above)."""
    from lidar_mitsuba.studies import sky_table
    doc = sky_table.load()
    e = np.asarray(doc["elevations_deg"])
    keep = e >= -4.0
    for i, aod in enumerate(doc["aerosol_optical_depths"]):
        for j, alb in enumerate(doc["irradiance_albedos"]):
            cf = sky.sky(solar_elevation_deg=e[keep], z_m=0.0, albedo=alb,
                         tau_rayleigh=doc["tau_rayleigh"], aerosol_optical_depth=aod,
                         refraction=False).diffuse
            ren = doc["diffuse_irradiance"][i, j][keep]
            se = doc["diffuse_irradiance_standard_error"][i, j][keep]
            assert np.all(np.abs(cf - ren) < 3 * se + 0.20 * ren), (aod, alb, cf / ren)


def test_grid_interpolation_matches_direct_evaluation():
    """``nadir_radiance`` interpolates on a 0.25 deg x 250 m grid: within 1 % of a direct
    evaluation (with the renders' correction below -4 deg) at off-node points from twilight
    to day."""
    elev = np.array([-5.13, -2.61, -1.37, 0.11, 3.93, 12.2])
    z = np.array([130.0, 1880.0, 420.0, 2210.0, 70.0, 990.0])
    tau = lambda zz: radiometry.rayleigh_optical_depth(532.0, radiometry.isa_pressure_hpa(zz))  # noqa
    got = sky.nadir_radiance(solar_elevation_deg=elev, z_m=z, albedo=0.9, tau_rayleigh_of=tau,
                             aerosol_optical_depth=0.05)
    for k in range(elev.size):
        want = sky.sky(solar_elevation_deg=[elev[k]], z_m=z[k], albedo=0.9,
                       tau_rayleigh=float(tau(z[k])), aerosol_optical_depth=0.05).toa_radiance
        want = want * sky.twilight_correction(elev[k], 0.05)
        assert got[k] == pytest.approx(float(want[0]), rel=0.01), k


def test_twilight_correction_from_the_renders():
    """Below -4 deg the plane-parallel diffuse transport misses the sunward sky lit lower
    down: the renders are brighter (1.3-2x at -6 deg, more at -8 in hazy air; their standard
    errors 5-25 %). The correction is 1 from -4 deg up, continuous, and larger deeper."""
    c = sky.twilight_correction(np.array([-9.0, -8.0, -7.0, -6.0, -5.0, -4.0, -3.9, 10.0]),
                                0.05)
    assert np.all(c[-3:] == 1.0)
    assert 1.2 < c[3] < 2.5 and c[1] >= c[3] and np.all(np.diff(c[1:6]) <= 0)
    assert c[0] == pytest.approx(c[1])


def test_atlas_background_continuous_through_sunset():
    """ATLAS's solar background has no step at 0 deg (refraction, the sunlit air above the
    shadow), falls smoothly through twilight and is zero at night (-20 deg)."""
    inst = Instrument.atlas("strong")
    elev = np.array([-20.0, -8.0, -4.0, -1.0, -0.25, 0.25, 1.0, 4.0])
    n = elev.size
    rad = radiometry.shot_radiometry(inst, delta_time_s=np.zeros(n), z_m=np.zeros(n),
                                     albedo=0.9, solar_elevation_deg=elev,
                                     solar_azimuth_deg=np.zeros(n))
    solar = rad.solar_mhz
    assert solar[0] == 0.0
    assert np.all(np.diff(solar[1:]) > 0)
    assert solar[5] / solar[4] < 1.5
    assert 0.02 < solar[3] / solar[7] < 0.2          # twilight at -1 deg: a few % of +4 deg
