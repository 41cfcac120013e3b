"""ATL03's shape in the realism matrix (:mod:`lidar_mitsuba.studies.realism`): the spread and
tails of a beam's surface photons about each 20 m segment's median, measured on the real file
and predicted on its twin's photons, and issue 41's verdict on them (the robust spread within
:data:`SPREAD_AGREES`, each tail beyond +-20 cm within a factor :data:`TAIL_FACTOR`; the
rule ``validate``'s sea-ice twin rows use too), with the tails' binomial standard errors.
Pure numpy (h5py for the real file).
"""
from __future__ import annotations

import math

import numpy as np

SPREAD_AGREES = 0.30
"""The twin's robust spread within this fraction of the real one agrees (issue 41)."""
TAIL_FACTOR = 2.0
"""Each tail beyond +-20 cm within this factor of the real one agrees (issue 41)."""
TAIL_M = 0.20
"""ATL03 tails: the fraction of surface photons farther than this below / above their
segment's median [m]."""

FAR_CUT_M = 0.3
"""Residuals above +this [m] are the far upper tail (ridge sails' photons; session 22)."""

TAIL_WINDOW_M = 1.0
"""The predicted tails count the simulated surface photons within this distance [m] of their
segment's median, as ATL03's ``signal_conf_ph >= 3`` photons lie over flat ice (ESTIMATE: the reach of
the product's signal finder, not a physical parameter; the shipped night subset's
high-confidence photons lie within -1.0 .. +0.7 m of their segment's median): photons the
snow returns from deeper down are low-confidence there, and background here."""


def atl03_shape(path, beam: str) -> dict:
    """Robust spread and tails of an ATL03 beam's surface photons about each segment's
    median (:func:`~lidar_mitsuba.products.atl03.rates.atl03_rates`, the code validate uses)."""
    from ..products.atl03.rates import atl03_rates
    try:
        r = atl03_rates(path, beam)
    except (KeyError, IndexError, ValueError):    # photons dropped, or not fitting their
        return {}                                 # index (the file's line says which)
    res = np.asarray(r["residuals_m"])
    return shape_stats(res)


def tails(residuals_m, *, cut_m: float = TAIL_M, far_cut_m: float = FAR_CUT_M) -> dict:
    """Fractions of ``residuals_m`` below ``-cut_m`` and above ``+cut_m`` (strictly), and
    above ``+far_cut_m`` (``above_far``), with their binomial standard errors
    ``sqrt(f (1 - f) / n)``; ``n`` the residuals counted (the sea-ice ladder's,
    :mod:`~lidar_mitsuba.studies.sea_ice`, and ``validate``'s too)."""
    r = np.asarray(residuals_m, np.float64).ravel()
    n = int(r.size)
    out = {"n": n, "cut_m": float(cut_m), "far_cut_m": float(far_cut_m)}
    for side, k in (("below", int(np.sum(r < -cut_m))), ("above", int(np.sum(r > cut_m))),
                    ("above_far", int(np.sum(r > far_cut_m)))):
        f = k / n if n else float("nan")
        out[side] = f
        out[f"{side}_count"] = k
        out[f"{side}_se"] = math.sqrt(f * (1.0 - f) / n) if n else float("nan")
    return out


def shape_stats(residuals_m) -> dict:
    """Robust sd (1.4826 MAD) of height residuals [m], their tails below / above ``TAIL_M``
    and the tails' binomial standard errors (:func:`tails`)."""
    res = np.asarray(residuals_m, np.float64)
    if res.size < 10:
        return {}
    t = tails(res)
    out = {"spread_robust_m": float(1.4826 * np.median(np.abs(res - np.median(res)))),
           "shape_photons": int(res.size)}
    for side in ("below", "above"):
        out[f"tail_{side}"], out[f"tail_{side}_se"] = t[side], t[f"{side}_se"]
    return out


SEGMENT_M = 20.0
"""ATL03's geolocation segment [m]: the real residuals are about each one's median
(:func:`~lidar_mitsuba.products.atl03.rates.atl03_rates`), and so are the predicted."""


def segment_residuals_m(h_m, along_m, *, min_photons: int = 3) -> np.ndarray:
    """Signal photons' heights ``h_m`` [m] less their ``SEGMENT_M`` along-track segment's
    median (``along_m`` [m] from the track's first shot, like ``h_m``; segments with at least
    ``min_photons``, as :func:`~lidar_mitsuba.products.atl03.rates.atl03_rates`), those
    within :data:`TAIL_WINDOW_M` of it (the reach of ATL03's high-confidence photons). Over
    rough ice the segment's median leaves in the relief shorter than the segment, as it does
    in the real file's."""
    h = np.asarray(h_m, np.float64)
    seg = np.floor(np.asarray(along_m, np.float64) / SEGMENT_M).astype(np.int64)
    out = []
    for k in np.unique(seg):
        hk = h[seg == k]
        if hk.size >= min_photons:
            r = hk - np.median(hk)
            out.append(r[np.abs(r) <= TAIL_WINDOW_M])
    return np.concatenate(out) if out else np.zeros(0)


def _ratio_se(p: float, sp: float, m: float, sm: float) -> tuple[float, float]:
    """``p / m`` and its standard error from the two independent ones (first order)."""
    r = p / m
    return r, abs(r) * float(np.hypot(sp / p if p > 0 else 0.0, sm / m))


def shape_verdict(measured: dict, predicted: dict) -> dict | None:
    """Issue 41's verdict on a row's shape (:func:`shape_stats` of the real and the predicted
    residuals): the spread's ratio (agrees within ``1 +- SPREAD_AGREES``) and each tail's
    ratio with its standard error from the two binomial ones (agrees within a factor
    ``TAIL_FACTOR`` either way, the point values judged as ``validate`` judges them; the SEs
    say how far the sampling alone could move them). None without both shapes."""
    if "spread_robust_m" not in measured or "spread_robust_m" not in predicted:
        return None
    spread = predicted["spread_robust_m"] / measured["spread_robust_m"]
    out = {"spread_ratio": spread, "spread_agrees": bool(abs(spread - 1.0) <= SPREAD_AGREES)}
    bad = [] if out["spread_agrees"] else [f"spread {100 * (spread - 1):+.0f} %"]
    for side in ("below", "above"):
        m, p = measured[f"tail_{side}"], predicted[f"tail_{side}"]
        if not m > 0:
            out[f"tail_{side}_agrees"] = False
            bad.append(f"no real photon {side}")
            continue
        r, se = _ratio_se(p, predicted[f"tail_{side}_se"], m, measured[f"tail_{side}_se"])
        ok = 1.0 / TAIL_FACTOR <= r <= TAIL_FACTOR
        out.update({f"tail_{side}_ratio": r, f"tail_{side}_ratio_se": se,
                    f"tail_{side}_agrees": bool(ok)})
        if not ok:
            bad.append(f"tail {side} x{r:.2f} +- {se:.2f}")
    out["verdict"] = "agrees" if not bad else "disagrees"
    out["reason"] = ", ".join(bad) if bad else (
        f"spread {100 * (spread - 1):+.0f} % (within {100 * SPREAD_AGREES:.0f} %), tails x"
        f"{out['tail_below_ratio']:.2f} +- {out['tail_below_ratio_se']:.2f} below, "
        f"x{out['tail_above_ratio']:.2f} +- {out['tail_above_ratio_se']:.2f} above (within a "
        f"factor {TAIL_FACTOR:g})")
    return out
