"""The sun and the clear sky at every solar elevation, -10 to +90 deg: what a nadir-looking
receiver above the atmosphere sees of the sunlit surface and air, and the irradiance at the
surface. Pure numpy (and ``scipy.special``); one evaluation costs a few milliseconds.
The equations and their sources are on ``docs/physics/sky.md``.

The atmosphere is a stack of horizontal layers above the surface (plane-parallel for the
diffuse light), lit by a sun whose rays cross a **spherical** Earth (the pseudo-spherical
approximation, Dahlback & Stamnes 1991, Planet. Space Sci. 39, 671):

* **The sun at a point** at height ``z`` [m]: its rays, refracted (Saemundsson 1986 above the
  local horizontal; a grazing ray's bending scaled with the air's density at its tangent
  point below it), cross exponential Rayleigh (scale height 8 km) and aerosol columns (the
  Chapman grazing-incidence function, asymptotic form, Chapman 1931 / Rees 1989 sec. 2.2) and
  a spherical ozone shell (15-30 km); a ray whose tangent point lies below the horizon sphere
  (``horizon_height_m`` above sea level) is in the Earth's shadow. At the surface the direct
  beam's Rayleigh air mass is Kasten & Young's (1989, Appl. Opt. 28, 4735).
* **First-order scattering** of that sunlight by each layer (Rayleigh and Henyey-Greenstein
  aerosol phase functions), attenuated on its way down to the surface (the diffuse
  transmittance: exponential integrals ``E2``, ``E4`` of the vertical optical depth between
  the layer and the surface, not the plane-parallel ``1 - exp(-tau / mu_s)`` that lets light
  scattered out of a slant beam reach the ground unattenuated) and on its way up to the
  receiver (``exp(-tau)``).
* **Higher orders** (ESTIMATE: isotropic): the layers' diffuse light scatters again, and the
  Lambertian surface reflects it back up; the mean intensity of every order >= 2 solves the
  plane-parallel Schwarzschild-Milne equation with an isotropic source (the layer-averaged
  ``E1``/``E2``/``E3`` kernels, Chandrasekhar 1960 ch. I), with the exact first order in it.
  Its error is charted against Mitsuba's multiple-scattering renders
  (:mod:`lidar_mitsuba.studies.sky_table`): a few per cent from -4 to +30 deg.
* **Deep twilight** (below -4 deg): the plane-parallel diffuse transport misses the sky toward
  the sun, lit lower down; :func:`nadir_radiance` multiplies the closed form by the renders'
  ratio to it there (:func:`twilight_correction`, from ``data/sky_table.json``).

Everything is per unit top-of-atmosphere solar irradiance (``E0 = 1`` on a surface normal to
the sun): multiply by ``E0`` [W m^-2 nm^-1] for W m^-2 nm^-1 (irradiance) and
W m^-2 nm^-1 sr^-1 (radiance).
"""
from __future__ import annotations

import functools
import json
import math
import pathlib
from dataclasses import dataclass

import numpy as np
from scipy.special import expn

EARTH_RADIUS_M = 6371000.0
"""Mean radius of the Earth [m] (IUGG, Moritz 2000)."""
RAYLEIGH_SCALE_HEIGHT_M = 8000.0
"""Scale height of the air's density [m] for the Rayleigh extinction profile and the
refraction (US Standard Atmosphere 1976: 8.4 km at the surface, 6.3 km at the tropopause;
8 km as in ``radiometry.RAYLEIGH_SCALE_HEIGHT_M``)."""
TOP_M = 100000.0
"""Top of the model atmosphere [m]: the Rayleigh optical depth above it is 4e-7."""
OZONE_BOTTOM_M, OZONE_TOP_M = 15000.0, 30000.0
"""Ozone layer [m] (ESTIMATE: the bulk of the stratospheric ozone lies between 15 and 30 km,
peak near 22 km, the height SPECTRL2 uses, Bird & Riordan 1986)."""
OZONE_COLUMN_ATM_CM = 0.30
"""Ozone column [atm cm] (ESTIMATE: 300 Dobson units, the global mean; polar columns run
from 0.15 in the Antarctic spring's hole to 0.45 in the Arctic spring)."""
OZONE_ABSORPTION_PER_ATM_CM = 0.0654
"""Ozone's Chappuis-band absorption coefficient at 532 nm [(atm cm)^-1]: SPECTRL2's table
(Bird & Riordan 1986, after Leckner 1978; pvlib's ``spectrl2`` holds it), 0.063 at 530 nm and
0.075 at 540 nm, interpolated (2.4e-21 cm^2 per molecule)."""
REFRACTION_HORIZON_DEG = 1.02 / math.tan(math.radians(10.3 / 5.11)) / 60.0
"""Refraction of a ray reaching sea level horizontally [deg]: Saemundsson's (1986) formula at
0 deg geometric elevation, 0.483 deg (10 C, 1010 hPa)."""
AEROSOL_ASYMMETRY = 0.7
"""Henyey-Greenstein asymmetry of the aerosol phase function at 532 nm (ESTIMATE: 0.6-0.75
for continental and Arctic haze aerosol, d'Almeida et al. 1991)."""
N_LAYERS = 48
_MU, _W_MU = np.polynomial.legendre.leggauss(12)
_MU, _W_MU = 0.5 * (_MU + 1.0), 0.5 * _W_MU          # Gauss nodes on (0, 1)
_PHI = (np.arange(24) + 0.5) * (2.0 * np.pi / 24)     # azimuths (midpoint rule, periodic)


