"""Signal/noise classification of photons: ATL03's ``signal_conf_ph``, by a histogram test.

The track is cut into blocks of ``block_shots`` consecutive shots; in each block, photon heights
relative to the range-gate centre are histogrammed in bins of ``bin_m``. The noise level per bin
``lam`` is estimated from the histograms, iteratively: start from the bins more than 2 m from
the block's fullest bin, then mark bins whose count is improbable under Poisson(``lam``) (tail
probability < 1e-3) as signal and re-estimate ``lam`` as the mean of the other bins; each
estimate pools ``pool_blocks`` neighbouring blocks, since a block alone holds few noise photons. A photon's neighbourhood count
``k`` is the number of photons in its own bin and the two adjacent ones; under noise alone ``k``
is Poisson(``3 lam``). Its confidence follows from the tail probability ``P = P(K >= k)``:

====  ===============  ======================
conf  ATL03 meaning    rule
====  ===============  ======================
4     high             P < 1e-6
3     medium           1e-6 <= P < 1e-4
2     low              1e-4 <= P < 1e-2
0     noise            P >= 1e-2
====  ===============  ======================

(ATL03's 1, "buffer", is not used.) With no noise at all every photon is high confidence.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special
from scipy.ndimage import uniform_filter1d


def signal_confidence(*, shot: np.ndarray, h_m: np.ndarray, gate_center_h_m: np.ndarray,
                      range_gate_m: float, block_shots: int = 20, bin_m: float = 0.5,
                      pool_blocks: int = 11) -> np.ndarray:
    """(n,) int8 confidence (0, 2, 3, 4) of each photon.

    Args:
        shot: (n,) shot index of each photon.
        h_m: (n,) photon elevation [m].
        gate_center_h_m: (n_shots,) elevation of each shot's range-gate centre [m].
        range_gate_m: height of the range gate [m].
        block_shots: shots per along-track block.
        bin_m: histogram bin height [m].
        pool_blocks: the noise level of a block is pooled over this many neighbouring blocks.
    """
    return histogram_test(shot=shot, h_m=h_m, gate_center_h_m=gate_center_h_m,
                          range_gate_m=range_gate_m, block_shots=block_shots, bin_m=bin_m,
                          pool_blocks=pool_blocks).conf


@dataclass
class HistogramTest:
    """What the histogram test found (:func:`histogram_test`).

    Attributes:
        conf: (n,) int8 confidence of each photon (:func:`signal_confidence`).
        tail_p: (n,) the tail probability ``P(K >= k)`` of each photon's neighbourhood count
            under noise alone (1 for an empty track; 0 where no noise was estimated).
        noise_per_bin: (n_blocks,) the pooled noise level ``lam`` of each block: expected noise
            photons in one ``bin_m`` bin over ``block_shots`` shots.
        block_shots, bin_m: the histogram's block length [shots] and bin height [m].
    """
    conf: np.ndarray
    tail_p: np.ndarray
    noise_per_bin: np.ndarray
    block_shots: int
    bin_m: float


def histogram_test(*, shot: np.ndarray, h_m: np.ndarray, gate_center_h_m: np.ndarray,
                   range_gate_m: float, block_shots: int = 20, bin_m: float = 0.5,
                   pool_blocks: int = 11, noise_per_bin=None) -> HistogramTest:
    """The histogram test of :func:`signal_confidence` (same arguments), with its per-photon
    tail probabilities and per-block noise levels (blocks up to the last photon's).

    ``noise_per_bin``: the noise level ``lam`` [expected noise photons in one ``bin_m`` bin
    over ``block_shots`` shots] given instead of estimated from the photons (a scalar or
    (n_blocks,)), as ATL03's finder takes it from the 50-shot background rate of its tall
    band: a quiet night's gate holds too few noise photons to estimate it
    (:func:`lidar_mitsuba.night.atl03_leak`). ``None`` (the default): estimated as above."""
    shot = np.asarray(shot, np.int64)
    if shot.size == 0:
        return HistogramTest(np.zeros(0, np.int8), np.ones(0), np.zeros(0), int(block_shots),
                             float(bin_m))
    rel = np.asarray(h_m, float) - np.asarray(gate_center_h_m, float)[shot] + range_gate_m / 2.0
    n_bins = max(3, int(np.ceil(range_gate_m / bin_m)))
    b = np.clip((rel / bin_m).astype(np.int64), 0, n_bins - 1)
    block = shot // block_shots
    n_blocks = int(block.max()) + 1
    counts = np.bincount(block * n_bins + b, minlength=n_blocks * n_bins).reshape(n_blocks, n_bins)
    if noise_per_bin is None:
        lam = _noise_level(counts, bin_m=bin_m, pool_blocks=pool_blocks)
    else:
        lam = np.array(np.broadcast_to(np.asarray(noise_per_bin, float), (n_blocks,)))
    padded = np.pad(counts, ((0, 0), (1, 1)))
    neighbourhood = padded[:, :-2] + padded[:, 1:-1] + padded[:, 2:]
    # the tail probability and confidence of every (block, bin) cell, then each photon's
    # cell's (the test depends on the photon through its cell only; cells are fewer)
    mean = 3.0 * lam[:, None]
    p = np.where(mean > 0, _poisson_sf(neighbourhood - 1, np.maximum(mean, 1e-300)), 0.0)
    cell = np.zeros(p.shape, np.int8)
    cell[p < 1e-2] = 2
    cell[p < 1e-4] = 3
    cell[p < 1e-6] = 4
    return HistogramTest(cell[block, b], p[block, b], lam, int(block_shots), float(bin_m))


def _noise_level(counts: np.ndarray, *, bin_m: float, pool_blocks: int) -> np.ndarray:
    """(n_blocks,) each block's noise level ``lam`` from the (n_blocks, n_bins) histogram
    ``counts``, by the iteration the module's docstring describes."""
    # initial noise level: bins more than 2 m from the block's fullest bin
    far = np.abs(np.arange(counts.shape[1])[None, :] - counts.argmax(1)[:, None]) * bin_m > 2.0
    noise_bins = far
    for _ in range(4):
        total = uniform_filter1d((counts * noise_bins).sum(1).astype(float), pool_blocks, mode="nearest")
        used = uniform_filter1d(noise_bins.sum(1).astype(float), pool_blocks, mode="nearest")
        lam = total / np.maximum(used, 1e-12)
        noise_bins = ~(_poisson_sf(counts - 1, np.maximum(lam, 1e-12)[:, None]) < 1e-3)
    return lam


def _poisson_sf(k, mu):
    """P(K >= k + 1) for K ~ Poisson(mu), elementwise; 1 for k < 0 (what
    ``scipy.stats.poisson.sf`` gives, from the same ``special.pdtrc``, without importing
    scipy.stats, which costs most of a second)."""
    k, mu = np.broadcast_arrays(np.asarray(k), np.asarray(mu, float))
    out = np.ones(k.shape)
    some = k >= 0                   # (empty cells, most of a quiet track, need no pdtrc)
    out[some] = special.pdtrc(k[some], mu[some])
    return out


def classification_rates(conf: np.ndarray, is_signal: np.ndarray, *, min_conf: int = 2) -> dict:
    """Hit rate (true signal photons with conf >= ``min_conf``) and false-alarm rate (noise
    photons with conf >= ``min_conf``) against the simulation truth."""
    conf = np.asarray(conf)
    is_signal = np.asarray(is_signal, bool)
    flagged = conf >= min_conf
    n_sig, n_noise = int(is_signal.sum()), int((~is_signal).sum())
    return {"min_conf": int(min_conf), "n_signal": n_sig, "n_noise": n_noise,
            "hit_rate": float(flagged[is_signal].mean()) if n_sig else float("nan"),
            "false_alarm_rate": float(flagged[~is_signal].mean()) if n_noise else float("nan")}
