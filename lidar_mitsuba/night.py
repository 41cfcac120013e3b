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
5. **the laser's own photons that the signal finder does not call high confidence**: ATL03
   takes out of each row's histogram exactly its high-confidence photons and their height
   span (:func:`removed_signal`; the real file shows it), so the pulse's tails, echoes,
   afterpulses and the snow's late photons that its finder leaves stay in the background:
   ``L`` such photons per shot add ``L c / (2 (H - w))`` (:func:`atl03_leak`, from a
   simulation's photons through our finder). Without a simulation, a signal of ``S``
   photons per shot of which a fraction ``f`` falls outside a span ``w`` adds
   ``S f c / (2 H)`` (for a Gaussian pulse ``f = erfc(w / (2 sqrt(2) sigma))``).

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

BCKGRD_SHOTS = 50
"""Shots summed into one altimetric histogram, one row of ``bckgrd_atlas`` (ATL03 ATBD; four
rows a 200-shot major frame, ``pce_mframe_cnt``, in the real files; 200 Hz at 10 kHz): our
ATL03 writer's rows too (``products/atl03/beam.py``)."""


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
                     leak_hz: float | None = None,
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
        leak_hz: the leak term itself [Hz, detected] where it was counted as ATL03 counts it
            (:func:`atl03_leak`); then ``signal_per_shot`` and ``outside_fraction`` are unused.
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
        # the part of the layer's attenuated backscatter inside the band: its share from
        # below the band's top, the light dimmed on its way into the layer from above
        in_band = cloud.backscatter_share_below(top)
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
    if leak_hz is None:
        leak_hz = _span_leak_hz(instrument, band, signal_per_shot, outside_fraction) / band_s
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


def _span_leak_hz(instrument, band: HistogramBand, signal_per_shot: float,
                  outside_fraction) -> float:
    """The leak without a simulation [detected photons per shot]: ``signal_per_shot`` times
    the median ``outside_fraction`` (default: the Gaussian pulse's outside the band's span)."""
    if outside_fraction is None:
        sigma_m = C_M_PER_NS * instrument.pulse_sigma_ns / 2.0
        outside_fraction = gaussian_outside_fraction(band.signal_span_m, sigma_m)
    return signal_per_shot * float(np.nanmedian(np.atleast_1d(outside_fraction)))


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


# ------------------------------------------------------------------------------ term 5
def removed_signal(*, row, h_m, high, n_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """What ATL03 takes out of each 50-shot row's histogram as signal: ``(count, span_m)``,
    (n_rows,) each, the number of the row's high-confidence photons and their height span [m]
    (max - min; 0 in a row without one). ``bckgrd_counts - bckgrd_counts_reduced`` and
    ``bckgrd_int_height - bckgrd_int_height_reduced`` of the shipped night subset are these,
    exactly (to float32's rounding of the 5 km heights), for the photons that are high
    confidence for any surface type, each row's photons those of its 50 pulses
    (``tests/test_realism.py::test_atl03_removes_exactly_its_high_confidence_photons_and_their_span``).

    Args:
        row: (n,) each photon's row; h_m: (n,) its height [m]; high: (n,) bool, high
            confidence; n_rows: rows."""
    count, lo, hi = removed_extremes(row=row, h_m=h_m, high=high, n_rows=n_rows)
    return count, np.where(count > 0, hi - lo, 0.0)


def removed_extremes(*, row, h_m, high, n_rows: int, ascending: bool | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rule of :func:`removed_signal` as ``(count, lo, hi)``, (n_rows,) each: the number of
    each row's high-confidence photons and their lowest and highest height [m] (``inf`` and
    ``-inf`` in a row without one), as our ATL03 writer keeps them for rows that runs share
    (``products/atl03/beam.py``). Photons in ascending rows (a track's, shot by shot:
    ``ascending=True`` says so, ``None`` looks) are reduced in place; others are sorted by row
    first (the same numbers: a min is exact)."""
    high = np.asarray(high, bool)
    at = np.asarray(row, np.int64)[high]
    h = np.asarray(h_m)[high]
    count = np.bincount(at, minlength=n_rows)
    lo, hi = np.full(n_rows, np.inf), np.full(n_rows, -np.inf)
    if at.size:
        if not ascending and (ascending is False or np.any(at[1:] < at[:-1])):
            order = np.argsort(at, kind="stable")
            at, h = at[order], h[order]
        start = np.flatnonzero(np.r_[True, at[1:] != at[:-1]])
        lo[at[start]] = np.minimum.reduceat(h, start)
        hi[at[start]] = np.maximum.reduceat(h, start)
    return count, lo, hi


@dataclass
class Leak:
    """The laser's photons ATL03 leaves in its background (:func:`atl03_leak`).

    Attributes:
        leak_hz: their rate over the band less each row's span [Hz, detected].
        signal, high, leftover: (n_rows,) each row's laser photons, its high-confidence
            photons (laser and noise) and the laser photons left in the background (those not
            high confidence, and the expected afterpulses of the laser's photons).
        span_m: (n_rows,) the span removed [m]; shots: (n_rows,) shots of each row (each
            averaged over the draws of :func:`atl03_leak`).
        keep: the share of the laser's photons kept (a cloud's transmission).
    """
    leak_hz: float
    signal: np.ndarray
    high: np.ndarray
    leftover: np.ndarray
    span_m: np.ndarray
    shots: np.ndarray
    keep: float = 1.0

    def summary(self) -> dict:
        """Plain numbers for a report: the rate, its standard error from the laser photons'
        own sampling, the left-over share of the laser's photons and the rows' median span.
        The error: the left-over count averaged over the draws is ``sum_i p_i`` over the
        simulated laser photons, ``p_i <= keep`` the chance photon ``i`` is kept and left
        over, so its Poisson variance ``sum_i p_i^2 <= keep N``: relative error at most
        ``sqrt(keep / N)``, ``N`` the averaged count (``1 / sqrt(N)`` with no cloud)."""
        n = float(self.leftover.sum())
        return {"leak_hz": self.leak_hz,
                "leak_se_hz": self.leak_hz * math.sqrt(self.keep / n) if n > 0 else 0.0,
                "leftover_photons": n, "signal_photons": int(self.signal.sum()),
                "leftover_fraction": n / max(int(self.signal.sum()), 1),
                "rows": int(self.shots.size),
                "span_median_m": float(np.median(self.span_m)) if self.span_m.size else 0.0}


def atl03_leak(*, shot, h_m, is_signal, gate_center_h_m, range_gate_m: float, n_shots: int,
               noise_hz: float, band_rate_hz: float, band_height_m: float,
               rng: np.random.Generator, keep: float = 1.0,
               afterpulse_probability: float = 0.0, realizations: int = 32,
               passes: int = 2) -> Leak:
    """Term 5 as ATL03 counts it, from a simulation's photons: its laser photons (``is_signal``;
    heights already moved by the snow's delay where it has one), each kept with probability
    ``keep`` (a cloud's two-way transmission), among noise photons drawn at ``noise_hz`` over
    each shot's range gate (the other terms' rate there, not the simulation's), through our
    signal finder (:func:`~lidar_mitsuba.products.classify.histogram_test`) with ATL03's
    rule, a photon's confidence its own bin's (``neighbourhood_bins=1``: ATL03 ATBD release
    006, section 5.1.1), and its expected background from the photon cloud (the laser's own
    tail photons in it), as ATL03's ``signal_find_output`` shows its finder taking it at night
    (the classify module's docstring), but never below the band's rate (ESTIMATE: a floor
    against an estimate of nothing from a quiet gate's few photons, ~0.02 noise photons in
    200 shots of a night's 30 m gate; how ATL03 treats a photon cloud without background was
    not found); each 50-shot row then loses its high-confidence photons and their span
    (:func:`removed_signal`) and keeps the rest. The band's rate is ``band_rate_hz`` (the
    other terms) plus the leak itself: ``passes`` rounds, the first without it. Photons
    outside the gate (the snow's deepest) are never high confidence, and count: the band
    reaches 2.5 km below the surface. Afterpulses (``afterpulse_probability`` a laser
    photon: 10-45 m below, outside any span) are added as their expected number. The
    thinning and the noise are drawn ``realizations`` times over the same laser photons and
    the rows' counts averaged (the laser photons' own sampling error remains:
    :meth:`Leak.summary`).

    Args:
        shot: (n,) each photon's shot (0 .. n_shots - 1); h_m: (n,) its height [m];
            is_signal: (n,) the laser's (the simulation's other photons are dropped).
        gate_center_h_m: (n_shots,) each shot's gate centre [m]; range_gate_m: its height [m].
        noise_hz, band_rate_hz: [Hz, detected]; band_height_m: the band ``H`` [m].
    """
    sig = np.asarray(is_signal, bool)
    photons = (np.asarray(shot, np.int64)[sig], np.asarray(h_m, np.float64)[sig])
    gate = np.asarray(gate_center_h_m, np.float64)
    rows = -(-n_shots // BCKGRD_SHOTS)
    shots = np.bincount(np.arange(n_shots) // BCKGRD_SHOTS, minlength=rows)
    draws = []
    for _ in range(max(int(realizations), 1)):
        kept = rng.random(photons[0].size) < keep if keep < 1.0 else slice(None)
        n_noise = rng.poisson(noise_hz * 2.0 * range_gate_m / C_M_PER_S, n_shots)
        n_shot = np.repeat(np.arange(n_shots), n_noise)
        n_h = gate[n_shot] + (rng.random(n_shot.size) - 0.5) * range_gate_m
        draws.append((photons[0][kept], photons[1][kept], n_shot, n_h))
    leak_hz = 0.0
    for _ in range(max(int(passes), 1)):
        acc = np.zeros((4, rows))                  # signal, high, leftover, span: summed
        for d in draws:
            acc += _rows_left(*d, gate=gate, range_gate_m=range_gate_m, rows=rows,
                              rate_hz=band_rate_hz + leak_hz,
                              afterpulse_probability=afterpulse_probability)
        signal, high, leftover, span = acc / len(draws)
        leak_hz = float(leftover.sum() / np.sum(shots * 2.0 * (band_height_m - span)
                                                / C_M_PER_S))
    return Leak(leak_hz, signal, high, leftover, span, shots, float(keep))


def _rows_left(s_shot, s_h, n_shot, n_h, *, gate, range_gate_m: float, rows: int,
               rate_hz: float, afterpulse_probability: float) -> np.ndarray:
    """(4, rows): each row's laser photons, high-confidence photons, laser photons left in
    the background and span removed [m], for one draw of :func:`atl03_leak` (laser photons
    ``s_*``, noise photons ``n_*``: shot, height [m]), the finder's noise level at least
    ``rate_hz``'s."""
    from .products.classify import histogram_test
    block_shots, bin_m = 20, 0.5                    # histogram_test's defaults (our writer's)
    inside = np.abs(s_h - gate[s_shot]) <= range_gate_m / 2.0
    t_shot = np.concatenate([s_shot[inside], n_shot])
    t_h = np.concatenate([s_h[inside], n_h])
    order = np.argsort(t_shot, kind="stable")
    # ATL03's rule (a photon's bin alone), the background from the photon cloud, at least
    # the band's rate
    test = histogram_test(shot=t_shot[order], h_m=t_h[order], gate_center_h_m=gate,
                          range_gate_m=range_gate_m, block_shots=block_shots, bin_m=bin_m,
                          neighbourhood_bins=1,
                          min_noise_per_bin=rate_hz * 2.0 * bin_m / C_M_PER_S * block_shots)
    high_t = np.empty(t_shot.size, bool)
    high_t[order] = test.conf == 4
    high_s = np.zeros(s_shot.size, bool)
    high_s[np.flatnonzero(inside)] = high_t[:int(inside.sum())]
    count, span = removed_signal(row=t_shot // BCKGRD_SHOTS, h_m=t_h, high=high_t, n_rows=rows)
    signal = np.bincount(s_shot // BCKGRD_SHOTS, minlength=rows)
    leftover = (np.bincount(s_shot[~high_s] // BCKGRD_SHOTS, minlength=rows)
                + afterpulse_probability * signal)
    return np.stack([signal, count, leftover, span])