@dataclass(frozen=True)
class Sky:
    """What one solar elevation gives, per unit top-of-atmosphere solar irradiance. Arrays of
    the elevations' shape.

    Attributes:
        direct: direct sun on the horizontal surface [1] (``E0 mu T``).
        diffuse: diffuse sky on the horizontal surface, all orders [1].
        diffuse_first: its first-order part [1].
        path_radiance: the air's radiance toward the nadir-looking receiver above the
            atmosphere [sr^-1].
        surface_radiance: the Lambertian surface's radiance reaching that receiver, after the
            air above it [sr^-1].
        toa_radiance: their sum: what the receiver sees [sr^-1].
    """
    direct: np.ndarray
    diffuse: np.ndarray
    diffuse_first: np.ndarray
    path_radiance: np.ndarray
    surface_radiance: np.ndarray

    @property
    def toa_radiance(self) -> np.ndarray:
        return self.path_radiance + self.surface_radiance

    @property
    def global_irradiance(self) -> np.ndarray:
        return self.direct + self.diffuse


def saemundsson_refraction_deg(elevation_deg):
    """Refraction [deg] of a ray from space to sea level arriving at geometric elevation
    ``elevation_deg`` [deg] (Saemundsson 1986, Sky & Telescope 72, 70: ``R = 1.02 /
    tan(h + 10.3 / (h + 5.11))`` arcmin; within 0.07 arcmin of Bennett's 1982 inverse; valid
    for h >= -1 deg, clipped there)."""
    h = np.maximum(np.asarray(elevation_deg, np.float64), -1.0)
    return 1.02 / np.tan(np.deg2rad(h + 10.3 / (h + 5.11))) / 60.0


def apparent_mu0(elevation_deg):
    """``mu0`` [1]: the cosine of the sun's apparent zenith angle at sea level, the sine of
    its apparent elevation (Saemundsson's refraction, :func:`saemundsson_refraction_deg`,
    added to the geometric ``elevation_deg`` [deg], array; capped at 90 deg), clipped to
    [1e-3, 1]: the collimated beam's ``mu0`` the cloud layers' Monte Carlo and table take
    (:mod:`lidar_mitsuba.atmosphere.cloud_shade`,
    :mod:`lidar_mitsuba.atmosphere.cloud_reflection`), which must be above 0."""
    h = np.asarray(elevation_deg, np.float64)
    h_app = h + saemundsson_refraction_deg(h)
    return np.clip(np.sin(np.deg2rad(np.minimum(h_app, 90.0))), 1e-3, 1.0)


