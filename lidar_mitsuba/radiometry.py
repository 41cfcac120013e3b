"""Radiometry from first principles: how many laser photons come back, and how much sunlight and
laser light scattered by the air reaches the detector with them. Pure numpy, and the NREL
Solar Position Algorithm (Reda & Andreas 2004, as implemented by pvlib) for the sun.

Signal: the lidar equation for the reference plate that defines
``Instrument.signal_photons`` (flat, horizontal, Lambertian, albedo 0.9, at nadir; any other
surface scales it by its traced return weight)::

    N_signal = (E_pulse / h nu) * T^2 * (0.9 / pi) * (A_tel / R^2) * eta_rx

with ``E_pulse`` the beam's transmitted pulse energy, ``h nu = h c / lambda``, ``T`` the
one-way clear-sky transmission between the surface and space, ``A_tel`` the telescope's
collecting area, ``R`` the range and ``eta_rx`` the receiver's optical transmission (telescope,
filter, fibres, aft optics) up to the detector. The detector's own efficiency (the PDE) and
its fill factor apply later, per photon (:mod:`lidar_mitsuba.detector.pmt`), to signal and background
alike.

Atmosphere (clear sky, :class:`Atmosphere`): Rayleigh optical depth at sea level from
Bodhaine et al. (1999), eq. 30, scaled by the surface pressure of the ISA troposphere; aerosol
optical depth at sea level, decaying with an aerosol scale height. ``T = exp(-tau(z) / mu)``.

Solar background reaching the detector [photons/s]::

    rate = E0 L * d_lambda * Omega_fov * A_tel * eta_rx / (h nu)

``E0`` the top-of-atmosphere solar spectral irradiance at the laser wavelength (scaled by the
Earth-Sun distance), ``L`` the radiance per unit ``E0`` that a nadir-looking receiver sees of
the sunlit surface (Lambertian albedo ``rho_bg``) and air, from :mod:`lidar_mitsuba.sky`: the
direct sun (curved-Earth air mass, refraction, the surface's height), the diffuse sky
attenuated on its way down, multiple scattering and the surface's light scattered back, and
the twilight sky of the sunlit air above the Earth's shadow, to about -10 deg
(``docs/physics/sky.md``); ``d_lambda`` the filter's equivalent width and ``Omega_fov`` the
field of view's solid angle. Moon and airglow are not modelled (a full moon adds ~4-13 Hz a
beam over snow, airglow under 1 Hz: ``docs/physics/night-floor.md``);
``Atmosphere.aerosol_forward_fraction`` is no longer used by
the sun's part (the sky model's aerosol phase function is a Henyey-Greenstein one).

Laser light scattered back by the air just above the surface is a background of its own, inside
the range gate: ``(E_pulse / h nu) T^2 beta_pi(z) (c / 2) (A_tel / R^2) eta_rx`` photons per
second of round-trip time, ``beta_pi`` the Rayleigh backscatter coefficient (``3 / 8 pi`` of
the scattering coefficient). Dark counts are the detector's, per channel.

Every constant carries its source; those estimated are marked ESTIMATE.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import os
import sys
from dataclasses import dataclass

import numpy as np

from .constants import C_M_PER_NS, REFERENCE_ALBEDO, check

H_PLANCK_J_S = 6.62607015e-34
"""Planck's constant [J s] (SI, exact)."""
C_M_PER_S = C_M_PER_NS * 1e9
SOLAR_IRRADIANCE_532_W_M2_NM = 1.892
"""Top-of-atmosphere solar spectral irradiance near 532 nm at 1 au [W m^-2 nm^-1]: the
ASTM G173-03 extraterrestrial spectrum (SMARTS 2.9.2; Gueymard 2004's composite) averaged
over 530-534 nm (1.958 at 532 nm on its 1 nm grid). For a 30 pm filter, checked against the
SAO2010 spectrum (Chance & Kurucz 2010, 0.04 nm resolution; its 530-534 nm mean 1.912): a
30 pm band anywhere in 532.0-532.4 nm (the laser's 532.27 nm in air or in vacuum) holds
0.94-1.06 of that mean (``tests/test_radiometry.py``): the solar lines there move it by a few
per cent. ESTIMATE to that extent (the flown filter's shape is not published)."""
P0_HPA = 1013.25
"""Sea-level pressure of the standard atmosphere [hPa]."""
DEFAULT_ALBEDO = 0.9
"""Albedo for sunlight where a scene's own cannot be found (an XML scene's snow medium): snow."""
SDP_EPOCH_UNIX_S = 1514764800.0
"""Unix time of the ATLAS SDP epoch, 2018-01-01T00:00:00Z."""
RAYLEIGH_SCALE_HEIGHT_M = 8000.0
"""Scale height of the air's number density for the Rayleigh backscatter coefficient [m]."""


