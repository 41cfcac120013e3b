"""Every count that makes ATLAS's background rate: what the ``bckgrd_atlas/bckgrd_rate`` of an
ATL03 file (and the ``bckgrd`` of ATL06, ``backgr_r_200`` of ATL07 copied from it) counts,
term by term, each with its source. Pure numpy.

How the product measures it (ATL03 ATBD, Neumann et al., "background rate from the altimetric
histogram"; the fields of ``bckgrd_atlas``): ATLAS sums the photon events of 50 shots into an
altimetric histogram over a band ``bckgrd_int_height`` tall (about 5 km, its top
``bckgrd_hist_top`` about 2.5 km above the surface in the real files); the ground processing
removes the bins its signal finder calls surface (``bckgrd_int_height_reduced`` is the band less
that span, ``bckgrd_counts_reduced`` the counts left) and divides::

    bckgrd_rate = bckgrd_counts_reduced / (50 * 2 * bckgrd_int_height_reduced / c)

(the real ATL03 files agree to 2e-7). So the rate holds, averaged over the whole band:

1. **dark counts** of every anode of the beam's detector (:data:`DARK_COUNT_PER_ANODE_HZ`);
   both beams' detectors have 16 anodes, so both count the same dark rate;
2. **sunlight** (surface and sky): :meth:`~lidar_mitsuba.radiometry.LinkBudget.solar_background_hz`
   through :func:`~lidar_mitsuba.radiometry.shot_radiometry` (the sky model's, unchanged here);
3. **the laser's light scattered back by the air** over the part of the band above the surface
   (Rayleigh and aerosol; below the surface the band holds no air):
   ``N T0^2 (A / R^2) eta_rx * integral beta(z) T(z)^2 dz / (2 H / c)``;
4. **cloud backscatter** where a cloud layer is given
   (:class:`~lidar_mitsuba.atmosphere.cloud_layer.Cloud`), which also dims everything below it
   by ``exp(-2 eta tau)``;
5. **the laser's own surface photons that the signal span misses**: a signal of ``S`` detected
   photons per shot of which a fraction ``f`` falls outside the removed span adds
   ``S f c / (2 H)`` (the pulse's tails, echoes and afterpulses: whatever the detected
   photons' height distribution has outside the span; for a Gaussian pulse
   ``f = erfc(w / (2 sqrt(2) sigma))``).

Photon terms are thinned by the detector's fill factor and PDE (dead time is negligible at
these rates: < 1e-3 of a channel's time); dark counts are counted as they are. The strong:weak
ratio of the night floor follows from these terms: the air and the leak scale with the pulse
energy (4:1), the dark counts do not.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .constants import C_M_PER_NS, check

C_M_PER_S = C_M_PER_NS * 1e9

DARK_COUNT_PER_ANODE_HZ = 25.0
"""Dark counts of one anode of an ATLAS detector (a 16-anode photomultiplier) [Hz].
ESTIMATE: no flown value is published that we found (Martino et al. 2019 and the ATL03 ATBD
give none); bounded by the quietest 50-shot row of the real weak beam at night (599 Hz over
its detector's 16 anodes, ``lidar_mitsuba/data``, sun 7 deg below the horizon): <= 37 Hz an
anode. 25 Hz keeps the weak beam's 100 Hz a channel of earlier versions."""

AEROSOL_LIDAR_RATIO_SR = 50.0
"""Extinction-to-backscatter ratio of aerosol at 532 nm [sr] (ESTIMATE from the published
range: 40-70 sr for most aerosol types, Mueller et al. 2007, J. Geophys. Res. 112, D16202;
Arctic haze ~50-60 sr)."""

BAND_HEIGHT_M = 5006.5
"""Height of the altimetric histogram's band where a file does not give it [m]: ATL03's
``bckgrd_int_height`` over polar surfaces (5006.5 m in the shipped subset; ATL07's
``background_int_height`` reads 4998-5006 m). ESTIMATE for other files (over land the band
follows the onboard relief map: 750-3400 m in the forest clip)."""

BAND_TOP_ABOVE_SURFACE_M = 2506.0
"""Top of that band above the surface where a file does not give it [m]: the shipped subset's
``bckgrd_hist_top`` (2517-2521 m) over its surface (12 m). ESTIMATE elsewhere."""

SIGNAL_SPAN_M = 0.9
"""Height span the product removes as surface signal where a file does not give it [m]:
``bckgrd_int_height - bckgrd_int_height_reduced`` of the shipped subset (median 0.9 m, sea
ice at night). ESTIMATE elsewhere (the forest clip removes ~5 m)."""


def dark_count_per_channel_hz(*, anodes: int, channels: int) -> float:
    """Dark counts of one channel [Hz]: :data:`DARK_COUNT_PER_ANODE_HZ` times the anodes it
    sums (``anodes / channels``)."""
    check("channels", channels, channels > 0 and anodes % channels == 0,
          f"must divide the {anodes} anodes")
    return DARK_COUNT_PER_ANODE_HZ * anodes / channels


def cloud_backscatter(cloud) -> tuple[float, float]:
    """``(two-way transmission, integrated attenuated backscatter [1/sr])`` of a cloud layer
    (:class:`~lidar_mitsuba.atmosphere.cloud_layer.Cloud`: its lidar ratio and Platt's eta,
    :meth:`~lidar_mitsuba.atmosphere.cloud_layer.Cloud.integrated_backscatter_sr`)."""
    return cloud.lidar_two_way_transmission, cloud.integrated_backscatter_sr()


def air_backscatter_integral_sr(atmosphere, *, z_lo_m: float, z_hi_m: float,
                                wavelength_nm: float = 532.0, n: int = 400) -> float:
    """``integral beta(z) T(z)^2 dz`` from ``z_lo_m`` to ``z_hi_m`` [m above sea level]
    [1/sr]: the air's backscatter (Rayleigh ``3 / 8 pi`` of its scattering, aerosol
    ``1 / AEROSOL_LIDAR_RATIO_SR`` of its extinction), the scattering coefficients the height
    derivatives of the :class:`~lidar_mitsuba.radiometry.Atmosphere`'s optical depths, each
    height's light attenuated on its way up and back (``T(z)`` its one-way transmission to
    space). Trapezoids on ``n`` heights."""
    if z_hi_m <= z_lo_m:
        return 0.0
    z = np.linspace(z_lo_m, z_hi_m, n)
    tau_r, tau_a = atmosphere.optical_depths(z, wavelength_nm)
    sigma_r = -np.gradient(tau_r, z)
    sigma_a = -np.gradient(tau_a, z)
    beta = 3.0 / (8.0 * math.pi) * sigma_r + sigma_a / AEROSOL_LIDAR_RATIO_SR
    t2 = np.exp(-2.0 * (tau_r + tau_a))
    y = beta * t2
    return float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(z)))