def refraction_deg(elevation_deg, z_m, *, tangent_z_m=None):
    """Refraction [deg] of the sun's ray reaching height ``z_m`` [m] at geometric elevation
    ``elevation_deg`` [deg]: Saemundsson's formula scaled with the air density at ``z_m``
    (refraction is proportional to ``n - 1``, itself to density) when the ray comes down to
    it; a ray that rose from a tangent point at ``tangent_z_m`` below it bent by the
    horizontal refraction scaled with the density there, once on its way down to the tangent
    point and by the fraction ``1 - exp(-(z - z_t) / H)`` of that again on its way up (the
    share of the air above the tangent point it crossed): continuous at 0 deg. ESTIMATE for
    the grazing rays: temperature's effect (cold polar air refracts ~10 % more) is left out."""
    h = np.asarray(elevation_deg, np.float64)
    z = np.asarray(z_m, np.float64)
    down = saemundsson_refraction_deg(np.maximum(h, 0.0)) * np.exp(-z / RAYLEIGH_SCALE_HEIGHT_M)
    if tangent_z_m is None:
        return down
    zt = np.asarray(tangent_z_m, np.float64)
    up = (REFRACTION_HORIZON_DEG * np.exp(-zt / RAYLEIGH_SCALE_HEIGHT_M)
          * (2.0 - np.exp(-np.maximum(z - zt, 0.0) / RAYLEIGH_SCALE_HEIGHT_M)))
    return np.where(h >= 0.0, down, up)


def kasten_young_air_mass(elevation_deg):
    """Relative optical air mass [1] at apparent solar elevation ``elevation_deg`` [deg]
    (Kasten & Young 1989, Appl. Opt. 28, 4735: ``1 / (sin h + 0.50572 (h + 6.07995)^-1.6364)``,
    a refracting ISO standard atmosphere; 38.1 at 0 deg, 12.4 at 4 deg). Clipped at 0 deg."""
    h = np.maximum(np.asarray(elevation_deg, np.float64), 0.0)
    return 1.0 / (np.sin(np.deg2rad(h)) + 0.50572 * (h + 6.07995) ** -1.6364)


def chapman_column(tau_at_z, z_m, elevation_deg, scale_height_m):
    """Optical depth [1] along a straight ray from height ``z_m`` [m] toward a source at
    elevation ``elevation_deg`` [deg], through an exponential column of scale height
    ``scale_height_m`` whose vertical optical depth above ``z_m`` is ``tau_at_z``: the Chapman
    function in its asymptotic form ``sqrt(pi x / 2) erfcx(sqrt(x / 2) cos chi)`` (x = r / H,
    within 0.2 % for x > 300, Rees 1989 eq. 2.2.9) and, below the local horizontal,
    ``2 sqrt(pi x_t / 2) tau(z_t) - Ch(x, pi - chi) tau(z)`` through the tangent point
    ``z_t``."""
    from scipy.special import erfcx
    r = EARTH_RADIUS_M + np.asarray(z_m, np.float64)
    h = np.deg2rad(np.asarray(elevation_deg, np.float64))
    x = r / scale_height_m
    ch = np.sqrt(0.5 * np.pi * x) * erfcx(np.sqrt(0.5 * x) * np.abs(np.sin(h)))
    r_t = r * np.cos(h)
    tau_t = tau_at_z * np.exp(np.minimum((r - r_t) / scale_height_m, 700.0))
    grazing = 2.0 * np.sqrt(0.5 * np.pi * r_t / scale_height_m) * tau_t - ch * tau_at_z
    return np.where(h >= 0.0, ch * tau_at_z, grazing)


def shell_path_m(z_m, elevation_deg, bottom_m: float, top_m: float):
    """Length [m] of a straight ray from height ``z_m`` [m] toward elevation
    ``elevation_deg`` [deg] inside the spherical shell between heights ``bottom_m`` and
    ``top_m`` [m]."""
    r = EARTH_RADIUS_M + np.asarray(z_m, np.float64)
    h = np.deg2rad(np.asarray(elevation_deg, np.float64))
    p2 = (r * np.cos(h)) ** 2                         # impact parameter squared

    def inside(a):        # the ray's length inside the sphere of radius a
        half = np.sqrt(np.maximum(a * a - p2, 0.0))
        from_inside = half - r * np.sin(h)
        from_outside = np.where((h < 0.0) & (p2 < a * a), 2.0 * half, 0.0)
        return np.where(r < a, from_inside, from_outside)
    return (inside(EARTH_RADIUS_M + top_m) - inside(EARTH_RADIUS_M + bottom_m))