def photon_energy_j(wavelength_nm: float) -> float:
    """``h c / lambda`` [J]."""
    return H_PLANCK_J_S * C_M_PER_S / (wavelength_nm * 1e-9)


def rayleigh_optical_depth(wavelength_nm: float, pressure_hpa=P0_HPA):
    """Rayleigh optical depth of the whole atmosphere above a surface at ``pressure_hpa``
    (Bodhaine et al. 1999, J. Atmos. Ocean. Tech. 16, 1854, eq. 30: sea level, 1013.25 hPa,
    45 deg latitude; 0.1112 at 532 nm), scaled by the pressure."""
    lam2 = (wavelength_nm * 1e-3) ** 2
    tau0 = (0.0021520 * (1.0455996 - 341.29061 / lam2 - 0.90230850 * lam2)
            / (1.0 + 0.0027059889 / lam2 - 85.968563 * lam2))
    return tau0 * np.asarray(pressure_hpa, np.float64) / P0_HPA


def isa_pressure_hpa(z_m):
    """Pressure [hPa] at height ``z_m`` [m] above sea level in the ISA troposphere (15 C and
    6.5 K/km at sea level): ``1013.25 (1 - 2.25577e-5 z)^5.25588``."""
    z = np.clip(np.asarray(z_m, np.float64), -500.0, 11000.0)
    return P0_HPA * (1.0 - 2.25577e-5 * z) ** 5.25588


@dataclass(frozen=True)
class Atmosphere:
    """A clear-sky atmosphere at the laser wavelength.

    Attributes:
        aerosol_optical_depth: aerosol optical depth at sea level at 532 nm (ESTIMATE
            default 0.05: clean polar air, Tomasi et al. 2007; 0.02-0.03 over the Antarctic
            plateau, 0.05-0.1 in the Arctic, more in spring haze).
        aerosol_scale_height_m: height over which aerosol decays by 1/e [m] (ESTIMATE 2000).
        aerosol_single_scattering_albedo: fraction of aerosol extinction that scatters
            (ESTIMATE 0.95).
        aerosol_forward_fraction: fraction of aerosol-scattered sunlight going down (ESTIMATE
            0.8).
    """
    aerosol_optical_depth: float = 0.05
    aerosol_scale_height_m: float = 2000.0
    aerosol_single_scattering_albedo: float = 0.95
    aerosol_forward_fraction: float = 0.8

    def __post_init__(self):
        f = math.isfinite
        check("aerosol_optical_depth", self.aerosol_optical_depth,
              f(self.aerosol_optical_depth) and 0 <= self.aerosol_optical_depth <= 5,
              "must be in [0, 5]")
        check("aerosol_scale_height_m", self.aerosol_scale_height_m,
              f(self.aerosol_scale_height_m) and self.aerosol_scale_height_m > 0, "must be > 0")
        for name in ("aerosol_single_scattering_albedo", "aerosol_forward_fraction"):
            v = getattr(self, name)
            check(name, v, f(v) and 0 <= v <= 1, "must be in [0, 1]")

    def optical_depths(self, z_m, wavelength_nm: float = 532.0):
        """``(tau_rayleigh, tau_aerosol)`` of the air above height(s) ``z_m`` [m]."""
        z = np.asarray(z_m, np.float64)
        tau_r = rayleigh_optical_depth(wavelength_nm, isa_pressure_hpa(z))
        tau_a = self.aerosol_optical_depth * np.exp(-np.maximum(z, 0.0)
                                                    / self.aerosol_scale_height_m)
        return tau_r, tau_a

    def transmission(self, z_m, *, mu: float = 1.0, wavelength_nm: float = 532.0):
        """One-way transmission between height(s) ``z_m`` [m] and space along a path of
        zenith-angle cosine ``mu``."""
        tau_r, tau_a = self.optical_depths(z_m, wavelength_nm)
        return np.exp(-(tau_r + tau_a) / mu)