def gaussian_outside_fraction(span_m, sigma_m: float):
    """Fraction of a Gaussian of standard deviation ``sigma_m`` [m] outside a span of
    ``span_m`` [m] centred on it: ``erfc(span / (2 sqrt(2) sigma))``."""
    from scipy.special import erfc
    span = np.asarray(span_m, np.float64)
    return erfc(span / (2.0 * math.sqrt(2.0) * max(sigma_m, 1e-12)))


@dataclass
class HistogramBand:
    """The altimetric histogram's band for one beam: its height, its top above the surface and
    the span removed as signal, each [m] (arrays or scalars; the defaults where a file gives
    none, :data:`BAND_HEIGHT_M`, ...), and whether they came from the file."""
    height_m: np.ndarray | float = BAND_HEIGHT_M
    top_above_surface_m: np.ndarray | float = BAND_TOP_ABOVE_SURFACE_M
    signal_span_m: np.ndarray | float = SIGNAL_SPAN_M
    from_file: bool = False


def background_terms(instrument, *, delta_time_s, z_m, albedo: float, solar_elevation_deg,
                     solar_azimuth_deg, band: HistogramBand | None = None,
                     signal_per_shot: float = 0.0, outside_fraction=None,
                     cloud=None, deck=None, deck_cover: float = 0.0) -> dict:
    """The detected background rate the product reports, term by term [Hz, medians over the
    shots or segments given], for an ATLAS ``instrument`` (with a link budget).

    Args:
        delta_time_s, z_m, solar_elevation_deg, solar_azimuth_deg: (n,) when [s since
            2018-01-01], the surface height [m above sea level], the sun [deg].
        albedo: the surface's Lambertian albedo for sunlight.
        band: the histogram's band (:class:`HistogramBand`; default: the polar defaults).
        signal_per_shot: detected surface photons per shot (the leak term's ``S``).
        outside_fraction: the fraction of them outside the removed span (default: the
            instrument's Gaussian pulse, :func:`gaussian_outside_fraction`).
        cloud: a :class:`~lidar_mitsuba.atmosphere.cloud_layer.Cloud` (default: clear
            sky).
        deck, deck_cover: clear segments in the gaps of a broken deck (a ``Cloud``) of this
            cover [0, 1], ``cloud`` None: the sunlight shaded (:func:`shaded_solar_hz`).

    Returns ``{"dark", "solar", "air", "cloud", "leak", "total"}`` [Hz, detected].
    """
    from .radiometry import shot_radiometry
    band = band or HistogramBand()
    link = instrument.link_budget
    keep = instrument.fill_factor * instrument.pde
    z = np.atleast_1d(np.asarray(z_m, np.float64))
    # under a cloud the sun sees the cloud over the surface (its two-stream system albedo,
    # as a run's radiometry: atmosphere.cloud_layer.clouded_radiometry), the direct sun's
    # share reflected with its nadir reflectance factor (atmosphere.cloud_reflection)
    sunlit = albedo if cloud is None else cloud.system_albedo(albedo)
    rad = shot_radiometry(instrument, delta_time_s=delta_time_s, z_m=z, albedo=sunlit,
                          solar_elevation_deg=solar_elevation_deg,
                          solar_azimuth_deg=solar_azimuth_deg)
    h = float(np.nanmedian(np.atleast_1d(band.height_m)))
    top = float(np.nanmedian(np.atleast_1d(band.top_above_surface_m)))
    z0 = float(np.nanmedian(z))
    lam = instrument.wavelength_nm
    range_m = instrument.altitude_m - z0
    # photons per shot per (1/sr of integrated backscatter) at the detector
    per_sr = (link.photons_per_pulse(lam) * link.telescope_area_m2 / range_m ** 2
              * link.receiver_transmission)
    band_s = 2.0 * h / C_M_PER_S
    t_cloud = 1.0
    cloud_hz = 0.0
    if cloud is not None:
        t_cloud, cloud_ib = cloud_backscatter(cloud)
        air_above = float(link.atmosphere.transmission(z0 + cloud.top_m, wavelength_nm=lam)
                          ** 2)
        # the part of the layer inside the band (ESTIMATE: its backscatter taken uniform
        # in height; exact for a layer wholly inside or outside the band)
        in_band = max(0.0, min(cloud.top_m, top) - cloud.base_m) / (cloud.top_m - cloud.base_m)
        cloud_hz = per_sr * cloud_ib * air_above * in_band / band_s
    lo, hi = z0, z0 + max(top, 0.0)
    if cloud is not None:             # the air below the cloud dimmed by it, above it not
        below = air_backscatter_integral_sr(link.atmosphere, z_lo_m=lo,
                                            z_hi_m=min(hi, z0 + cloud.base_m), wavelength_nm=lam)
        above = air_backscatter_integral_sr(link.atmosphere, z_lo_m=z0 + cloud.top_m,
                                            z_hi_m=hi, wavelength_nm=lam)
        air_sr = below * t_cloud + above
    else:
        air_sr = air_backscatter_integral_sr(link.atmosphere, z_lo_m=lo, z_hi_m=hi,
                                             wavelength_nm=lam)
    air_hz = per_sr * air_sr / band_s
    if outside_fraction is None:
        sigma_m = C_M_PER_NS * instrument.pulse_sigma_ns / 2.0
        outside_fraction = gaussian_outside_fraction(band.signal_span_m, sigma_m)
    f_out = float(np.nanmedian(np.atleast_1d(outside_fraction)))
    leak_hz = signal_per_shot * f_out / band_s          # detected photons already
    solar_hz = _solar_hz(instrument, float(np.median(rad.solar_mhz)) * 1e6, cloud=cloud,
                         albedo=albedo, deck=deck, deck_cover=deck_cover,
                         delta_time_s=delta_time_s, z_m=z0,
                         solar_elevation_deg=solar_elevation_deg)
    out = {"dark": instrument.dark_count_hz * instrument.channels,
           # sunlight as the sky model gives it, the surface's albedo the cloud's system's
           "solar": solar_hz * keep,
           "air": air_hz * keep, "cloud": cloud_hz * keep, "leak": leak_hz}
    out["total"] = sum(out.values())
    return out