@dataclass(frozen=True)
class Column:
    """The layered atmosphere above one surface height: layer edges and optical depths.

    Attributes:
        edges_m: (N + 1,) heights above sea level of the layer boundaries [m], surface first.
        d_rayleigh, d_aerosol, d_ozone: (N,) each layer's optical depths [1].
        tau_rayleigh, tau_aerosol: vertical optical depths above the surface [1].
        aerosol_ssa: aerosol single-scattering albedo; aerosol_scale_height_m [m].
        ozone_optical_depth: the whole ozone column's absorption optical depth [1].
    """
    edges_m: np.ndarray
    d_rayleigh: np.ndarray
    d_aerosol: np.ndarray
    d_ozone: np.ndarray
    tau_rayleigh: float
    tau_aerosol: float
    aerosol_ssa: float
    aerosol_scale_height_m: float
    ozone_optical_depth: float

    @classmethod
    def build(cls, *, z_m: float, tau_rayleigh: float, aerosol_optical_depth: float,
              aerosol_scale_height_m: float, aerosol_ssa: float,
              ozone_optical_depth: float, n_layers: int = N_LAYERS) -> "Column":
        """Layers from the surface height ``z_m`` [m] to 100 km, thin near the ground;
        ``tau_rayleigh`` the Rayleigh optical depth above the surface, ``aerosol_optical_depth``
        the aerosol's at sea level (decaying with ``aerosol_scale_height_m``)."""
        u = np.linspace(0.0, 1.0, n_layers + 1)
        edges = z_m + (TOP_M - z_m) * np.expm1(3.5 * u) / np.expm1(3.5)
        above = edges - z_m
        t_r = tau_rayleigh * np.exp(-above / RAYLEIGH_SCALE_HEIGHT_M)
        t_a = aerosol_optical_depth * np.exp(-edges / aerosol_scale_height_m)
        o3 = np.clip(edges, OZONE_BOTTOM_M, OZONE_TOP_M)
        d_o = ozone_optical_depth * np.diff(o3) / (OZONE_TOP_M - OZONE_BOTTOM_M)
        return cls(edges_m=edges, d_rayleigh=-np.diff(t_r), d_aerosol=-np.diff(t_a),
                   d_ozone=d_o, tau_rayleigh=float(tau_rayleigh),
                   tau_aerosol=float(aerosol_optical_depth
                                     * math.exp(-z_m / aerosol_scale_height_m)),
                   aerosol_ssa=float(aerosol_ssa),
                   aerosol_scale_height_m=float(aerosol_scale_height_m),
                   ozone_optical_depth=float(ozone_optical_depth))

    @property
    def mid_m(self) -> np.ndarray:
        return 0.5 * (self.edges_m[1:] + self.edges_m[:-1])

    @property
    def d_ext(self) -> np.ndarray:
        return self.d_rayleigh + self.d_aerosol + self.d_ozone

    @property
    def d_sca(self) -> np.ndarray:
        return self.d_rayleigh + self.aerosol_ssa * self.d_aerosol

    def sun_transmittance(self, z_m, elevation_deg, *, horizon_height_m: float,
                          refraction: bool, aerosol_factor: float = 1.0):
        """Transmittance [1] of the sunlight reaching height(s) ``z_m`` [m] (above sea level)
        with the sun at geometric elevation ``elevation_deg`` [deg] there, and the sun's
        apparent elevation [deg]: ``(T, h_apparent)``. Zero in the Earth's shadow.
        ``aerosol_factor`` scales the aerosol's optical depth (delta scaling)."""
        z = np.asarray(z_m, np.float64)
        h0 = np.asarray(elevation_deg, np.float64)
        r = EARTH_RADIUS_M + z
        zt0 = np.maximum(r * np.cos(np.deg2rad(np.minimum(h0, 0.0))) - EARTH_RADIUS_M, 0.0)
        h = h0 + (refraction_deg(h0, z, tangent_z_m=zt0) if refraction else 0.0)
        r_t = np.where(h < 0.0, r * np.cos(np.deg2rad(h)), r)
        lit = (h >= 0.0) | (r_t > EARTH_RADIUS_M + horizon_height_m)
        z0 = self.edges_m[0]
        tau_r_z = self.tau_rayleigh * np.exp(-(z - z0) / RAYLEIGH_SCALE_HEIGHT_M)
        tau_a_z = self.tau_aerosol * np.exp(-(z - z0) / self.aerosol_scale_height_m)
        tau = (chapman_column(tau_r_z, z, h, RAYLEIGH_SCALE_HEIGHT_M)
               + aerosol_factor * chapman_column(tau_a_z, z, h, self.aerosol_scale_height_m))
        k_o3 = self.ozone_optical_depth / (OZONE_TOP_M - OZONE_BOTTOM_M)
        tau = tau + k_o3 * shell_path_m(z, h, OZONE_BOTTOM_M, OZONE_TOP_M)
        return np.where(lit, np.exp(-np.minimum(tau, 700.0)), 0.0), h