# ------------------------------------------------------------------------------ the sun
def solar_angles(lat_deg, lon_deg, delta_time_s, *, every: int = 100):
    """Solar elevation and azimuth [deg] at each shot: ``(elevation, azimuth)``, each the shape
    of the inputs (``lat_deg``, ``lon_deg`` [deg], ``delta_time_s`` [s since 2018-01-01
    UTC, the ATLAS SDP epoch; no leap second since]).

    The NREL Solar Position Algorithm (Reda & Andreas 2004, Solar Energy 76, 577; +-0.0003 deg)
    through pvlib (``pvlib.spa.solar_position_numpy``), geometric elevation (no refraction),
    azimuth clockwise from north. It costs ~3 us a point, so it runs on every ``every``-th
    shot, on both sides of any jump in time (> 1 s) or position (> 1 km), and on the last,
    and is interpolated linearly in between (the sun moves 0.0004 deg in 10 ms).
    """
    spa = _spa()
    lat = np.atleast_1d(np.asarray(lat_deg, np.float64))
    lon = np.atleast_1d(np.asarray(lon_deg, np.float64))
    t = np.atleast_1d(np.asarray(delta_time_s, np.float64))
    n = t.size
    if n == 0:
        return np.zeros(0), np.zeros(0)
    jump = np.flatnonzero((np.abs(np.diff(t)) > 1.0) | (np.abs(np.diff(lat)) > 0.01)
                          | (np.abs(np.diff(lon)) * np.cos(np.deg2rad(lat[:-1])) > 0.01))
    keys = np.unique(np.concatenate([np.arange(0, n, max(int(every), 1)), jump, jump + 1,
                                     [n - 1]]))
    unix = t[keys] + SDP_EPOCH_UNIX_S
    year = 2018 + (t[keys] / (365.25 * 86400.0))
    delta_t = spa.calculate_deltat(year, np.ones_like(year))
    _, _, _, elev, azim, _ = spa.solar_position_numpy(
        unix, lat[keys], lon[keys], 0.0, P0_HPA, 0.0, delta_t, 0.5667, numthreads=1)
    i = np.arange(n, dtype=np.float64)
    elevation = np.interp(i, keys, elev)
    rad = np.deg2rad(azim)                       # azimuth wraps at 360: interpolate its vector
    azimuth = np.mod(np.rad2deg(np.arctan2(np.interp(i, keys, np.sin(rad)),
                                           np.interp(i, keys, np.cos(rad)))), 360.0)
    shape = np.shape(delta_time_s)
    return elevation.reshape(shape), azimuth.reshape(shape)