def _solar_hz(instrument, solar_hz: float, *, cloud, albedo: float, deck, deck_cover: float,
              delta_time_s, z_m: float, solar_elevation_deg) -> float:
    """The sky model's sunlight ``solar_hz`` [Hz] under ``cloud`` with the direct sun's share
    reflected with the layer's nadir reflectance factor
    (:func:`~lidar_mitsuba.atmosphere.cloud_reflection.direct_sun_factor`, at the median
    factor over the shots), or clear in the gaps of a broken ``deck`` (:func:`shaded_solar_hz`)."""
    if cloud is not None:
        from .atmosphere.cloud_reflection import direct_sun_factor
        link = instrument.link_budget
        return solar_hz * float(np.median(direct_sun_factor(
            cloud, surface_albedo=albedo, solar_elevation_deg=solar_elevation_deg, z_m=z_m,
            atmosphere=link.atmosphere, wavelength_nm=instrument.wavelength_nm)))
    if deck is not None and deck_cover > 0.0:
        return shaded_solar_hz(instrument, solar_hz, deck=deck, cover=deck_cover,
                               delta_time_s=delta_time_s, z_m=z_m,
                               solar_elevation_deg=solar_elevation_deg)
    return solar_hz


def shaded_solar_hz(instrument, solar_hz: float, *, deck, cover: float, delta_time_s,
                    z_m: float, solar_elevation_deg) -> float:
    """The sunlight [Hz, before the PDE] a nadir receiver sees over a clear gap of a broken
    deck (:mod:`lidar_mitsuba.atmosphere.cloud_shade`): the air above the deck's top lit as
    in clear sky (the sky model's path radiance over a black surface at the top's height,
    seen from the same range), everything below it (the surface and the lower air, whose
    light is ``solar_hz`` less that) times the shade factor at the median sun. The surface's
    light scattered back down by the upper air is counted with the lower part (ESTIMATE: a
    few per cent of it)."""
    from .atmosphere.cloud_shade import shade_factor
    elev = np.atleast_1d(np.asarray(solar_elevation_deg, np.float64))
    factor = shade_factor(cover=float(cover), optical_depth=deck.optical_depth, g=deck.g,
                          solar_elevation_deg=float(np.nanmedian(elev)))
    if factor >= 1.0:
        return solar_hz
    from .radiometry import earth_sun_distance_au
    link = instrument.link_budget
    t = np.atleast_1d(np.asarray(delta_time_s, np.float64))
    above = link.solar_background_hz(
        wavelength_nm=instrument.wavelength_nm, fov_diameter_m=instrument.fov_diameter_m,
        range_m=instrument.altitude_m - z_m, z_m=np.full(elev.shape, z_m + deck.top_m),
        solar_elevation_deg=elev, albedo=0.0, earth_sun_au=earth_sun_distance_au(t))
    above_hz = min(float(np.median(above)), solar_hz)
    return above_hz + (solar_hz - above_hz) * factor