def hg_phase(cos_theta, g: float):
    """Henyey-Greenstein phase function, normalised to 4 pi over the sphere."""
    return (1.0 - g * g) / (1.0 + g * g - 2.0 * g * cos_theta) ** 1.5


def _rayleigh(cos_theta):
    """Rayleigh phase function (no depolarisation), normalised to 4 pi."""
    return 0.75 * (1.0 + cos_theta ** 2)


def _e3_diff(a, b):
    return expn(3, a) - expn(3, b)


def _kernels(d):
    """The isotropic-source kernels of the layers (no sun in them): ``M`` (N, N) layer-mean
    intensity at layer j per unit source function in layer i; ``up`` (N,) mean intensity per
    unit Lambertian surface radiance; ``down`` (N,) flux at the surface per unit source
    function; ``toa`` (N,) radiance at the top, straight up, per unit source function; and
    each layer's optical depth below and above its middle. ``d`` (N,): the layers' extinction
    optical depths, surface first."""
    top = np.concatenate([[0.0], np.cumsum(d)])        # optical depth from the surface up
    lo, hi = top[:-1], top[1:]
    gap = np.maximum(lo[None, :] - hi[:, None], lo[:, None] - hi[None, :])
    gap = np.maximum(gap, 0.0)
    dj, di = d[:, None], d[None, :]
    m = (expn(3, gap) - expn(3, gap + di) - expn(3, gap + dj)
         + expn(3, gap + di + dj)) / (2.0 * dj)
    np.fill_diagonal(m, 1.0 - (0.5 - expn(3, d)) / d)
    up = _e3_diff(lo, hi) / (2.0 * d)
    down = 2.0 * np.pi * _e3_diff(lo, hi)
    total = top[-1]
    toa = np.exp(-(total - hi)) - np.exp(-(total - lo))
    return m, up, down, toa, 0.5 * (lo + hi), total - 0.5 * (lo + hi)


def sky(*, solar_elevation_deg, z_m: float, albedo: float, tau_rayleigh: float,
        aerosol_optical_depth: float, aerosol_scale_height_m: float = 2000.0,
        aerosol_ssa: float = 0.95, ozone_optical_depth: float | None = None,
        horizon_height_m: float = 0.0, refraction: bool = True,
        multiple_scattering: bool = True) -> Sky:
    """The sun and sky at solar elevation(s) ``solar_elevation_deg`` [deg, geometric] over a
    horizontal Lambertian surface of albedo ``albedo`` at height ``z_m`` [m], per unit
    top-of-atmosphere irradiance.

    Args:
        tau_rayleigh: Rayleigh optical depth of the air above the surface at the wavelength.
        aerosol_optical_depth: aerosol optical depth at sea level at the wavelength (it decays
            with ``aerosol_scale_height_m`` [m]); ``aerosol_ssa`` its single-scattering albedo.
        ozone_optical_depth: the ozone column's (default: 0.3 atm cm at 532 nm, 0.0195).
        horizon_height_m: height above sea level [m] of the sphere that casts the Earth's
            shadow (ESTIMATE default 0: the sea-level horizon; an ice sheet stretching
            toward the sun casts it higher).
        refraction: bend the sun's rays (off for comparing with straight-ray renders).
        multiple_scattering: add the orders >= 2 and the surface's light scattered back.
    """
    if ozone_optical_depth is None:
        ozone_optical_depth = OZONE_COLUMN_ATM_CM * OZONE_ABSORPTION_PER_ATM_CM
    col = Column.build(z_m=float(z_m), tau_rayleigh=tau_rayleigh,
                       aerosol_optical_depth=aerosol_optical_depth,
                       aerosol_scale_height_m=aerosol_scale_height_m,
                       aerosol_ssa=aerosol_ssa, ozone_optical_depth=ozone_optical_depth)
    h0 = np.atleast_1d(np.asarray(solar_elevation_deg, np.float64))
    shape = np.shape(solar_elevation_deg)
    t_mid, h_mid = col.sun_transmittance(col.mid_m[None, :], h0[:, None],
                                         horizon_height_m=horizon_height_m,
                                         refraction=refraction)          # (E, N)
    direct = _direct(col, h0, float(z_m), horizon_height_m, refraction)
    below, above = _kernels(col.d_ext)[4:]
    first_down, first_toa = _first_order(col, t_mid, h_mid, below, above)
    path, diffuse = first_toa, first_down
    if multiple_scattering:
        path, diffuse = _all_orders(col, t_mid, direct, first_down, first_toa, float(albedo))
    surface = float(albedo) / np.pi * (direct + diffuse) * math.exp(-np.sum(col.d_ext))
    return Sky(*(a.reshape(shape) for a in (direct, diffuse, first_down, path, surface)))


