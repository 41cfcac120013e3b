"""The final ground surface and ground band of the ATL08-like classifier: the ground's centre
found from its lower side, so that vegetation just above the ground cannot pull it up.

The lower envelope (:func:`lidar_mitsuba.products.atl08.classify.envelope`) follows the lowest
photon of each along-track bin: it lies below the ground's centre (a bin's minimum), or, where a
bin returned no ground photon, on the lowest vegetation. The ATL08 ATBD (Neuenschwander & Pitts,
release 002, 2019, secs. 4.8-4.10) refines such a first surface iteratively: photons far above
the fitted surface are dropped, the surface refitted, the threshold shrunk. Refitting through
the median of *all* photons within a symmetric band fails under dense low vegetation: where the
vegetation starting half a metre above the ground holds more photons per metre of height than
the ground's return (the forest clip, docs/guide/atl08.md), the band's median climbs into the
vegetation, the band widens with it, and the ground is lost in the understorey.

Here the ground's return is taken as what the instrument makes it: heights normal about the
surface with spread ``sigma`` (the pulse, 0.1 m for ATLAS, widened by slope and roughness over
the footprint), and vegetation only *above* it. So:

1. **Fit window, asymmetric**: from :data:`LOWER_SIGMAS` spreads below the current surface
   up to the ground band's top (step 5): over bare ground 3 spreads (a symmetric window,
   whose median is the centre whatever the return's shape), under a dense understorey down
   to one (:data:`UPPER_SIGMAS`), which vegetation beginning more than a spread above the
   ground does not reach.
2. **Surface**: the first surface smoothed at the fit's bin (along-track bins holding
   ~:data:`GROUND_PER_BIN` ground photons), plus, in each bin, the median residual in the
   window less the median a normal variable has in that window
   (:func:`truncated_normal_median`: ``-0.199 sigma`` for ``[-3, 1] sigma``, 0 for
   ``[-3, 3]``), joined by lines:
   its fixed point is the ground's centre, whatever lies above the window.
3. **Spread** from the curvature of the ground's lower flank (:func:`_flank_fit`): a Poisson
   maximum-likelihood fit of a normal plus the known background to the histogram of the
   residuals, each measured against the surface drawn without the photon's own bin (a bin's
   median is one of its few photons: residuals from it would shrink the spread); the
   curvature does not depend on where the surface sits, as the median depth below it would.
   Floored at the pulse's spread, it may change by at most :data:`SIGMA_STEP` a refit: it
   climbs from the pulse's, the centre refitted at each step, and stops at the first spread
   the flank agrees with.
4. Repeat until the spread moves by less than 2 % and the surface by less than 5 % of
   ``sigma`` (a bin's median can hop between neighbouring photons for ever), or
   :data:`MAX_ITERATIONS` times.
5. **Ground band**: from ``LOWER_SIGMAS sigma`` below the surface to ``u`` above, where ``u``
   is where the ground's own height density ``G / (sigma sqrt(2 pi)) exp(-u^2 / 2 sigma^2)``
   (``G`` ground photons per metre of track) falls to the density of what lies just above the
   ground (vegetation and background, photons per metre of track per metre of height, measured
   in :data:`VEGETATION_PROBE_M` above the band): the equal-odds (Bayes) boundary between a
   ground photon and a canopy one, bounded to ``[UPPER_SIGMAS, LOWER_SIGMAS] sigma``. Over bare
   ground it reaches the 3-sigma band; under a dense understorey it closes to one spread.
6. **Optionally** (``spread_cap``; the classifier's ``Settings.slope_capped_ground``, off
   by default): **the spread the instrument gives, roughness where the flank demands it**
   (session 20).
   Steps 1-4 let the spread grow to whatever the flank fit asks. Under vegetation beginning
   within a spread of the ground and denser per metre of height than the ground's return
   (a weak beam by day under a young stand: the forest clip), that fixed point is unstable:
   a surface a little high lets the vegetation's base into the window, the flank fit reads
   it as a wider ground, the window widens and the surface climbs into the vegetation
   (docs/guide/atl08.md). So the fit runs first with the spread capped at what the
   instrument makes of a smooth ground on the track's slope (:func:`slope_spread`: the pulse
   and the footprint over the slope, ``sigma^2 = sigma_pulse^2 + (s sigma_fp)^2``, the term
   ATL08's own ``sigma_topo`` reports); then the residuals *below* that surface, where no
   vegetation is, are tested for a wider ground (:func:`lower_flank_gain`: a half-normal
   about the surface, its spread free against the cap, over the known background); only
   where the likelihood ratio passes :data:`ROUGHNESS_GAIN` (a 3-sigma test) is the fit run
   again with the spread free (steps 1-4 as before: a rough ground). The test lacks power
   where the capped fit slides into a rough ground's lower flank (the capped spread makes the
   ground's own upper half look like vegetation above the band, the band's top closes to one
   spread and the surface sinks): on a bare 0.5 m rough ground it misses four seeds of five.
   Hence off by default.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

LOWER_SIGMAS = 3.0
"""Fit window and ground band below the surface, in ground spreads: the usual 3-sigma tail
(0.13 % of ground photons beyond it); below the ground there is only background."""
UPPER_SIGMAS = 1.0
"""The least top of the fit window and of the ground band above the surface, in ground
spreads (under a dense understorey). ESTIMATE: the window holds 84 % of the
ground's return, while vegetation must begin within one spread (0.1-0.5 m) of the ground to
enter. Narrower (0.5) keeps more of a dense understorey out of a 0.4 m ground's fit but leaves
the flank too short to measure a rough ground's spread (on the synthetic clouds of
tests/test_atl08.py a 0.5 m ground's centre came out 0.37 m low)."""
GROUND_PER_BIN = 9.0
"""Ground photons wanted per along-track bin of the fit. ESTIMATE: the median of n normal
photons scatters by ~1.25 sigma / sqrt(n), 0.42 sigma for 9; bins stay between the envelope's
finest and coarsest (5-40 m)."""
VEGETATION_PROBE_M = 2.0
"""Height above the 3-sigma ground band over which the density of what lies above the ground is
measured for the band's upper edge [m]. ESTIMATE: the lowest two metres, where an understorey
begins; taller, a sparse canopy's crowns would dilute it."""
SIGMA_STEP = 1.25
"""Most the spread may grow (or shrink) by from one refit to the next. ESTIMATE: it starts at
the pulse's and climbs to the ground's, the centre refitted at each step, so that it stops at
the first spread the lower flank agrees with; unbounded, one refit from a surface still off
the centre can jump past it into the vegetation (measured on the synthetic clouds of
tests/test_atl08.py: a rough 0.5 m ground's centre 0.11 m low without the bound, 0.01 m with)."""
ATLAS_FOOTPRINT_SIGMA_M = 10.9 / 4.0
"""Standard deviation of ATLAS's Gaussian footprint on the ground [m]: a quarter of its
10.9 m 1/e^2 diameter (Magruder et al. 2021, Earth and Space Science,
doi:10.1029/2020EA001414; :data:`lidar_mitsuba.instrument.ATLAS`). A slope ``s`` across it
spreads a smooth ground's heights by ``s`` times this."""
ROUGHNESS_GAIN = 4.5
"""Log-likelihood gain (half the likelihood-ratio statistic) of a free spread over the capped
one on the ground's lower flank above which the ground is taken as rougher than the slope
makes it: 2 x 4.5 = 9, the chi-square (1 degree of freedom) of a 3-sigma test, the cut used
throughout this classifier (the noise filter's and the envelopes' 3-sigma tails)."""
MAX_ITERATIONS = 25
"""Refits at most: the spread climbs from the pulse's 0.1 m to a rough ground's 0.5 m in
ln 5 / ln 1.25 ~ 7 refits, and the surface, starting on the lower envelope (within a spread or
two of the centre), moves by up to ~1.2 spreads a refit."""


