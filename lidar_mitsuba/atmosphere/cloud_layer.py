"""A cloud layer as a run's input, and its closed forms. Pure numpy.

:class:`Cloud` is one homogeneous layer over the whole track: vertical optical depth at
532 nm ``optical_depth`` (tau), base and top ``base_m``, ``top_m`` above the surface,
Henyey-Greenstein asymmetry ``g``, single-scattering albedo and lidar ratio. What a run does
with it (``lm.simulate(cloud=...)``; docs/physics/clouds.md):

* the ground's light: the unscattered part is attenuated both ways, ``exp(-2 tau)``
  (Beer-Lambert); the part scattered forward that still reaches the receiver's field of view
  arrives late (the surface appears lower: Duda et al. 2001; Yang et al. 2011). Both are
  tabulated once per cloud from the media integrator (:mod:`.cloud_kernel`);
* the cloud's own backscatter where the layer lies inside the range gate (fog, low stratus,
  blowing snow): the single-scattering lidar equation with the cloud's lidar ratio
  (:meth:`Cloud.backscatter_weight`);
* the sunlight: the cloud over a Lambertian surface of albedo A has the two-stream albedo
  ``R + T^2 A / (1 - R A)`` of a conservative layer (:meth:`Cloud.system_albedo`, Bohren
  1987): the sun below a thick cloud is dimmed and the cloud's top is bright;
  :func:`clouded_radiometry` replaces the surface's albedo by it in the solar background,
  and attenuates the air's laser backscatter under the cloud by ``exp(-2 tau)``.

:class:`CloudClimatology` draws clouds for campaigns: cloudy with probability
``cloud_fraction``, the optical depth log-normal, seeded.

Published values used (each also where it is used):

* water droplets at 532 nm: ``g = 0.85`` (Hansen & Travis 1974, Space Sci. Rev. 16, 527:
  the asymmetry of cloud droplet size distributions at visible wavelengths, 0.84-0.86),
  single-scattering albedo 1 (a co-albedo ~1e-6 for 10 um droplets from liquid water's
  absorption index k ~ 2e-9 at 532 nm, Hale & Querry 1973, Appl. Opt. 12, 555), lidar ratio 18.8 sr (O'Connor,
  Illingworth & Gaussiat 2004, J. Atmos. Ocean. Technol. 21, 777: liquid water clouds,
  ~18.8 sr for the droplet sizes of stratocumulus; recalled);
* ice crystals: ``g = 0.75`` and lidar ratio 25 sr (recalled: ice-cloud asymmetry 0.74-0.80
  at visible wavelengths, Baum et al. 2011 J. Appl. Meteor. Climatol. 50, 1037; CALIOP's
  ice-cloud lidar ratio ~25 sr, Garnier et al. 2015 J. Appl. Meteor. Climatol. 54, 1063;
  ground-based cirrus lidars give 29 +- 12 sr, Chen, Chiang & Nee 2002, Appl. Opt. 41, 6470:
  CALIOP's is kept, a spaceborne 532 nm lidar's view of the clouds ATLAS sees, and inside
  Chen et al.'s range);
* Platt's multiple-scattering factor ``eta`` (Platt 1973, J. Atmos. Sci. 30, 1191): a lidar's
  closed-form attenuation through a cloud is ``exp(-2 eta tau)``, ``eta < 1`` where light
  scattered forward stays in the field of view (:attr:`Cloud.multiple_scattering_eta`,
  default 1: single scattering; the traced runs carry the forward scattering themselves);
* Henyey-Greenstein's backscatter ``p(pi) = (1 - g^2) / (4 pi (1 + g)^3)`` is ~20 times
  below a droplet's (its forward peak is too weak and its back too dark), so the backscatter
  uses the lidar ratio: ``beta = sigma_ext / S``.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..constants import C_M_PER_NS, REFERENCE_ALBEDO, ParameterError

WATER_G = 0.85
"""Henyey-Greenstein asymmetry of cloud droplets at 532 nm (Hansen & Travis 1974)."""
WATER_LIDAR_RATIO_SR = 18.8
"""Extinction-to-backscatter ratio of liquid water clouds [sr] (O'Connor et al. 2004)."""
ICE_G = 0.75
"""Asymmetry of ice crystals at visible wavelengths (Baum et al. 2011: 0.74-0.80)."""
ICE_LIDAR_RATIO_SR = 25.0
"""Extinction-to-backscatter ratio of ice clouds [sr] (CALIOP's, Garnier et al. 2015)."""
LIDAR_RATIO_SR = {"water": WATER_LIDAR_RATIO_SR, "ice": ICE_LIDAR_RATIO_SR}
"""The lidar ratio of each phase [sr]: the one table (module sources)."""
MAX_OPTICAL_DEPTH = 20.0
"""Above this the ground's unscattered light is exp(-40): nothing of the surface is left."""
MAX_TOP_M = 20000.0
"""The highest cloud top above the surface [m] (above the tropopause: none)."""


def _finite(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) \
        and math.isfinite(float(v))


@dataclass(frozen=True)
class Cloud:
    """One homogeneous cloud layer over the track.

    Attributes:
        optical_depth: vertical optical depth at 532 nm (>= 0; 0: clear sky) [1].
        base_m, top_m: the layer's base and top above the surface [m] (0 <= base < top).
        g: Henyey-Greenstein asymmetry of the phase function (-1 < g < 1; 0.85: water).
        single_scattering_albedo: scattering / extinction (0 < a <= 1; 1: water at 532 nm).
        lidar_ratio_sr: extinction-to-backscatter ratio S [sr] setting the cloud's own
            backscatter ``beta = sigma_ext / S``; ``None``: Henyey-Greenstein's ``p(pi)``.
        phase: a label (``"water"``, ``"ice"``, ``"hg"``): where ``g`` and ``S`` come from.
        multiple_scattering_eta: Platt's factor on the optical depth in the closed-form lidar
            attenuation ``exp(-2 eta tau)`` (0 < eta <= 1; 1: single scattering). Used by the
            closed forms (:meth:`lidar_two_way_transmission`,
            :meth:`integrated_backscatter_sr`); traced runs carry forward scattering
            themselves and ignore it.
    """
    optical_depth: float
    base_m: float
    top_m: float
    g: float = WATER_G
    single_scattering_albedo: float = 1.0
    lidar_ratio_sr: float | None = WATER_LIDAR_RATIO_SR
    phase: str = "water"
    multiple_scattering_eta: float = 1.0

    def __post_init__(self):
        tau = self.optical_depth
        if not (_finite(tau) and 0 <= tau <= MAX_OPTICAL_DEPTH):
            raise ParameterError("cloud_od", f"the cloud's optical depth must be in [0, "
                                 f"{MAX_OPTICAL_DEPTH:g}] (got {tau!r})")
        if not (_finite(self.base_m) and 0 <= self.base_m < MAX_TOP_M):
            raise ParameterError("cloud_base_m", f"must be in [0, {MAX_TOP_M:g}) m above the "
                                 f"surface (got {self.base_m!r})")
        if not (_finite(self.top_m) and self.base_m < self.top_m <= MAX_TOP_M):
            raise ParameterError("cloud_top_m", f"must be above the base ({self.base_m!r} m) "
                                 f"and at most {MAX_TOP_M:g} m (got {self.top_m!r})")
        if not (_finite(self.g) and -1 < self.g < 1):
            raise ParameterError("cloud_g", f"must be in (-1, 1) (got {self.g!r})")
        a = self.single_scattering_albedo
        if not (_finite(a) and 0 < a <= 1):
            raise ParameterError("cloud_albedo", f"must be in (0, 1] (got {a!r})")
        s = self.lidar_ratio_sr
        if s is not None and not (_finite(s) and 1 <= s <= 200):
            raise ParameterError("cloud_lidar_ratio_sr", f"must be in [1, 200] sr or None "
                                 f"(got {s!r})")
        eta = self.multiple_scattering_eta
        if not (_finite(eta) and 0 < eta <= 1):
            raise ParameterError("multiple_scattering_eta", f"must be in (0, 1] (got {eta!r})")

    @classmethod
    def water(cls, optical_depth: float, base_m: float, top_m: float) -> "Cloud":
        """A liquid water cloud: g 0.85, albedo 1, lidar ratio 18.8 sr (module sources)."""
        return cls(optical_depth, base_m, top_m)

    @classmethod
    def ice(cls, optical_depth: float, base_m: float, top_m: float) -> "Cloud":
        """An ice cloud: g 0.75, albedo 1, lidar ratio 25 sr (module sources)."""
        return cls(optical_depth, base_m, top_m, g=ICE_G, lidar_ratio_sr=ICE_LIDAR_RATIO_SR,
                   phase="ice")

    @property
    def clear(self) -> bool:
        """No cloud (optical depth 0): the run is clear sky, to the bit."""
        return self.optical_depth == 0

    @property
    def thickness_m(self) -> float:
        return self.top_m - self.base_m

    @property
    def extinction_per_m(self) -> float:
        """sigma_ext = tau / thickness [1/m]."""
        return self.optical_depth / self.thickness_m

    @property
    def two_way_transmission(self) -> float:
        """exp(-2 tau): the ground's unscattered light after the way down and up."""
        return math.exp(-2.0 * self.optical_depth)

    @property
    def lidar_two_way_transmission(self) -> float:
        """``exp(-2 eta tau)``: what the closed-form lidar equation leaves of a return from
        below the layer (Platt's eta; = :attr:`two_way_transmission` at eta = 1)."""
        return math.exp(-2.0 * self.multiple_scattering_eta * self.optical_depth)

    def integrated_backscatter_sr(self) -> float:
        """``integral beta T_c^2 dz`` through the whole layer [1/sr], ``beta = s_s p(pi)``:
        for a uniform layer ``(1 - exp(-2 eta tau)) albedo p(pi) / (2 eta)`` (``= (1 -
        exp(-2 eta tau)) / (2 eta S)`` with a lidar ratio S; the closed form of the layer's
        attenuated backscatter)."""
        eta, tau = self.multiple_scattering_eta, self.optical_depth
        return ((1.0 - math.exp(-2.0 * eta * tau)) * self.single_scattering_albedo
                * self.backscatter_phase_per_sr / (2.0 * eta))

    def backscatter_share_below(self, z_m: float) -> float:
        """The share of :meth:`integrated_backscatter_sr` returned from heights below ``z_m``
        [m above the surface]: light that reaches a depth ``d`` below the top is dimmed by
        ``exp(-2 eta s d)`` (``s`` the extinction), so the layer's part below ``z`` returns
        ``(exp(-2 eta s (top - z)) - exp(-2 eta tau)) / (1 - exp(-2 eta tau))`` of it (the
        lidar equation through a uniform layer, as :meth:`backscatter_weight`); 1 at or above
        the top, 0 at or below the base."""
        if self.clear or z_m <= self.base_m:
            return 0.0
        if z_m >= self.top_m:
            return 1.0
        k = 2.0 * self.multiple_scattering_eta * self.extinction_per_m
        whole = math.exp(-2.0 * self.multiple_scattering_eta * self.optical_depth)
        return (math.exp(-k * (self.top_m - z_m)) - whole) / (1.0 - whole)

    @property
    def backscatter_phase_per_sr(self) -> float:
        """p(pi) [1/sr]: ``1 / (albedo S)`` with a lidar ratio (beta = sigma_s p(pi) =
        sigma_ext / S), else Henyey-Greenstein's ``(1 - g^2) / (4 pi (1 + g)^3)``."""
        if self.lidar_ratio_sr is not None:
            return 1.0 / (self.single_scattering_albedo * self.lidar_ratio_sr)
        g = self.g
        return (1 - g * g) / (4 * math.pi * (1 + g) ** 3)

    # ---------------------------------------------------------------- its own backscatter
    def backscatter_weight(self, lo_m: float, hi_m: float) -> float:
        """The cloud's single-scattering return from heights ``lo_m`` .. ``hi_m`` above the
        surface, in return weight per path (a Lambertian 0.9 plate at nadir = 1):
        ``(pi / 0.9) beta (exp(-2 s (top - z_hi)) - exp(-2 s (top - z_lo))) / (2 s)`` over the
        part of the layer between them, ``beta = s_s p(pi)`` and ``s`` its extinction (the
        lidar equation; multiple scattering, which adds to it in thick clouds, left out)."""
        z0, z1 = max(lo_m, self.base_m), min(hi_m, self.top_m)
        if self.clear or z1 <= z0:
            return 0.0
        s = self.extinction_per_m
        beta = s * self.single_scattering_albedo * self.backscatter_phase_per_sr
        span = math.exp(-2 * s * (self.top_m - z1)) - math.exp(-2 * s * (self.top_m - z0))
        return math.pi / REFERENCE_ALBEDO * beta * span / (2 * s)

    def backscatter_heights_m(self, u: np.ndarray, lo_m: float, hi_m: float) -> np.ndarray:
        """Heights [m] above the surface distributed as the cloud's return between ``lo_m``
        and ``hi_m`` (the inverse CDF of ``exp(-2 s (top - z))`` at uniforms ``u``)."""
        z0, z1 = max(lo_m, self.base_m), min(hi_m, self.top_m)
        s2 = 2 * self.extinction_per_m
        a, b = math.exp(-s2 * (self.top_m - z0)), math.exp(-s2 * (self.top_m - z1))
        return self.top_m + np.log(a + np.asarray(u) * (b - a)) / s2

    # ---------------------------------------------------------------- sunlight
    @property
    def diffuse_reflectance(self) -> float:
        """Two-stream reflectance of the layer for diffuse light, ``(1 - g) tau / (2 + (1 -
        g) tau)`` (conservative scattering, Bohren 1987, Am. J. Phys. 55, 524), with
        absorption put in as extra extinction (a's co-albedo: exact at a = 1)."""
        t = (1 - self.g) * self.optical_depth * self.single_scattering_albedo
        return t / (2 + t) * math.exp(-(1 - self.single_scattering_albedo) * self.optical_depth)

    @property
    def diffuse_transmittance(self) -> float:
        """Two-stream transmittance ``2 / (2 + (1 - g) tau)`` (Bohren 1987), with absorption."""
        t = (1 - self.g) * self.optical_depth * self.single_scattering_albedo
        return 2 / (2 + t) * math.exp(-(1 - self.single_scattering_albedo) * self.optical_depth)

    def system_albedo(self, surface_albedo: float) -> float:
        """The albedo the sun sees from above: the cloud over a Lambertian surface of albedo A,
        ``R + T^2 A / (1 - R A)`` (the adding rule for two diffusely reflecting layers)."""
        r, t, a = self.diffuse_reflectance, self.diffuse_transmittance, float(surface_albedo)
        return r + t * t * a / (1 - r * a)

    # ---------------------------------------------------------------- records
    def to_dict(self) -> dict:
        """The fields (Platt's eta only where it is not 1: a run's record stays as it was)."""
        d = dataclasses.asdict(self)
        if d["multiple_scattering_eta"] == 1.0:
            del d["multiple_scattering_eta"]
        return d

    def describe(self) -> str:
        s = "" if self.lidar_ratio_sr is None else f", lidar ratio {self.lidar_ratio_sr:g} sr"
        return (f"a {self.phase} cloud {self.base_m:g}-{self.top_m:g} m above the surface, "
                f"optical depth {self.optical_depth:g} (two-way transmission "
                f"{self.two_way_transmission:.3g}), g {self.g:g}, albedo "
                f"{self.single_scattering_albedo:g}{s}")


def as_cloud(value, name: str = "cloud") -> Cloud | None:
    """A run's ``cloud`` argument checked: a :class:`Cloud`, a dict of its fields, or None."""
    if value is None or isinstance(value, Cloud):
        return value
    if isinstance(value, dict):
        try:
            return Cloud(**value)
        except TypeError as e:
            raise ParameterError(name, str(e)) from None
    raise ParameterError(name, f"must be a Cloud, a dict of its fields or None (got "
                         f"{type(value).__name__})")


def clouded_radiometry(rad, cloud: Cloud, instrument, *, delta_time_s, z_m):
    """A run's :class:`~lidar_mitsuba.radiometry.ShotRadiometry` under ``cloud``: the solar
    background again with the surface's albedo replaced by the cloud-over-surface albedo
    (:meth:`Cloud.system_albedo`: a thin cloud dims the surface's reflected sunlight, a thick
    one is brighter than dark ground), the direct sun's share of it reflected with the
    layer's nadir reflectance factor
    (:func:`~lidar_mitsuba.atmosphere.cloud_reflection.direct_sun_factor`), and the air's laser backscatter (from just above the
    surface, under the cloud) times ``exp(-2 tau)``. The signal scale is unchanged (the
    cloud's attenuation is in the returns)."""
    from .. import radiometry
    if cloud is None or cloud.clear or rad is None:
        return rad
    sunny = radiometry.shot_radiometry(
        instrument, delta_time_s=delta_time_s, z_m=z_m,
        albedo=cloud.system_albedo(rad.albedo), solar_elevation_deg=rad.solar_elevation_deg,
        solar_azimuth_deg=rad.solar_azimuth_deg)
    from .cloud_reflection import direct_sun_factor
    solar = sunny.solar_mhz * direct_sun_factor(
        cloud, surface_albedo=rad.albedo, solar_elevation_deg=rad.solar_elevation_deg,
        z_m=float(np.nanmedian(np.atleast_1d(z_m))),
        atmosphere=instrument.link_budget.atmosphere, wavelength_nm=instrument.wavelength_nm)
    back = rad.backscatter_mhz * cloud.two_way_transmission
    other = rad.background_mhz - rad.solar_mhz - rad.backscatter_mhz   # the instrument's own
    return dataclasses.replace(rad, solar_mhz=solar, backscatter_mhz=back,
                               background_mhz=solar + back + other)


def window_heights_m(instrument) -> tuple[float, float]:
    """The range gate's heights relative to the reference surface [m]: ``+-gate / 2``."""
    half = instrument.range_gate_m / 2.0
    return -half, half


def delay_to_height_m(delay_ns):
    """A round-trip delay [ns] as the height it lowers a photon by [m] (c t / 2)."""
    return C_M_PER_NS * np.asarray(delay_ns) / 2.0


@dataclass(frozen=True)
class CloudClimatology:
    """Clouds drawn for a campaign's granules: cloudy with probability ``cloud_fraction``,
    the optical depth log-normal (median ``optical_depth_median``, log standard deviation
    ``optical_depth_log_sigma``, capped at :data:`MAX_OPTICAL_DEPTH`), the layer at
    ``base_m`` .. ``top_m`` of ``phase`` (``"water"`` or ``"ice"``). The numbers are the
    user's: give a region's and season's, e.g. from CALIPSO or ATL09 cloud statistics."""
    cloud_fraction: float
    optical_depth_median: float = 1.0
    optical_depth_log_sigma: float = 1.0
    base_m: float = 1000.0
    top_m: float = 1500.0
    phase: str = "water"

    def __post_init__(self):
        f = self.cloud_fraction
        if not (_finite(f) and 0 <= f <= 1):
            raise ParameterError("cloud_fraction", f"must be in [0, 1] (got {f!r})")
        m = self.optical_depth_median
        if not (_finite(m) and 0 < m <= MAX_OPTICAL_DEPTH):
            raise ParameterError("optical_depth_median", f"must be in (0, "
                                 f"{MAX_OPTICAL_DEPTH:g}] (got {m!r})")
        s = self.optical_depth_log_sigma
        if not (_finite(s) and 0 <= s <= 5):
            raise ParameterError("optical_depth_log_sigma", f"must be in [0, 5] (got {s!r})")
        if self.phase not in ("water", "ice"):
            raise ParameterError("phase", f"must be 'water' or 'ice' (got {self.phase!r})")
        Cloud(1.0, self.base_m, self.top_m)          # checks the heights

    def draw(self, rng: np.random.Generator) -> Cloud | None:
        """One granule's cloud (None: clear), from ``rng``."""
        cloudy = rng.random() < self.cloud_fraction
        tau = min(self.optical_depth_median * math.exp(self.optical_depth_log_sigma
                                                        * rng.standard_normal()),
                  MAX_OPTICAL_DEPTH)
        if not cloudy:
            return None
        make = Cloud.water if self.phase == "water" else Cloud.ice
        return make(round(tau, 4), self.base_m, self.top_m)