def _direct(col: Column, h0, z_m: float, horizon_height_m: float, refraction: bool):
    """Direct sun on the horizontal surface [per unit E0]: the Rayleigh column's Kasten &
    Young air mass at the apparent elevation (with refraction; a straight-ray Chapman column
    without), the aerosol's Chapman column, the ozone shell; zero below the horizon."""
    t, h = col.sun_transmittance(np.full_like(h0, z_m), h0, horizon_height_m=horizon_height_m,
                                 refraction=refraction)
    if refraction:        # the Rayleigh part by Kasten & Young, continued below 0 by Chapman
        ch = chapman_column(1.0, z_m, h, RAYLEIGH_SCALE_HEIGHT_M)
        ch0 = chapman_column(1.0, z_m, 0.0, RAYLEIGH_SCALE_HEIGHT_M)
        m_ky = np.where(h >= 0.0, kasten_young_air_mass(h), kasten_young_air_mass(0.0) * ch / ch0)
        t = np.where(t > 0.0, t * np.exp(col.tau_rayleigh * (ch - m_ky)), 0.0)
    return t * np.maximum(np.sin(np.deg2rad(h)), 0.0)


def _first_order(col: Column, t_mid, h_mid, below, above):
    """First-order sky: ``(flux down at the surface, radiance straight up at the top)`` per
    unit E0, each (E,). A horizontal layer of scattering optical depth ``d`` lit by ``E0 T``
    scatters ``E0 T d`` per unit area whatever the sun's elevation (the beam's slant path and
    its slant cross-section cancel); its light reaches the surface by the phase function's
    downward lobe through ``exp(-tau / mu)``: for Rayleigh, azimuth-averaged,
    ``(3 / 8) [(1 + (1 - mu0^2) / 2) E2(t) + (mu0^2 - (1 - mu0^2) / 2) E4(t)]``."""
    mu0 = np.sin(np.deg2rad(h_mid))                                      # (E, N)
    d_r, d_a = col.d_rayleigh, col.aerosol_ssa * col.d_aerosol
    s2 = 1.0 - mu0 ** 2
    e2, e4 = expn(2, below), expn(4, below)                              # (N,)
    f_r = 0.375 * ((1.0 + 0.5 * s2) * e2 + (mu0 ** 2 - 0.5 * s2) * e4)
    # aerosol: Gauss-Legendre in mu, midpoint in azimuth, of HG's downward lobe, with the sun
    # as the lowest layer sees it (the aerosol's; refraction aloft differs by < 0.5 deg)
    m0 = mu0[:, :1]                                                      # (E, 1)
    ct = (np.sqrt(1.0 - m0 ** 2)[..., None] * np.sqrt(1.0 - _MU ** 2)[:, None] * np.cos(_PHI)
          + m0[..., None] * _MU[:, None])                                # (E, mu, phi)
    p_a = hg_phase(ct, AEROSOL_ASYMMETRY).mean(axis=-1)                  # (E, mu)
    att = np.exp(-below[:, None] / _MU)                                  # (N, mu)
    f_a = 0.5 * (p_a * _W_MU) @ att.T                                    # (E, N)
    flux = np.sum(t_mid * (d_r * f_r + d_a * f_a), axis=-1)
    cos_up = -mu0            # the sun's ray (going down at mu0) turned straight up
    phase = d_r * _rayleigh(cos_up) + d_a * hg_phase(cos_up, AEROSOL_ASYMMETRY)
    radiance = np.sum(t_mid * phase / (4.0 * np.pi) * np.exp(-above), axis=-1)
    return flux, radiance


