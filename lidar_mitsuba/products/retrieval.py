"""Elevation retrieval: photon heights, and elevation bias and precision. Pure numpy.

A detected photon's elevation is ``h = altitude - c * t / 2`` with ``t`` its round-trip time;
it is placed at its shot's footprint centre, as ATLAS does. The reference elevation of a shot is
the footprint-weighted (Gaussian) mean of the surface. Over a set of photons, the *elevation
bias* is the mean of ``h - z_ref`` and the *precision* its standard deviation.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from ..constants import C_M_PER_NS


def photon_heights_m(time_ns: np.ndarray, *, altitude_m: float) -> np.ndarray:
    """(n,) photon elevations [m] from round-trip times [ns], in float64."""
    return altitude_m - C_M_PER_NS * np.asarray(time_ns, np.float64) / 2.0


@dataclass(frozen=True)
class ElevationStats:
    """Bias and precision of ``h - z_ref`` over a set of photons, with their Monte Carlo
    standard errors (the ``_se`` suffix marks a standard error throughout the package).

    Attributes:
        bias_m: mean of h - z_ref [m] (NaN without photons).
        bias_se_m: standard error of ``bias_m``, std / sqrt(n) [m].
        std_m: precision, the sample standard deviation (ddof=1) [m] (NaN with < 2 photons).
        std_se_m: standard error of ``std_m`` from the photons' kurtosis
            (:func:`std_standard_error`; std / sqrt(2 (n - 1)) for normal residuals) [m].
        n_photons: photons used.
        shots: shots spanned.
        photons_per_shot: n_photons / shots.
    """
    bias_m: float
    bias_se_m: float
    std_m: float
    std_se_m: float
    n_photons: int
    shots: int
    photons_per_shot: float

    def to_dict(self) -> dict:
        return asdict(self)


def std_standard_error(x: np.ndarray) -> float:
    """Standard error [units of x] of the sample standard deviation (ddof = 1) of ``x`` (n,).

    The delta method on ``Var(s^2) = sigma^4 (kappa - (n - 3) / (n - 1)) / n`` gives
    ``SE(s) = s sqrt((kappa - (n - 3) / (n - 1)) / (4 n))``, with the kurtosis ``kappa``
    estimated by ``3 + G2`` (the excess-kurtosis estimator that is unbiased for normal data)
    and held at its floor of 1. For normal data this is ``s / sqrt(2 (n - 1))``; a heavy tail
    (photons scattered twice and delayed by metres: a kurtosis of hundreds) makes the precision
    of a run many times noisier than that, and this says so. ``s / sqrt(2 (n - 1))`` below four
    values (no kurtosis estimate); NaN below two.
    """
    x = np.asarray(x, np.float64)
    n = x.size
    if n < 2:
        return math.nan
    s = float(x.std(ddof=1))
    if n < 4 or s == 0.0:
        return s / math.sqrt(2.0 * (n - 1))
    d = x - x.mean()
    m2 = float(np.mean(d * d))
    g2 = float(np.mean(d ** 4)) / (m2 * m2) - 3.0
    kappa = max(3.0 + ((n + 1) * g2 + 6.0) * (n - 1) / ((n - 2) * (n - 3)), 1.0)
    return s * math.sqrt((kappa - (n - 3) / (n - 1)) / (4.0 * n))


def elevation_stats(dh_m: np.ndarray, *, shots: int) -> ElevationStats:
    """Bias, precision and counts of the elevation residuals ``dh_m`` (shape (n,)) over ``shots``."""
    dh = np.asarray(dh_m, np.float64)
    n = dh.size
    bias = float(dh.mean()) if n else math.nan
    std = float(dh.std(ddof=1)) if n > 1 else math.nan
    return ElevationStats(bias_m=bias, bias_se_m=std / math.sqrt(n) if n > 1 else math.nan,
                          std_m=std, std_se_m=std_standard_error(dh),
                          n_photons=int(n), shots=int(shots),
                          photons_per_shot=n / shots if shots else math.nan)


@dataclass(frozen=True)
class StatsReport:
    """Overall, per-window and per-channel statistics of one beam."""
    overall: ElevationStats
    windows: list[dict]
    channels: list[dict]
    window_shots: int

    def to_dict(self) -> dict:
        d = self.overall.to_dict()
        d.update(window_shots=self.window_shots, windows=self.windows, channels=self.channels)
        return d


def elevation_report(*, dh_m: np.ndarray, shot: np.ndarray, channel: np.ndarray, n_shots: int,
                     n_channels: int, window_shots: int = 1000) -> StatsReport:
    """Statistics overall, per window of ``window_shots`` consecutive shots and per channel.

    Args:
        dh_m: (n,) residuals h - z_ref of the photons used (e.g. the signal photons) [m].
        shot, channel: (n,) shot index and channel of each photon.
        n_shots: shots in the track; n_channels: detector channels.
    """
    if window_shots < 1:
        raise ValueError(f"window must be >= 1 shot (got {window_shots})")
    dh_m = np.asarray(dh_m, np.float64)
    shot = np.asarray(shot, np.int64)
    channel = np.asarray(channel)
    if shot.size and (shot.min() < 0 or shot.max() >= n_shots):
        raise ValueError(f"shot indices must lie in [0, {n_shots}) (got {shot.min()} .. {shot.max()})")
    if channel.size and (channel.min() < 0 or channel.max() >= n_channels):
        raise ValueError(f"channels must lie in [0, {n_channels}) "
                         f"(got {channel.min()} .. {channel.max()})")
    windows = []
    for k, start in enumerate(range(0, n_shots, window_shots)):
        stop = min(n_shots, start + window_shots)
        sel = (shot >= start) & (shot < stop)
        row = {"window": k, "first_shot": start, "last_shot": stop - 1}
        row.update(elevation_stats(dh_m[sel], shots=stop - start).to_dict())
        windows.append(row)
    channels = []
    for c in range(n_channels):
        row = {"channel": c}
        row.update(elevation_stats(dh_m[channel == c], shots=n_shots).to_dict())
        channels.append(row)
    return StatsReport(overall=elevation_stats(dh_m, shots=n_shots), windows=windows,
                       channels=channels, window_shots=window_shots)


def format_report(report: StatsReport, *, title: str = "") -> str:
    """A plain-text table of a :class:`StatsReport` (cm, like the paper)."""
    def line(label, s):
        return (f"{label:<12}{s['n_photons']:>10}{s['photons_per_shot']:>10.3f}"
                f"{100 * s['bias_m']:>11.2f}{100 * s['bias_se_m']:>9.2f}{100 * s['std_m']:>11.2f}")
    head = f"{'':<12}{'photons':>10}{'per shot':>10}{'bias [cm]':>11}{'± [cm]':>9}{'std [cm]':>11}"
    rows = [title] if title else []
    rows.append(head)
    rows.append(line("overall", report.overall.to_dict()))
    for c in report.channels:
        rows.append(line(f"channel {c['channel']}", c))
    if len(report.windows) > 1:
        for w in report.windows:
            rows.append(line(f"window {w['window']}", w))
    return "\n".join(rows)