def truncated_normal_median(lo: float, hi):
    """Median of a standard normal variable restricted to ``[-lo, hi]`` [standard deviations]
    (``hi`` scalar or array)."""
    a, b = stats.norm.cdf(-lo), stats.norm.cdf(hi)
    return stats.norm.ppf(0.5 * (a + b))


@dataclass
class GroundFit:
    """The final ground (:func:`final_ground`).

    Attributes:
        surface_m: (n,) the ground's centre at each photon [m].
        sigma_m: the ground return's spread (one standard deviation) [m].
        lower_m: the ground band's depth below the surface [m] (``LOWER_SIGMAS sigma``).
        upper_m: (n,) the ground band's height above the surface at each photon [m].
        bin_m: the along-track bin of the fit [m].
        slope_sigma_m: the spread a smooth ground on the track's slope gives
            (:func:`slope_spread`) [m], the first fit's cap.
        rough: whether the lower flank asked for a wider spread (step 6) and the fit ran
            with the spread free.
    """
    surface_m: np.ndarray
    sigma_m: float
    lower_m: float
    upper_m: np.ndarray
    bin_m: float
    slope_sigma_m: float = 0.0
    rough: bool = False


def _bins(x: np.ndarray, bin_m: float, x0: float) -> np.ndarray:
    return np.floor((x - x0) / bin_m).astype(np.int64)