def _all_orders(col: Column, t_mid, direct, first_down, first_toa, albedo: float):
    """Add the orders >= 2 and the surface's coupling (ESTIMATE: isotropic scattering from the
    second order on): the layers' source function ``S = w (J_sun + J)`` with ``J = M S + up
    I_s`` and the Lambertian surface's radiance ``I_s = albedo (F_dir + F_1 + down (S - S_1))
    / pi``, solved as one linear system; returns ``(path radiance, diffuse flux)`` with the
    exact first order in them. (Delta-scaling the aerosol's forward peak, Joseph, Wiscombe &
    Weinman 1976, was tried: it mends the hazy path radiance over dark ground but loses
    6-8 % of the light over snow against the renders; the isotropic form is kept.)"""
    w = col.d_sca / col.d_ext                                            # (N,)
    m, up, down, toa, _, _ = _kernels(col.d_ext)
    s1 = w * t_mid / (4.0 * np.pi)                                       # (E, N) first order
    n = w.size
    a = np.eye(n) - w[:, None] * m - (albedo / np.pi) * (w * up)[:, None] * down[None, :]
    rhs = (s1 + (w * up)[None, :] * (albedo / np.pi)
           * (direct + first_down - s1 @ down)[:, None])
    s = np.linalg.solve(a[None], rhs[..., None])[..., 0]                 # (E, N)
    extra = s - s1
    return first_toa + extra @ toa, first_down + extra @ down


NIGHT_DEG = -12.0
"""Below this solar elevation [deg] no air under 100 km (the model's top) is sunlit from a
sea-level horizon (the shadow is 140 km up at -12 deg): the sky model gives zero."""
GRID_ELEVATION_DEG = 0.25
GRID_HEIGHT_M = 250.0
"""Node spacing of the grid on which :func:`nadir_radiance` evaluates the model for many
shots, interpolated linearly in log radiance in between (elevation [deg], height [m])."""
TABLE = pathlib.Path(__file__).resolve().parent / "data" / "sky_table.json"
"""Mitsuba's renders of the sky (:mod:`lidar_mitsuba.studies.sky_table`), made once."""
DEEP_TWILIGHT_DEG = -4.0
"""Above this solar elevation [deg] the closed form agrees with the renders (within a few per
cent, ``docs/physics/sky.md``); below it the diffuse light's plane-parallel transport misses
the sunward sky lit lower down, and the renders' ratio to the closed form corrects it."""


@functools.cache
def _twilight_ratios():
    """``(elevations (K,), aerosol depths (A,), log(render / closed form) (A, K))`` below
    :data:`DEEP_TWILIGHT_DEG`, pooled over the albedos (and the deep-twilight renders with
    more samples) by inverse variance; 0 at :data:`DEEP_TWILIGHT_DEG` itself."""
    doc = json.loads(TABLE.read_text())
    e = np.asarray(doc["elevations_deg"])
    keep = np.flatnonzero(e < DEEP_TWILIGHT_DEG)
    rad = np.asarray(doc["radiance_per_sr"])
    se = np.asarray(doc["standard_error_per_sr"])
    aods = np.asarray(doc["aerosol_optical_depths"])
    out = np.zeros((aods.size, keep.size + 1))
    for i, aod in enumerate(aods):
        for n, k in enumerate(keep):
            entries = [(alb, rad[i, j, k], se[i, j, k]) for j, alb in enumerate(doc["albedos"])]
            entries += [(d["albedo"], d["radiance_per_sr"], d["standard_error_per_sr"])
                        for d in doc.get("deep_twilight", [])
                        if d["aerosol_optical_depth"] == aod and d["elevation_deg"] == e[k]]
            logs, weights = [], []
            for alb, r, s in entries:
                cf = sky(solar_elevation_deg=[e[k]], z_m=0.0, albedo=alb,
                         tau_rayleigh=doc["tau_rayleigh"], aerosol_optical_depth=aod,
                         refraction=False).toa_radiance[0]
                logs.append(math.log(r / cf))
                weights.append((r / s) ** 2)
            out[i, n] = np.average(logs, weights=weights)
    return np.concatenate([e[keep], [DEEP_TWILIGHT_DEG]]), aods, out