@functools.cache
def _spa():
    """pvlib's ``spa`` module. Importing it as ``pvlib.spa`` runs pvlib's package import, which
    brings pandas and scipy.integrate (about 0.7 s of a granule's start-up); ``spa.py`` itself
    needs only numpy, so it is loaded from pvlib's folder on its own (the same code: the same
    numbers), unless pvlib is imported already."""
    if "pvlib.spa" in sys.modules:
        return sys.modules["pvlib.spa"]
    import importlib.util
    folder = importlib.util.find_spec("pvlib").submodule_search_locations[0]
    spec = importlib.util.spec_from_file_location("_lidar_mitsuba_pvlib_spa",
                                                  os.path.join(folder, "spa.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def earth_sun_distance_au(delta_time_s):
    """Earth-Sun distance [au] at ``delta_time_s`` [s since 2018-01-01 UTC] (Spencer 1971's
    Fourier series, as in Iqbal 1983: the 1/r^2 factor to +-0.01 %)."""
    day = np.asarray(delta_time_s, np.float64) / 86400.0
    g = 2.0 * np.pi * np.mod(day, 365.25) / 365.25            # day angle, 0 on 1 January
    inv_r2 = (1.000110 + 0.034221 * np.cos(g) + 0.001280 * np.sin(g)
              + 0.000719 * np.cos(2 * g) + 0.000077 * np.sin(2 * g))
    return 1.0 / np.sqrt(inv_r2)


# ------------------------------------------------------------------------------ the lidar
@dataclass(frozen=True)
class LinkBudget:
    """What turns a pulse into photons at the detector: the transmitter's energy, the
    receiver's optics and the clear sky between them (see the module docstring for the
    equations). An :class:`~lidar_mitsuba.instrument.Instrument` with a link budget derives its
    ``signal_photons`` from it and gets its background per shot from the sun and the air.

    Attributes:
        pulse_energy_uj: transmitted energy of one pulse of this beam [uJ].
        telescope_diameter_m: receiver telescope aperture [m] (ATLAS: 0.8, the "2.6 feet"
            beryllium telescope; central obscuration not modelled).
        receiver_transmission: fraction of the light entering the telescope that reaches the
            detector: mirrors, fibres, aft optics and the filter's peak (ESTIMATE 0.5 for
            ATLAS: no published value found).
        filter_bandwidth_pm: equivalent width of the receiver's optical filter [pm] (ATLAS:
            30; it sets the solar background only).
        atmosphere: the clear sky (:class:`Atmosphere`).
        solar_background: add sunlight reflected by the surface and scattered by the air.
        laser_backscatter: add the laser light the air just above the surface scatters back
            into the range gate.
    """
    pulse_energy_uj: float
    telescope_diameter_m: float = 0.8
    receiver_transmission: float = 0.5
    filter_bandwidth_pm: float = 30.0
    atmosphere: Atmosphere = Atmosphere()
    solar_background: bool = True
    laser_backscatter: bool = True

    def __post_init__(self):
        if isinstance(self.atmosphere, dict):          # from a run's config (JSON)
            object.__setattr__(self, "atmosphere", Atmosphere(**self.atmosphere))
        f = math.isfinite
        check("pulse_energy_uj", self.pulse_energy_uj,
              f(self.pulse_energy_uj) and 0 < self.pulse_energy_uj <= 1e6, "must be in (0, 1e6]")
        check("telescope_diameter_m", self.telescope_diameter_m,
              f(self.telescope_diameter_m) and 0 < self.telescope_diameter_m <= 100,
              "must be in (0, 100]")
        check("receiver_transmission", self.receiver_transmission,
              f(self.receiver_transmission) and 0 < self.receiver_transmission <= 1,
              "must be in (0, 1]")
        check("filter_bandwidth_pm", self.filter_bandwidth_pm,
              f(self.filter_bandwidth_pm) and 0 < self.filter_bandwidth_pm <= 1e5,
              "must be in (0, 1e5]")

    @property
    def telescope_area_m2(self) -> float:
        return math.pi * self.telescope_diameter_m ** 2 / 4.0

    def photons_per_pulse(self, wavelength_nm: float) -> float:
        """Photons in one transmitted pulse: ``E / (h c / lambda)``."""
        return self.pulse_energy_uj * 1e-6 / photon_energy_j(wavelength_nm)

    def signal_photons(self, *, wavelength_nm: float, range_m, z_m=0.0):
        """Mean photons per shot reaching the detector from the reference plate (flat,
        horizontal, Lambertian, albedo 0.9) at nadir, at range(s) ``range_m`` [m] and height(s)
        ``z_m`` [m] above sea level: the lidar equation (module docstring)."""
        two_way = self.atmosphere.transmission(z_m, wavelength_nm=wavelength_nm) ** 2
        return (self.photons_per_pulse(wavelength_nm) * two_way * REFERENCE_ALBEDO / math.pi
                * self.telescope_area_m2 / np.asarray(range_m, np.float64) ** 2
                * self.receiver_transmission)

    def _etendue_sr_m2(self, fov_diameter_m: float, range_m):
        """Field-of-view solid angle times collecting area [sr m^2]."""
        omega = math.pi * (fov_diameter_m / 2.0) ** 2 / np.asarray(range_m, np.float64) ** 2
        return omega * self.telescope_area_m2

    def solar_background_hz(self, *, wavelength_nm: float, fov_diameter_m: float, range_m,
                            z_m, solar_elevation_deg, albedo, earth_sun_au=1.0,
                            horizon_height_m: float = 0.0):
        """Sunlight reaching the detector [photons/s] (before its PDE), clear sky: the radiance
        a nadir-looking receiver sees of the sunlit surface and air, from the sun at any
        elevation down to the twilight's end (:mod:`lidar_mitsuba.sky`: curved-Earth air
        mass and refraction, diffuse light attenuated on its way down, multiple scattering,
        the sunlit air above the Earth's shadow; ``docs/physics/sky.md``). Arrays broadcast;
        ``solar_elevation_deg`` geometric [deg], ``z_m`` the surface's height [m],
        ``albedo`` its Lambertian albedo for sunlight, ``horizon_height_m`` the height [m]
        of the sphere that casts the Earth's shadow."""
        from . import sky
        atm = self.atmosphere
        shape = np.broadcast_shapes(np.shape(range_m), np.shape(z_m),
                                    np.shape(solar_elevation_deg), np.shape(albedo),
                                    np.shape(earth_sun_au))
        e0 = SOLAR_IRRADIANCE_532_W_M2_NM / np.asarray(earth_sun_au, np.float64) ** 2
        radiance = e0 * sky.nadir_radiance(
            solar_elevation_deg=solar_elevation_deg, z_m=z_m, albedo=albedo,
            tau_rayleigh_of=lambda z: rayleigh_optical_depth(wavelength_nm, isa_pressure_hpa(z)),
            aerosol_optical_depth=atm.aerosol_optical_depth,
            aerosol_scale_height_m=atm.aerosol_scale_height_m,
            aerosol_ssa=atm.aerosol_single_scattering_albedo,
            horizon_height_m=horizon_height_m)
        watts = (radiance * self.filter_bandwidth_pm * 1e-3
                 * self._etendue_sr_m2(fov_diameter_m, range_m) * self.receiver_transmission)
        return np.broadcast_to(watts / photon_energy_j(wavelength_nm), shape)

    def laser_backscatter_hz(self, *, wavelength_nm: float, range_m, z_m):
        """The laser's own light scattered back by the air just above height(s) ``z_m`` [m]
        into the range gate, as a rate [photons per second of round-trip time] at the
        detector (before its PDE): ``N (T^2) beta_pi (c / 2) (A / R^2) eta``, with the Rayleigh
        backscatter coefficient ``beta_pi = (3 / 8 pi) tau_R(z) / H`` (number density scale
        height ``H``; aerosol backscatter left out)."""
        tau_r, _ = self.atmosphere.optical_depths(z_m, wavelength_nm)
        beta_pi = 3.0 / (8.0 * math.pi) * tau_r / RAYLEIGH_SCALE_HEIGHT_M
        two_way = self.atmosphere.transmission(z_m, wavelength_nm=wavelength_nm) ** 2
        return (self.photons_per_pulse(wavelength_nm) * two_way * beta_pi * C_M_PER_S / 2.0
                * self.telescope_area_m2 / np.asarray(range_m, np.float64) ** 2
                * self.receiver_transmission)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


# ------------------------------------------------------------------------------ per shot
@dataclass
class ShotRadiometry:
    """A run's link budget shot by shot. Every array has shape (n_shots,).

    Attributes:
        signal_scale: each shot's signal relative to ``Instrument.signal_photons`` (its range
            and the air above its surface against nadir at sea level from ``altitude_m``).
        background_mhz: photons per second reaching the detector inside the gate [MHz]
            (before its PDE): ``solar_mhz + backscatter_mhz`` plus the instrument's own
            ``background_mhz``.
        solar_mhz: the sun's part (surface and air); backscatter_mhz: the laser light the air
            scatters back.
        solar_elevation_deg, solar_azimuth_deg: the sun at the footprint [deg] (azimuth
            clockwise from north).
        albedo: the surface's Lambertian albedo for sunlight used.
    """
    signal_scale: np.ndarray
    background_mhz: np.ndarray
    solar_mhz: np.ndarray
    backscatter_mhz: np.ndarray
    solar_elevation_deg: np.ndarray
    solar_azimuth_deg: np.ndarray
    albedo: float

    def detector_inputs(self, a: int, b: int) -> dict:
        """``pmt.detect``'s per-shot keywords for shots ``a`` .. ``b - 1``."""
        return {"signal_scale": self.signal_scale[a:b],
                "background_mhz": self.background_mhz[a:b]}

    def summary(self) -> dict:
        """Medians and ranges, JSON-able (a run's ``config["radiometry"]``)."""
        def stats(a):
            a = np.asarray(a, np.float64)
            return {"median": float(np.median(a)), "min": float(a.min()), "max": float(a.max())}
        return {"signal_scale": stats(self.signal_scale),
                "background_mhz": stats(self.background_mhz),
                "solar_mhz": stats(self.solar_mhz), "backscatter_mhz": stats(self.backscatter_mhz),
                "solar_elevation_deg": stats(self.solar_elevation_deg), "albedo": self.albedo}


def shot_radiometry(instrument, *, delta_time_s, z_m, albedo: float, solar_elevation_deg,
                    solar_azimuth_deg) -> ShotRadiometry:
    """Each shot's signal scale and background from ``instrument.link_budget``.

    Args:
        instrument: an :class:`~lidar_mitsuba.instrument.Instrument` with a link budget.
        delta_time_s: (n_shots,) when [s since 2018-01-01] (the Earth-Sun distance).
        z_m: (n_shots,) the surface's height above sea level [m] under each shot (the range
            is ``instrument.altitude_m - z_m``; the air above it attenuates and scatters).
        albedo: the surface's Lambertian albedo for sunlight.
        solar_elevation_deg, solar_azimuth_deg: (n_shots,) the sun (:func:`solar_angles`).
    """
    link = instrument.link_budget
    lam = instrument.wavelength_nm
    z = np.asarray(z_m, np.float64)
    rng_m = instrument.altitude_m - z
    elev = np.asarray(solar_elevation_deg, np.float64)
    azim = np.asarray(solar_azimuth_deg, np.float64)
    scale = (link.signal_photons(wavelength_nm=lam, range_m=rng_m, z_m=z)
             / link.signal_photons(wavelength_nm=lam, range_m=instrument.altitude_m))
    zero = np.zeros(z.shape)
    solar = (link.solar_background_hz(
        wavelength_nm=lam, fov_diameter_m=instrument.fov_diameter_m, range_m=rng_m, z_m=z,
        solar_elevation_deg=elev, albedo=albedo,
        earth_sun_au=earth_sun_distance_au(delta_time_s)) * 1e-6
        if link.solar_background else zero)
    back = (link.laser_backscatter_hz(wavelength_nm=lam, range_m=rng_m, z_m=z) * 1e-6
            if link.laser_backscatter else zero)
    return ShotRadiometry(signal_scale=np.asarray(scale, np.float64),
                          background_mhz=solar + back + instrument.background_mhz,
                          solar_mhz=solar, backscatter_mhz=back, solar_elevation_deg=elev,
                          solar_azimuth_deg=azim, albedo=float(albedo))


def run_radiometry(instrument, geoloc, z_m: np.ndarray, *, scene,
                     x_m, y_m, snow, albedo: float | None = None) -> ShotRadiometry:
    """Each shot's signal scale and background (:func:`shot_radiometry`) for a run of
    ``instrument`` (an :class:`~lidar_mitsuba.instrument.Instrument`) at ``geoloc`` (a
    :class:`~lidar_mitsuba.geotrack.Geolocation`): the sun where and when the shot is, the surface's albedo for sunlight from its own BSDF (a snow
    volume: diffusion theory's albedo; ``albedo``: the surface's own, where it gives one,
    e.g. a forest over snow), the air above the surface height ``z_m``."""
    if geoloc.solar_elevation_deg is not None:            # a real granule's own
        elev, azim = geoloc.solar_elevation_deg, geoloc.solar_azimuth_deg
    else:
        elev, azim = solar_angles(geoloc.lat_deg, geoloc.lon_deg, geoloc.delta_time_s)
    if albedo is not None:
        albedo = float(albedo)
    elif snow is not None:
        albedo = float(snow.diffusion().total_reflectance())
    else:
        from .trace import scene as scn
        from .track import spread_shots
        pick = spread_shots(np.size(x_m), 5)
        albedo = scn.sunlit_albedo(scene, np.asarray(x_m)[pick], np.asarray(y_m)[pick],
                                   solar_elevation_deg=float(np.median(elev)),
                                   solar_azimuth_deg=float(np.median(azim)))
        if not np.isfinite(albedo):       # an XML scene's medium, or no surface in reach
            albedo = DEFAULT_ALBEDO
    return shot_radiometry(instrument, delta_time_s=geoloc.delta_time_s, z_m=z_m,
                           albedo=albedo, solar_elevation_deg=elev, solar_azimuth_deg=azim)