def _group_medians(b: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The median of ``v`` in each group of ``b`` (sorted group ids, the groups present)."""
    order = np.lexsort((v, b))
    bs, vs = b[order], v[order]
    start = np.flatnonzero(np.r_[True, bs[1:] != bs[:-1]])
    count = np.diff(np.r_[start, bs.size])
    return 0.5 * (vs[start + (count - 1) // 2] + vs[start + count // 2])


def _bin_medians(x: np.ndarray, v: np.ndarray, bin_m: float, x0: float):
    """``(ids, x_med, v_med)``: the bins of ``bin_m`` [m] holding points, each's median ``x``
    and median ``v``."""
    b = _bins(x, bin_m, x0)
    return np.unique(b), _group_medians(b, x), _group_medians(b, v)


def _line(xm: np.ndarray, vm: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Lines through ``(xm, vm)`` (held flat beyond the ends) at ``at``."""
    keep = np.r_[True, np.diff(xm) > 0]
    return np.interp(at, xm[keep], vm[keep])


def _line_without_own_bin(ids, xm, vm, at, bin_m: float, x0: float) -> np.ndarray:
    """The line of :func:`_line` at each of ``at`` drawn through the bins either side of the
    point's own bin only (leave-one-bin-out): a point's residual from it measures the
    ground's scatter, where a surface drawn through the point's own bin would shrink it
    (with few photons a bin, the median is one of them)."""
    b = _bins(at, bin_m, x0)
    k = np.searchsorted(ids, b)
    own = (k < ids.size) & (ids[np.minimum(k, ids.size - 1)] == b)
    left, right = k - 1, np.where(own, k + 1, k)
    lo_ok, hi_ok = left >= 0, right < ids.size
    li, ri = np.clip(left, 0, ids.size - 1), np.clip(right, 0, ids.size - 1)
    xl, xr, vl, vr = xm[li], xm[ri], vm[li], vm[ri]
    w = np.where(lo_ok & hi_ok & (xr > xl), (at - xl) / np.where(xr > xl, xr - xl, 1.0), 0.0)
    both = vl + w * (vr - vl)
    return np.where(lo_ok & hi_ok, both, np.where(lo_ok, vl, vr))


def final_ground(x: np.ndarray, h: np.ndarray, sig: np.ndarray, start_m: np.ndarray,
                 sigma0_m: float | None, *, min_sigma_m: float, min_bin_m: float,
                 max_bin_m: float, depth0_m: float, background_per_m2: float = 0.0,
                 footprint_sigma_m: float = ATLAS_FOOTPRINT_SIGMA_M,
                 spread_cap: bool = False) -> GroundFit:
    """The ground's centre, spread and band (module docstring): steps 1-5 with the spread
    free; with ``spread_cap`` (step 6), the fit with the spread capped at
    :func:`slope_spread`, then, where its lower flank asks for more (:func:`lower_flank_gain`
    above :data:`ROUGHNESS_GAIN`), with the spread free. Arguments as :func:`_refit`'s;
    ``footprint_sigma_m``: the footprint's standard deviation [m] (default ATLAS's)."""
    kw = dict(min_sigma_m=min_sigma_m, min_bin_m=min_bin_m, max_bin_m=max_bin_m,
              depth0_m=depth0_m, background_per_m2=background_per_m2)
    cap = slope_spread(x, start_m, sig, pulse_sigma_m=min_sigma_m,
                       footprint_sigma_m=footprint_sigma_m)
    if not spread_cap:
        fit = _refit(x, h, sig, start_m, sigma0_m, cap_m=np.inf, **kw)
        fit.slope_sigma_m = cap
        return fit
    fit = _refit(x, h, sig, start_m, sigma0_m, cap_m=cap, **kw)
    fit.slope_sigma_m = cap
    span = max(float(np.ptp(x[sig])) if sig.any() else 0.0, min_bin_m)
    gain = lower_flank_gain((h - fit.surface_m)[sig], sigma_m=fit.sigma_m,
                            background_per_m=background_per_m2 * span)
    if gain > ROUGHNESS_GAIN:
        fit = _refit(x, h, sig, start_m, sigma0_m, cap_m=np.inf, **kw)
        fit.slope_sigma_m, fit.rough = cap, True
    return fit


def slope_spread(x: np.ndarray, start_m: np.ndarray, sig: np.ndarray, *, pulse_sigma_m: float,
                 footprint_sigma_m: float, bin_m: float = 40.0) -> float:
    """The spread [m] of a smooth ground's return on the track's slope:
    ``sqrt(pulse^2 + (s footprint_sigma)^2)``, ``s`` the median absolute slope of the first
    surface ``start_m`` (the lower envelope) between the medians of its ``bin_m`` along-track
    bins (the envelope's coarsest level: the slope over a few footprints, not the scatter of
    single photons). A Gaussian footprint of standard deviation ``w`` on a plane of slope
    ``s`` spreads the heights it sees by ``s w`` (ATL08's ``sigma_topo`` is this term)."""
    if not np.any(sig):
        return float(pulse_sigma_m)
    x0 = float(np.min(x[sig]))
    ids, xm, hm = _bin_medians(x[sig], np.asarray(start_m, np.float64)[sig], bin_m, x0)
    ok = np.diff(xm) > 0
    s = float(np.median(np.abs(np.diff(hm)[ok] / np.diff(xm)[ok]))) if ok.sum() >= 1 else 0.0
    return float(np.hypot(pulse_sigma_m, s * footprint_sigma_m))


def lower_flank_gain(r: np.ndarray, *, sigma_m: float, background_per_m: float) -> float:
    """How much a wider ground explains the residuals ``r`` [m] below the surface better than
    spread ``sigma_m``: on ``[-(LOWER_SIGMAS + 1) sigma, 0]`` in quarter-spread bins, the
    Poisson log-likelihood of the known background (``background_per_m`` photons per metre of
    height over the track) plus a half-normal about 0 (amplitude profiled out) with its spread
    free (at least ``sigma_m``), less that with ``sigma_m``. Below the surface there is no
    vegetation: only the ground's lower half and background."""
    from scipy import optimize, special
    width = max(sigma_m / 4.0, 0.01)
    edges = -width * np.arange(int(round(4 * (LOWER_SIGMAS + 1))), -1, -1)
    counts = np.histogram(r, edges)[0].astype(np.float64)
    if counts.sum() < 5:
        return 0.0
    b = background_per_m * width

    def profiled(log_s: float) -> float:
        shape = np.diff(special.ndtr(edges * np.exp(-log_s)))

        def nll(log_a):
            lam = b + np.exp(log_a) * shape + 1e-12
            return float(np.sum(lam - counts * np.log(lam)))
        return float(optimize.minimize_scalar(nll, bounds=(-10.0, 20.0), method="bounded").fun)
    at_cap = profiled(np.log(sigma_m))
    free = optimize.minimize_scalar(profiled, bounds=(np.log(sigma_m), np.log(sigma_m) + 3.0),
                                    method="bounded")
    return float(at_cap - min(free.fun, at_cap))


def _refit(x: np.ndarray, h: np.ndarray, sig: np.ndarray, start_m: np.ndarray,
           sigma0_m: float | None, *, cap_m: float, min_sigma_m: float, min_bin_m: float,
           max_bin_m: float, depth0_m: float, background_per_m2: float = 0.0) -> GroundFit:
    """Steps 1-5 of the module docstring, the spread at most ``cap_m`` [m].

    Args:
        x, h: (n,) along-track distance [m] and height [m] of every photon.
        sig: (n,) bool, the photons that passed the noise filter.
        start_m: (n,) the first surface at each photon (the lower envelope) [m].
        sigma0_m: first guess of the ground's spread [m]; None: ``min_sigma_m`` (the spread
            then climbs from the pulse's, :data:`SIGMA_STEP`).
        min_sigma_m: the spread's floor [m] (the pulse's, in height).
        min_bin_m, max_bin_m: bounds of the fit's along-track bin [m].
        depth0_m: the least depth below the centre over which the flank is fitted [m] (a
            range that does not shrink with the spread).
        background_per_m2: the background density [1/(m m)], the flank fit's known floor.

    The spread, measured from residuals against the surface drawn without each photon's
    own bin, carries that surface's error: the median of ``n`` photons a bin scatters by
    ``1.25 sigma / sqrt(n)``, and a line between two bins' medians has on average 2/3 of
    that variance, so ``sigma^2 (1 + (pi/2)(2/3)/n)`` is measured and divided out.
    """
    start = np.asarray(start_m, np.float64)
    g = start.copy()
    sigma = min_sigma_m if sigma0_m is None else max(float(sigma0_m), min_sigma_m)
    mass = stats.norm.cdf(UPPER_SIGMAS) - stats.norm.cdf(-LOWER_SIGMAS)
    span = max(float(np.ptp(x[sig])) if sig.any() else 0.0, min_bin_m)
    x0 = float(x.min()) if x.size else 0.0
    bin_m = max_bin_m
    for _ in range(MAX_ITERATIONS):
        r = h - g
        # the window's top: the ground band's (the equal-odds height, 1 to 3 spreads)
        top = _upper_edge(x, r, sig, sigma, bin_m, x0)
        keep = sig & (r >= -LOWER_SIGMAS * sigma) & (r <= top)
        if keep.sum() < 2:
            break
        m0 = truncated_normal_median(LOWER_SIGMAS, top / sigma)
        per_m = keep.sum() / mass / span                  # ground photons per metre
        bin_m = float(np.clip(GROUND_PER_BIN / per_m, min_bin_m, max_bin_m))
        # the first surface smoothed at this bin (the lower envelope passes through single
        # photons), the window's median offset from it in each bin, less a normal's
        ref = _line(*_bin_medians(x[sig], start[sig], bin_m, x0)[1:], x)
        ids, xm, vm = _bin_medians(x[keep], (h - ref - m0 * sigma)[keep], bin_m, x0)
        g_new = ref + _line(xm, vm, x)
        corr = g_new - g
        # the spread from residuals against the surface drawn without the photon's own bin
        r = h - ref - (_line_without_own_bin(ids, xm, vm, x, bin_m, x0) if ids.size > 2
                       else _line(xm, vm, x))
        g = g_new
        n_bin = keep.sum() / max(ids.size, 1)
        fitted = _flank_fit(r[sig], sigma_m=sigma, depth0_m=depth0_m,
                            background_per_m=background_per_m2 * span)
        new = max(fitted / np.sqrt(1.0 + np.pi / 2 * (2.0 / 3.0) / n_bin), min_sigma_m)
        new = float(min(np.clip(new, sigma / SIGMA_STEP, sigma * SIGMA_STEP),
                        max(cap_m, min_sigma_m)))
        settled = abs(new - sigma) < 0.02 * sigma
        sigma = new
        if settled and np.max(np.abs(corr[sig])) < 0.05 * sigma:
            break
    upper = _upper_edge(x, h - g, sig, sigma, bin_m, x0)
    return GroundFit(g, sigma, LOWER_SIGMAS * sigma, upper, bin_m)


def _flank_fit(r: np.ndarray, *, sigma_m: float, depth0_m: float,
               background_per_m: float) -> float:
    """The ground's spread [m] from the curvature of its lower flank: a Poisson
    maximum-likelihood fit of ``b + A N(mu, sigma)`` (``b``: the background, photons per metre
    of height over the track, known) to the histogram of the residuals ``r`` [m] from
    ``max(LOWER_SIGMAS + 1, depth0/sigma_m)`` spreads below the surface to
    :data:`UPPER_SIGMAS` above it, in bins of a quarter spread. The curvature of the log
    density does not depend on where the surface sits (the median depth below it would)."""
    from scipy import optimize, special
    lo = -max((LOWER_SIGMAS + 1.0) * sigma_m, depth0_m)
    width = max(sigma_m / 4.0, 0.01)
    edges = np.arange(lo, UPPER_SIGMAS * sigma_m + 0.5 * width, width)
    counts = np.histogram(r, edges)[0].astype(np.float64)
    if counts.sum() < 5 or edges.size < 4:
        return sigma_m
    b = background_per_m * width

    def nll(p):
        lam = b + np.exp(p[2]) * np.diff(special.ndtr((edges - p[0]) * np.exp(-p[1]))) + 1e-12
        return float(np.sum(lam - counts * np.log(lam)))
    p0 = [0.0, np.log(sigma_m), np.log(counts.sum() * 1.2)]
    res = optimize.minimize(nll, p0, method="Nelder-Mead",
                            options={"xatol": 1e-3, "fatol": 1e-3, "maxiter": 300})
    return float(np.exp(res.x[1]))


def _upper_edge(x: np.ndarray, r: np.ndarray, sig: np.ndarray, sigma: float, bin_m: float,
                x0: float) -> np.ndarray:
    """(n,) the ground band's upper edge above the surface [m] at each photon: the equal-odds
    height (module docstring, step 5) in each fit bin, joined by lines."""
    b = _bins(x, bin_m, x0)
    nb = int(b.max()) + 1 if b.size else 0
    below = sig & (r < 0) & (r >= -LOWER_SIGMAS * sigma)
    probe = sig & (r > LOWER_SIGMAS * sigma) & (r <= LOWER_SIGMAS * sigma + VEGETATION_PROBE_M)
    # ground photons per bin: twice those below the centre (a half normal truncated at 3 sigma
    # holds 0.4987 of the return); density above the ground per metre of height
    n_ground = 2.0 * np.bincount(b[below], minlength=nb) / (2 * stats.norm.cdf(0) -
                                                              2 * stats.norm.cdf(-LOWER_SIGMAS))
    n_above = np.bincount(b[probe], minlength=nb) / VEGETATION_PROBE_M
    peak = n_ground / (sigma * np.sqrt(2 * np.pi))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(n_above > 0, peak / np.maximum(n_above, 1e-300), np.inf)
        u = sigma * np.sqrt(2.0 * np.log(np.maximum(ratio, 1.0)))
    u = np.clip(np.where(np.isfinite(u), u, np.inf), UPPER_SIGMAS * sigma, LOWER_SIGMAS * sigma)
    centres = x0 + (np.arange(nb) + 0.5) * bin_m
    return np.interp(x, centres, u) if nb else np.zeros(x.size)