def twilight_correction(solar_elevation_deg, aerosol_optical_depth: float):
    """The renders' ratio to the closed form below :data:`DEEP_TWILIGHT_DEG` [1]:
    interpolated in log against elevation (held below the table's lowest, -8 deg) and
    linearly against aerosol optical depth (clipped to the table's 0.02-0.1); 1 above."""
    elev, aods, log_ratio = _twilight_ratios()
    a = float(np.clip(aerosol_optical_depth, aods[0], aods[-1]))
    row = np.array([np.interp(a, aods, log_ratio[:, k]) for k in range(elev.size)])
    h = np.asarray(solar_elevation_deg, np.float64)
    return np.where(h < DEEP_TWILIGHT_DEG, np.exp(np.interp(h, elev, row)), 1.0)


def _nodes(values, step: float):
    lo, hi = float(np.min(values)), float(np.max(values))
    k0, k1 = math.floor(lo / step), math.ceil(hi / step)
    return np.arange(k0, max(k1, k0 + 1) + 1) * step


def nadir_radiance(*, solar_elevation_deg, z_m, albedo, tau_rayleigh_of, aerosol_optical_depth,
                   aerosol_scale_height_m: float = 2000.0, aerosol_ssa: float = 0.95,
                   horizon_height_m: float = 0.0):
    """Radiance [sr^-1, per unit top-of-atmosphere solar irradiance] that a nadir-looking
    receiver above the atmosphere sees of each shot's surface and air (:func:`sky`'s
    ``toa_radiance``). Arrays broadcast: ``solar_elevation_deg`` [deg, geometric], ``z_m``
    [m], ``albedo``; ``tau_rayleigh_of(z_m)`` gives the Rayleigh optical depth above a height.

    Many shots: the model runs on a grid of nodes 0.25 deg x 250 m apart spanning the shots
    (one surface height per column of layers, the elevations batched) and is interpolated
    bilinearly in log radiance (within 1 % of a direct evaluation, ``tests/test_sky.py``).
    Below -4 deg the renders' ratio corrects it (:func:`twilight_correction`)."""
    e, z, a = np.broadcast_arrays(np.asarray(solar_elevation_deg, np.float64),
                                  np.asarray(z_m, np.float64), np.asarray(albedo, np.float64))
    out = np.zeros(e.shape)
    day = e > NIGHT_DEG
    if not day.any():
        return out
    e_n = _nodes(e[day], GRID_ELEVATION_DEG)
    z_n = _nodes(z[day], GRID_HEIGHT_M)
    for alb in np.unique(a[day]):
        pick = day & (a == alb)
        table = np.empty((e_n.size, z_n.size))
        for j, zj in enumerate(z_n):
            table[:, j] = sky(solar_elevation_deg=e_n, z_m=zj, albedo=alb,
                              tau_rayleigh=float(tau_rayleigh_of(zj)),
                              aerosol_optical_depth=aerosol_optical_depth,
                              aerosol_scale_height_m=aerosol_scale_height_m,
                              aerosol_ssa=aerosol_ssa,
                              horizon_height_m=horizon_height_m).toa_radiance
        out[pick] = _bilinear_log(table, e_n, z_n, e[pick], z[pick])
    return out * twilight_correction(e, aerosol_optical_depth)


def _bilinear_log(table, x_nodes, y_nodes, x, y):
    """Bilinear interpolation of ``log(table)`` (zeros stay zero where a node is zero)."""
    log = np.log(np.maximum(table, 1e-300))
    fx = np.clip((x - x_nodes[0]) / (x_nodes[1] - x_nodes[0]) if x_nodes.size > 1
                 else np.zeros_like(x), 0, x_nodes.size - 1)
    fy = np.clip((y - y_nodes[0]) / (y_nodes[1] - y_nodes[0]) if y_nodes.size > 1
                 else np.zeros_like(y), 0, y_nodes.size - 1)
    i = np.minimum(fx.astype(int), max(x_nodes.size - 2, 0))
    j = np.minimum(fy.astype(int), max(y_nodes.size - 2, 0))
    tx, ty = fx - i, fy - j
    i1, j1 = np.minimum(i + 1, x_nodes.size - 1), np.minimum(j + 1, y_nodes.size - 1)
    v = ((1 - tx) * (1 - ty) * log[i, j] + tx * (1 - ty) * log[i1, j]
         + (1 - tx) * ty * log[i, j1] + tx * ty * log[i1, j1])
    return np.where(v < -600.0, 0.0, np.exp(v))
