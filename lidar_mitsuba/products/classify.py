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

**ATL03's own rule** (``neighbourhood_bins=1``, the term-5 leak's finder,
:func:`lidar_mitsuba.night.atl03_leak`): ATL03's finder histograms the photons and classifies
"all photons in any one bin" alike, as signal or background, with a confidence from that bin's
own signal-to-noise ratio (ICESat-2 ATL03 ATBD, release 006, Neumann et al. 2022, section 5.1.1
and step (f) of 5.1.4.2.5.2; NSIDC's ATL03 v006 user guide, section 2.3.1): a photon's count
is its own bin's, ``k`` against Poisson(``lam``), not its bin's and two neighbours'. The
default (3 bins: our writer's ``signal_conf_ph``, unchanged) lets a lone tail photon next to
the surface's bin borrow that bin's count. What ATL03's finder does that this one does not
(the ATBD's values for them were not found: ``snrlow``, ``snrmed``, ``e_m``, its minimum bin
sizes): its bin height and integration time are the smallest at which it finds signal (ATBD
5.1.1, 5.1.4.2.4; the shipped night subset's ``signal_find_output/ocean``: 0.7-2.05 m over
86-457 shots) where ours are fixed (``bin_m``, ``block_shots``); its thresholds are on a
bin's signal-to-noise ratio (``snrlow``, ``snrmed``) where ours are the tail probabilities
above. Its expected background comes from the atmospheric histogram or, for a surface type
whose ``pc_bckgrd_flag`` is set, from the photon cloud itself (ATBD 5.1.1, Table 5-2,
Appendix A): the shipped night subset's ``signal_find_output/ocean/bckgrd_mean`` reads
0.85-0.98 counts a bin (1.15-1.6 m over 86 shots) with a standard deviation of 2.2-3.1, not
Poisson and 60-100 times what its 15 kHz band rate puts in such a bin (0.010-0.014): there
the background is the photon cloud's, the laser's own tail photons in it, as the estimate
above (``noise_per_bin=None``) makes it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
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
                   pool_blocks: int = 11, noise_per_bin=None, neighbourhood_bins: int = 3,
                   min_noise_per_bin: float = 0.0) -> HistogramTest:
    """The histogram test of :func:`signal_confidence` (same arguments), with its per-photon
    tail probabilities and per-block noise levels (blocks up to the last photon's).

    ``noise_per_bin``: the noise level ``lam`` [expected noise photons in one ``bin_m`` bin
    over ``block_shots`` shots] given instead of estimated from the photons (a scalar or
    (n_blocks,)): a tall band's rate, as ATL03's atmospheric histogram gives it where a
    surface type's ``pc_bckgrd_flag`` is not set (the module docstring). ``None`` (the
    default): estimated as above, and at least ``min_noise_per_bin`` [same units] (the leak's
    finder, :func:`lidar_mitsuba.night.atl03_leak`: a quiet night's gate holds too few noise
    photons to estimate it alone).

    ``neighbourhood_bins``: 3 (the default: a photon's count is its bin's and its two
    neighbours', against Poisson(``3 lam``)) or 1 (ATL03's rule, the module docstring's: its
    own bin's, against Poisson(``lam``)).

    Computed on the cells that hold photons only (a few per cent of a track's cells): an
    empty cell's count ``0`` is never improbable (``P(K >= 0) = 1``), so it is always a noise
    bin, adds nothing to a block's noise total and one bin to its noise bins; the photons'
    cells and the counts in one compiled pass (:func:`_photon_cells`). The same numbers as
    the test over every cell (``tests/test_classify.py`` keeps that one and compares)."""
    shot = np.asarray(shot, np.int64)
    if shot.size == 0:
        return HistogramTest(np.zeros(0, np.int8), np.ones(0), np.zeros(0), int(block_shots),
                             float(bin_m))
    gate = np.asarray(gate_center_h_m, float)
    if shot.min() < 0 or shot.max() >= gate.size:
        raise IndexError("shot indices must be within gate_center_h_m")
    n_bins = max(3, int(np.ceil(range_gate_m / bin_m)))
    n_blocks = int(shot.max()) // int(block_shots) + 1
    slot, row, col, k, neighbourhood, peak = _photon_cells(
        shot, np.asarray(h_m, float), gate, range_gate_m / 2.0, float(bin_m), n_bins,
        int(block_shots), n_blocks)
    if neighbourhood_bins not in (1, 3):
        from ..constants import ParameterError
        raise ParameterError("neighbourhood_bins", "must be 1 or 3")
    if noise_per_bin is None:
        lam = _sparse_noise_level(row, col, k, peak, n_bins=n_bins, n_blocks=n_blocks,
                                  bin_m=bin_m, pool_blocks=pool_blocks)
        if min_noise_per_bin > 0.0:
            lam = np.maximum(lam, min_noise_per_bin)
    else:
        lam = np.array(np.broadcast_to(np.asarray(noise_per_bin, float), (n_blocks,)))
    if neighbourhood_bins == 1:                  # ATL03's: a photon's bin alone
        neighbourhood = k
    # the tail probability and confidence of every cell with photons, then each photon's
    # cell's (the test depends on the photon through its cell only; cells are fewer)
    mean = float(neighbourhood_bins) * lam[row]
    p = np.where(mean > 0, special.pdtrc(neighbourhood - 1, np.maximum(mean, 1e-300)), 0.0)
    conf = np.zeros(p.shape, np.int8)
    conf[p < 1e-2] = 2
    conf[p < 1e-4] = 3
    conf[p < 1e-6] = 4
    return HistogramTest(conf[slot], p[slot], lam, int(block_shots), float(bin_m))


def _sparse_noise_level(row, col, k, peak, *, n_bins: int, n_blocks: int, bin_m: float,
                        pool_blocks: int) -> np.ndarray:
    """(n_blocks,) each block's noise level ``lam``, by the module docstring's iteration, from
    the cells that hold photons (:func:`_photon_cells`: their block ``row``, bin ``col`` and
    count ``k``; each block's fullest bin ``peak``); the empty cells are noise bins that add
    nothing (``tests/test_classify.py`` keeps the iteration over every cell)."""
    # initial noise level: bins more than 2 m from the block's fullest bin
    far_bins = (np.abs(np.arange(n_bins)[None, :] - np.arange(n_bins)[:, None]) * bin_m
                > 2.0).sum(1)                      # a block's far bins, by its fullest bin
    noise = np.abs(col - peak[row]) * bin_m > 2.0
    n_noise = far_bins[peak]
    sf, lam_was = np.ones(k.size), None
    for _ in range(4):
        total = uniform_filter1d(np.bincount(row, weights=k * noise, minlength=n_blocks),
                                 pool_blocks, mode="nearest")
        used = uniform_filter1d(n_noise.astype(float), pool_blocks, mode="nearest")
        lam = np.maximum(total / np.maximum(used, 1e-12), 1e-12)
        # (a cell's tail probability again only where its block's level moved: the same
        # function of the same numbers)
        again = (np.arange(k.size) if lam_was is None
                 else np.flatnonzero((lam != lam_was)[row]))
        sf[again] = special.pdtrc(k[again] - 1, lam[row[again]])
        noise, lam_was = ~(sf < 1e-3), lam
        n_noise = n_bins - np.bincount(row[~noise], minlength=n_blocks)
    return total / np.maximum(used, 1e-12)


@numba.njit(cache=True, nogil=True)
def _photon_cells(shot, h_m, gate_center_h_m, half_gate_m, bin_m, n_bins, block_shots,
                  n_blocks):
    """The histogram's cells that hold photons, and each photon's.

    A photon's cell is ``block * n_bins + bin``: ``bin`` is ``int((h - gate[shot] +
    half_gate) / bin_m)`` clipped to the gate's bins, as numpy's ``astype(np.int64)``
    truncates (toward zero; a value beyond int64's range or NaN becomes its smallest,
    clipped to bin 0), ``block`` is ``shot // block_shots``.

    Returns ``(slot, row, col, count, neighbourhood, peak)``: (n,) each photon's place among
    the (m,) cells with photons, in the order of their cell numbers; their block, bin,
    photon count and the count of the bin and its two neighbours; (n_blocks,) each block's
    fullest bin (the first, as ``argmax``)."""
    n = shot.size
    cell = np.empty(n, np.int64)
    counts = np.zeros(n_blocks * n_bins, np.int64)
    for i in range(n):
        s = shot[i]
        q = (h_m[i] - gate_center_h_m[s] + half_gate_m) / bin_m
        b = np.int64(q) if -9.223372036854775808e18 <= q < 9.223372036854775808e18 else 0
        b = min(max(b, 0), n_bins - 1)
        cell[i] = (s // block_shots) * n_bins + b
        counts[cell[i]] += 1
    m = 0
    for c in range(counts.size):
        m += counts[c] > 0
    row, col = np.empty(m, np.int64), np.empty(m, np.int64)
    count, near = np.empty(m, np.int64), np.empty(m, np.int64)
    peak = np.zeros(n_blocks, np.int64)
    j = 0
    for r in range(n_blocks):
        top = 0
        left = 0                                 # the count of the bin before
        for b in range(n_bins):
            c = r * n_bins + b
            v = counts[c]
            if v > top:
                top, peak[r] = v, b
            if v > 0:
                row[j], col[j], count[j] = r, b, v
                near[j] = left + v + (counts[c + 1] if b < n_bins - 1 else 0)
                counts[c] = -1 - j               # (the cell's place, where its count was)
                j += 1
            left = v
    slot = np.empty(n, np.int64)
    for i in range(n):
        slot[i] = -1 - counts[cell[i]]
    return slot, row, col, count, near, peak


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
