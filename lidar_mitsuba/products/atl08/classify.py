"""Photon classification for the ATL08-like product: noise, ground, canopy, top of canopy.

Our own algorithm in the spirit of the ATL08 ATBD (Neuenschwander & Pitts, "ATBD for
Land-Vegetation Along-Track Products (ATL08)", release 002, 2019, sec. 4: noise filtering by
DRAGANN, de-trending, iterative ground finding, a top-of-canopy upper envelope, photon
classification). Pure numpy/scipy; it works on any photon cloud given
as along-track distance and height. The steps (:func:`classify_photons`):

1. **Trend** (ATBD 4.5, "de-trend the data"): in along-track blocks of ``trend_block_m``
   (20 m, one ATL03 segment) the height bin of ``trend_bin_m`` (3 m) holding most photons,
   smoothed by a running median over ``trend_median_blocks`` (5 blocks, 100 m: one ATL08
   segment) and interpolated: a coarse surface through the signal band, so that the noise
   filter's window follows slopes.
2. **Noise filter** (DRAGANN's idea, ATBD 4.3: count each photon's neighbours in a fixed
   search area; the background's count distribution is told apart from the signal's): the
   neighbours of each photon in rectangles ``|dx| <= a``, ``|dh - dtrend| <= b`` (self
   excluded; one tall window for canopy, one flat for ground: ``Settings.windows``).
   Under background alone the count is Poisson with mean
   ``lam = rho A`` (``rho``: background photons per m along track per m of height, ``A``
   the rectangle's area); a photon is signal when ``P(N >= n | lam) < false_alarm``. DRAGANN
   fits two Gaussians to the count histogram and cuts at their crossing; we cut where the
   background's own Poisson law says a count is improbable, which needs no fit and holds
   for any background rate. ``rho`` comes from the ATL03 background rate when known
   (``rate [Hz] * 2 / c`` per m of height per shot, times shots per metre) or is estimated
   from the cloud (:func:`background_density`).
3. **Ground** (ATBD 4.6-4.10, iterative filtering of the lowest photons): the lowest photon
   passing the ground's window in each along-track bin, coarse to fine
   (``envelope_levels``: 40, 20, 10, 5 m; each level searches only near the previous
   level's surface, and a 40 m bin holds a ground photon even under a dense stand). Each
   candidate is compared with a leave-one-out Theil-Sen line through its neighbours
   (:func:`_neighbour_residuals`: an outlier cannot explain itself, a slope is no outlier);
   those beyond ``outlier_sigmas`` (3) robust spreads, measured on the side below the ground
   where no vegetation is (:func:`_outer_sigma`), are dropped (canopy minima of bins the
   ground did not return from lie above; noise that passed the filter, below) and the rest
   joined by lines (:func:`_polyline`: the ATBD's smoothing spline overshoots between close
   candidates and across gaps). The final ground
   (:func:`lidar_mitsuba.products.atl08.ground.final_ground`): the ground's centre fitted from
   its lower side (a window 3 spreads below and 1 above the surface, less a normal's
   median in it), its spread from the curvature of its lower flank, climbing from the
   pulse's (optionally, ``slope_capped_ground``, at most what the pulse and the footprint
   make of the track's slope unless the photons below the surface ask for a rougher ground);
   ground photons lie from 3 spreads below the centre to the height where the
   ground's density falls to that of the vegetation above it (1 to 3 spreads).
4. **Top of canopy** (ATBD 4.11, upper envelope): the same on the highest photon above the
   ground band in each bin, the spread measured above it. Photons above it by more than
   ``outlier_sigmas`` robust spreads are noise; canopy photons within one robust spread
   below it (or above it up to the noise cut) are top of canopy.
5. **Classes** (``classed_pc_flag``): 0 noise (filtered out, below the ground band or
   above the canopy), 1 ground, 2 canopy (between the ground band and the top-of-canopy
   band), 3 top of canopy.

Constants not from a source are marked ESTIMATE in :class:`Settings`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import spatial, stats

from ...constants import C_M_PER_NS
from .ground import final_ground

NOISE, GROUND, CANOPY, TOP_OF_CANOPY = 0, 1, 2, 3
"""ATL08 ``classed_pc_flag`` values (ATL08 data dictionary: 0 noise, 1 ground, 2 canopy,
3 top of canopy)."""
MAD_PER_SIGMA = 0.6744897501960817
"""Median absolute deviation of a normal variable per standard deviation (Phi^-1(0.75))."""


@dataclass(frozen=True)
class Settings:
    """The classifier's constants, each with its source or reasoning.

    Attributes:
        trend_block_m: along-track block of the trend [m]: one ATL03 20 m segment.
        trend_bin_m: height bin of the trend's mode [m]. ESTIMATE: a canopy's densest 3 m
            layer outnumbers a 3 m bin of background wherever ATL08 can work (the ATBD's
            signal-to-noise floor).
        trend_median_blocks: running median of the block modes (blocks): 5 x 20 m = one
            100 m ATL08 segment.
        windows: half sizes ``(along, height)`` [m] of the neighbour rectangles; a photon
            is signal when its count in any of them is improbable. Sized from the detection
            condition ``rho_s A >= z sqrt(rho_b A)``, i.e. ``A >= z^2 rho_b / rho_s^2``
            (``z`` ~3.5 for a 1e-3 tail, ``rho_b`` ~0.04 /m^2 by day: a 4 MHz background at
            1.43 shots/m). ESTIMATE, canopy: a sparse stand seen by a weak beam, 0.5 signal
            photons a shot spread over 15 m of height (``rho_s`` ~0.05 /m^2), needs
            ``A`` >~ 200 m^2: +-15 m x +-4 m (240 m^2). Ground: a return concentrated within
            +-1 m (a 10 % slope across a footprint, sigma ~0.3 m, after de-trending) at 0.15
            photons a shot under a dense stand (``rho_s`` ~0.11 /m^2) needs ``A`` >~ 45 m^2:
            +-20 m x +-1 m (80 m^2; the ground is continuous along track, so a long window
            gathers it without smearing).
        false_alarm: tail probability below which a count is signal, shared by the windows
            (each tests at ``false_alarm / len(windows)``). ESTIMATE: with ~2000 background
            photons per 100 m segment in a 500 m telemetry band by day, 1e-3 lets ~2 through
            per segment; the ground and canopy envelopes reject those.
        envelope_bin_m: along-track bin of the lower and upper envelopes [m]. ESTIMATE:
            about half a footprint, the scale over which the ground under a footprint is one.
        envelope_levels: the envelopes' bins, coarse to fine, in ``envelope_bin_m``: 40 m
            bins first (ESTIMATE: under a stand that lets 0.1 ground photons a shot through,
            a 40 m bin of ~57 shots misses the ground with probability e^-5.7 ~ 0.3 %).
        outlier_sigmas: envelope outlier cut and buffer, in robust standard deviations
            (3: the usual normal-tail cut, 0.27 % of good points).
        min_buffer_m: floor of the ground band's depth [m]: 3 x ATLAS's pulse sigma in
            height (1.5 ns FWHM -> 0.64 ns -> 0.096 m; ATLAS as flown, docs/guide/atlas.md);
            the ground's spread starts from, and never falls below, a third of it.
        max_iterations: envelope refits at most.
        slope_capped_ground: fit the ground with its spread capped at what the pulse and the
            footprint make of the track's slope, freed only where the photons below the
            surface ask for a rougher ground (:func:`~.ground.final_ground`, step 6). Off by
            default: it keeps the ground out of a dense understorey beginning within a spread
            of it (the forest clip: terrain +0.63 m from NASA's instead of +2.26 m; the
            forest-clip-like synthetic cloud +0.21 to +0.68 m over five seeds instead of
            +0.65 to +1.07 m), but its roughness test lacks power where the capped surface
            slides into a rough ground's lower flank: a bare rough ground (0.5 m spread) comes
            out 0.37-0.49 m low on four of five seeds, which the free fit gets right
            (docs/guide/atl08.md).
    """
    trend_block_m: float = 20.0
    trend_bin_m: float = 3.0
    trend_median_blocks: int = 5
    windows: tuple = ((15.0, 4.0), (20.0, 1.0))
    false_alarm: float = 1e-3
    envelope_bin_m: float = 5.0
    envelope_levels: tuple = (8, 4, 2, 1)
    outlier_sigmas: float = 3.0
    min_buffer_m: float = 0.3
    max_iterations: int = 20
    slope_capped_ground: bool = False


@dataclass
class Classification:
    """What :func:`classify_photons` found.

    Attributes:
        classes: (n,) int8 ``classed_pc_flag`` (0 noise, 1 ground, 2 canopy, 3 top of canopy).
        is_signal: (n,) bool: passed the noise filter (ATL08's ``d_flag``).
        ground_h_m: (n,) the ground surface at each photon [m] (NaN where none was found).
        toc_h_m: (n,) the top-of-canopy surface at each photon [m] (NaN where none).
        ground_buffer_m: the ground band's depth below the ground surface [m].
        background_per_m2: (n,) the background density used at each photon [1/(m m)].
        h_m: (n,) the photon heights classified [m].
        ground_top_m: (n,) the ground band's height above the ground surface [m]
            (:func:`lidar_mitsuba.products.atl08.ground.final_ground`); NaN where no ground.
        ground_sigma_m: the ground return's fitted spread [m] (0 where no ground).
    """
    classes: np.ndarray
    is_signal: np.ndarray
    ground_h_m: np.ndarray
    toc_h_m: np.ndarray
    ground_buffer_m: float
    background_per_m2: np.ndarray
    h_m: np.ndarray
    ground_top_m: np.ndarray | float = np.nan
    ground_sigma_m: float = 0.0

    @property
    def h_rel_m(self) -> np.ndarray:
        """Height above the ground surface [m] (ATL08 ``ph_h``); NaN where no ground."""
        return self.h_m - self.ground_h_m


def background_density_from_rate(rate_hz: np.ndarray, shots_per_m: float) -> np.ndarray:
    """Background photons per m along track per m of height [1/m^2] for a background count
    rate ``rate_hz`` [Hz] (ATL03 ``bckgrd_atlas/bckgrd_rate``): a photon arriving within
    ``dt`` is placed within ``c dt / 2`` of height, so ``rate * 2 / c`` per m per shot, times
    ``shots_per_m`` shots per metre of track."""
    return np.asarray(rate_hz, np.float64) * 2.0 / (C_M_PER_NS * 1e9) * shots_per_m


def background_density(x_m: np.ndarray, h_m: np.ndarray, *, block_m: float = 100.0,
                       bin_m: float = 5.0) -> np.ndarray:
    """(n,) background density [1/(m m)] at each photon, from the cloud itself: in each
    along-track block of ``block_m``, heights in ``bin_m`` bins over the block's span; the
    background's mean count per bin is the mean of the bins, iteratively leaving out those
    above ``mean + 3 sqrt(mean)`` (a Poisson 3-sigma clip: the signal's bins). It needs a
    height span mostly of background (a real telemetry band of ~100s of m); a narrow range
    gate filled by canopy overestimates it, so pass the rate when known."""
    x, h = np.asarray(x_m, np.float64), np.asarray(h_m, np.float64)
    out = np.zeros(x.size)
    if x.size == 0:
        return out
    block = np.floor((x - x.min()) / block_m).astype(np.int64)
    for b in np.unique(block):
        m = block == b
        hb = h[m]
        edges = np.arange(hb.min(), hb.max() + bin_m, bin_m)
        counts = np.histogram(hb, edges)[0].astype(np.float64) if edges.size > 1 else \
            np.array([float(hb.size)])
        keep = np.ones(counts.size, bool)
        for _ in range(20):
            mean = counts[keep].mean()
            new = counts <= mean + 3.0 * np.sqrt(max(mean, 1.0))
            if np.array_equal(new, keep) or not new.any():
                break
            keep = new
        span = max(float(np.ptp(x[m])), 1.0) if block_m > np.ptp(x[m]) else block_m
        out[m] = counts[keep].mean() / (bin_m * span)
    return out


def trend_surface(x_m: np.ndarray, h_m: np.ndarray, s: Settings) -> np.ndarray:
    """(n,) coarse surface through the signal band at each photon [m] (step 1)."""
    x, h = np.asarray(x_m, np.float64), np.asarray(h_m, np.float64)
    if x.size == 0:
        return np.zeros(0)
    block = np.floor((x - x.min()) / s.trend_block_m).astype(np.int64)
    ids = np.unique(block)
    centres, modes = np.empty(ids.size), np.empty(ids.size)
    for i, b in enumerate(ids):
        m = block == b
        hb = h[m]
        edges = np.arange(hb.min(), hb.max() + s.trend_bin_m, s.trend_bin_m)
        if edges.size < 2:
            modes[i] = hb.mean()
        else:
            counts = np.histogram(hb, edges)[0]
            k = int(np.argmax(counts))
            modes[i] = 0.5 * (edges[k] + edges[k + 1])
        centres[i] = x[m].mean()
    half = s.trend_median_blocks // 2
    smooth = np.array([np.median(modes[max(0, i - half):i + half + 1])
                       for i in range(ids.size)])
    return np.interp(x, centres, smooth)


def neighbour_counts(x_m: np.ndarray, dh_m: np.ndarray, *, along_m: float,
                     height_m: float) -> np.ndarray:
    """(n,) photons within ``|dx| <= along_m``, ``|ddh| <= height_m`` of each photon, itself
    excluded (a k-d tree in coordinates scaled to a square, Chebyshev distance)."""
    if np.size(x_m) == 0:
        return np.zeros(0, np.int64)
    pts = np.column_stack([np.asarray(x_m, np.float64) / along_m,
                           np.asarray(dh_m, np.float64) / height_m])
    tree = spatial.cKDTree(pts)
    n = tree.query_ball_point(pts, r=1.0, p=np.inf, return_length=True)
    return np.asarray(n, np.int64) - 1


def noise_filter(x_m: np.ndarray, h_m: np.ndarray, background_per_m2: np.ndarray,
                 s: Settings) -> np.ndarray:
    """(len(s.windows), n) bool: for each window of ``s.windows``, the photons whose
    neighbour count in it is improbable under background alone (step 2); a photon is
    signal when any row says so."""
    x, h = np.asarray(x_m, np.float64), np.asarray(h_m, np.float64)
    keep = np.zeros((len(s.windows), x.size), bool)
    if x.size == 0:
        return keep
    dh = h - trend_surface(x, h, s)
    rho = np.asarray(background_per_m2, np.float64)
    alpha = s.false_alarm / len(s.windows)
    for i, (along, height) in enumerate(s.windows):
        n = neighbour_counts(x, dh, along_m=along, height_m=height)
        keep[i] = stats.poisson.sf(n - 1, rho * (4.0 * along * height)) < alpha   # P(N >= n)
    return keep


def expected_passing(background_per_m2: np.ndarray, s: Settings, *, height_m: float) -> int:
    """Background photons expected beyond a surface in one envelope bin that the noise
    filter lets through: those within ``height_m`` (the window's half height: their window
    reaches the signal) of it, ``rho * envelope_bin_m * height_m``, rounded (median
    ``rho``)."""
    rho = float(np.median(background_per_m2)) if np.size(background_per_m2) else 0.0
    return int(round(rho * s.envelope_bin_m * height_m))


def _polyline(x: np.ndarray, h: np.ndarray):
    """Linear interpolation through ``(x, h)`` (``x`` increasing), continued beyond the end
    points along the slope of the last few (:func:`_end_slope`); a callable. A smoothing
    spline (the ATBD's) overshoots by tens of metres between close points of different
    heights (two bins' extremes at a shared edge) and across the gaps a dense canopy
    leaves; the candidates are already bin extremes or bin medians, so the line between
    them is the smoothing."""
    if x.size == 0:
        return lambda t: np.full(np.shape(t), np.nan)
    if x.size == 1:
        return lambda t: np.full(np.shape(t), float(h[0]))
    s0, s1 = _end_slope(x[:4], h[:4]), _end_slope(x[-4:], h[-4:])

    def f(t):
        t = np.asarray(t, np.float64)
        return np.interp(t, x, h) + np.where(t < x[0], s0 * (t - x[0]), 0.0) + \
            np.where(t > x[-1], s1 * (t - x[-1]), 0.0)
    return f


def _end_slope(x: np.ndarray, h: np.ndarray) -> float:
    """The median of the pairwise slopes of a few end points (Theil-Sen)."""
    a, b = np.triu_indices(x.size, 1)
    dx = x[b] - x[a]
    ok = dx != 0
    return float(np.median((h[b] - h[a])[ok] / dx[ok])) if ok.any() else 0.0


def envelope(x_m: np.ndarray, h_m: np.ndarray, s: Settings, *, upper: bool, skip: int = 0):
    """The lower (``upper=False``) or upper envelope of a photon cloud (steps 3-4), coarse to
    fine: at each bin size of ``envelope_levels`` (times ``envelope_bin_m``) the ``skip +
    1``-th most extreme photon of each bin (``skip``: the background photons expected to
    pass the noise filter beyond the surface in one bin, :func:`expected_passing`), among
    the photons within the previous level's cut of its surface; candidates beyond
    ``outlier_sigmas`` robust spreads of their neighbours' line are dropped and the rest
    joined (:func:`_envelope_level`). A coarse bin almost surely holds a ground photon even
    under a dense canopy, and its surface keeps the finer levels' canopy-only bins out.
    Returns ``(surface callable or None, robust sigma [m], the kept candidates'
    residuals)``."""
    x, h = np.asarray(x_m, np.float64), np.asarray(h_m, np.float64)
    if x.size == 0:
        return None, 0.0, np.zeros(0)
    f, sigma, r = None, 0.0, np.zeros(0)
    for level in s.envelope_levels:
        near = np.ones(x.size, bool) if f is None else \
            np.abs(h - f(x)) <= s.outlier_sigmas * sigma
        if near.sum() < 2:
            break
        g = _envelope_level(x[near], h[near], s, upper=upper, skip=skip,
                            bin_m=level * s.envelope_bin_m)
        if g[0] is None:
            break
        f, sigma, r = g
    return f, sigma, r


def _neighbour_residuals(x: np.ndarray, h: np.ndarray, *, half: int = 3) -> np.ndarray:
    """(n,) each point's height less a Theil-Sen line (the median of the pairwise slopes,
    the median intercept; robust to ~29 % outliers) through its up to ``half`` neighbours
    either side, evaluated at its position: leave-one-out, so a point never explains
    itself, and a line, so a slope is no outlier. Zero for fewer than 3 points."""
    n = x.size
    r = np.zeros(n)
    if n < 3:
        return r
    # the points with ``half`` neighbours either side and distinct neighbour positions, all
    # at once (the same medians of the same numbers: ~100x faster than one by one)
    inner = np.arange(half, n - half)
    offs = np.r_[-half:0, 1:half + 1]
    a, b = np.triu_indices(offs.size, 1)
    xj, hj = x[inner[:, None] + offs], h[inner[:, None] + offs]
    dx = xj[:, b] - xj[:, a]
    whole = (dx != 0).all(axis=1)
    if whole.any():
        k, xw, hw = inner[whole], xj[whole], hj[whole]
        slope = np.median((hw[:, b] - hw[:, a]) / dx[whole], axis=1)
        r[k] = h[k] - np.median(hw - slope[:, None] * (xw - x[k, None]), axis=1)
    done = np.zeros(n, bool)
    done[inner[whole]] = True
    for i in np.flatnonzero(~done):               # the ends, and repeated positions
        j = np.r_[max(0, i - half):i, i + 1:min(n, i + half + 1)]
        xj, hj = x[j], h[j]
        a, b = np.triu_indices(j.size, 1)
        dx = xj[b] - xj[a]
        ok = dx != 0
        slope = float(np.median((hj[b] - hj[a])[ok] / dx[ok])) if ok.any() else 0.0
        r[i] = h[i] - (np.median(hj - slope * (xj - x[i])))
    return r


def _envelope_level(x, h, s: Settings, *, upper: bool, skip: int, bin_m: float):
    """One level of :func:`envelope`: bins of ``bin_m`` [m]."""
    b = np.floor((x - x.min()) / bin_m).astype(np.int64)
    order = np.lexsort((-h if upper else h, b))       # per bin, the extreme first
    bo = b[order]
    start = np.r_[True, bo[1:] != bo[:-1]]
    run_start = np.maximum.accumulate(np.where(start, np.arange(bo.size), 0))
    rank = np.arange(bo.size) - run_start
    run_len = np.bincount(bo - bo.min())[bo - bo.min()]
    pick = order[rank == np.minimum(skip, run_len - 1)]
    pick = pick[np.argsort(x[pick], kind="stable")]
    xc, hc = x[pick], h[pick]
    keep = np.r_[True, np.diff(xc) > 0]               # strictly increasing for the line
    xc, hc = xc[keep], hc[keep]
    if xc.size == 0:
        return None, 0.0, np.zeros(0)
    # each candidate against what its neighbours say (:func:`_neighbour_residuals`): a
    # lone outlier (a canopy bin's minimum, a noise photon) cannot hide, on any slope, and
    # the candidates' scatter measures the surface's; the kept candidates, joined
    floor = s.min_buffer_m / s.outlier_sigmas
    r = _neighbour_residuals(xc, hc)
    sigma = max(_outer_sigma(r, upper=upper), floor)
    good = np.abs(r) <= s.outlier_sigmas * sigma
    if good.sum() < 2:
        good[:] = True
    return _polyline(xc[good], hc[good]), sigma, r[good]


def _outer_sigma(r: np.ndarray, *, upper: bool, strict: bool = True) -> float:
    """Robust spread of an envelope's candidates from its outer side only: the residuals
    below a lower envelope (above an upper one) are the surface's own scatter, while the
    inner side holds what the surface did not return in a bin (canopy over the ground,
    ground through a gap under the canopy top). For a normal scatter, 1.4826 x the median
    of ``|r|`` over the outer half is sigma; an envelope fitted above the ground sees the
    ground as outer residuals, so the cut tightens until the fit comes down to it."""
    if strict:               # about bin medians: the medians' own zero residuals left out
        outer = r[r > 0] if upper else -r[r < 0]
    else:                    # about a running median, which fits some candidates exactly
        outer = r[r >= 0] if upper else -r[r <= 0]
    if outer.size == 0:
        return 0.0
    return float(np.median(outer) / MAD_PER_SIGMA)


def classify_photons(*, x_m: np.ndarray, h_m: np.ndarray,
                     background_per_m2: np.ndarray | float | None = None,
                     settings: Settings | None = None) -> Classification:
    """Classify a photon cloud (module docstring).

    Args:
        x_m: (n,) along-track distance of each photon [m] (any origin).
        h_m: (n,) photon height [m].
        background_per_m2: background photons per m along track per m of height [1/(m m)],
            scalar or (n,) (:func:`background_density_from_rate`); ``None``: estimated from
            the cloud (:func:`background_density`).
        settings: the constants (default :class:`Settings`).
    """
    s = settings or Settings()
    x, h = np.asarray(x_m, np.float64), np.asarray(h_m, np.float64)
    if x.shape != h.shape or x.ndim != 1:
        raise ValueError("x_m and h_m must be 1-D arrays of the same shape")
    rho = (background_density(x, h) if background_per_m2 is None
           else np.broadcast_to(np.asarray(background_per_m2, np.float64), x.shape).copy())
    passed = noise_filter(x, h, rho, s)
    sig = passed.any(axis=0)
    flat = passed[int(np.argmin([w[1] for w in s.windows]))]      # the ground's window
    classes = np.zeros(x.size, np.int8)
    ground = np.full(x.size, np.nan)
    toc = np.full(x.size, np.nan)
    out = Classification(classes, sig, ground, toc, 0.0, rho, h)
    flat_h = min(w[1] for w in s.windows)
    gf, g_sigma, _ = envelope(x[flat], h[flat], s, upper=False,
                              skip=expected_passing(rho, s, height_m=flat_h))
    if gf is None:
        return out
    fit = final_ground(x, h, sig, gf(x), None, min_sigma_m=s.min_buffer_m / s.outlier_sigmas,
                       min_bin_m=s.envelope_bin_m,
                       max_bin_m=s.envelope_bin_m * max(s.envelope_levels), depth0_m=flat_h,
                       background_per_m2=float(np.median(rho)),
                       spread_cap=s.slope_capped_ground)
    ground[:] = fit.surface_m
    out.ground_buffer_m = fit.lower_m
    out.ground_top_m = fit.upper_m
    out.ground_sigma_m = fit.sigma_m
    dz = h - ground
    is_ground = sig & (dz >= -fit.lower_m) & (dz <= fit.upper_m)
    classes[is_ground] = GROUND
    above = sig & (dz > fit.upper_m)
    tf, t_sigma, _ = envelope(x[above], h[above], s, upper=True)
    if tf is None:
        return out
    toc[:] = np.maximum(tf(x), ground + fit.upper_m)
    dt = h - toc
    canopy = above & (dt <= s.outlier_sigmas * t_sigma)
    classes[canopy] = CANOPY
    classes[canopy & (dt >= -t_sigma)] = TOP_OF_CANOPY
    return out
