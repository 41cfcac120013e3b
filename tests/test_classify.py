"""The histogram test on the cells that hold photons (lidar_mitsuba.products.classify, with its
compiled pass over the photons) against the test over every cell, as it was written before
(kept here as the reference): the same confidences, tail probabilities and noise levels, to
the bit. Pure numpy: no rendering."""
import numpy as np
import pytest
from scipy import special
from scipy.ndimage import uniform_filter1d

from lidar_mitsuba.products import classify


def _sf_every_cell(k, mu):
    k, mu = np.broadcast_arrays(np.asarray(k), np.asarray(mu, float))
    out = np.ones(k.shape)
    some = k >= 0
    out[some] = special.pdtrc(k[some], mu[some])
    return out


def _test_every_cell(*, shot, h_m, gate_center_h_m, range_gate_m, block_shots=20, bin_m=0.5,
                     pool_blocks=11):
    """The histogram test over every (block, bin) cell (the library's until session 23)."""
    shot = np.asarray(shot, np.int64)
    rel = np.asarray(h_m, float) - np.asarray(gate_center_h_m, float)[shot] + range_gate_m / 2.0
    n_bins = max(3, int(np.ceil(range_gate_m / bin_m)))
    b = np.clip((rel / bin_m).astype(np.int64), 0, n_bins - 1)
    block = shot // block_shots
    n_blocks = int(block.max()) + 1
    counts = np.bincount(block * n_bins + b, minlength=n_blocks * n_bins).reshape(n_blocks, n_bins)
    far = np.abs(np.arange(n_bins)[None, :] - counts.argmax(1)[:, None]) * bin_m > 2.0
    noise_bins = far
    for _ in range(4):
        total = uniform_filter1d((counts * noise_bins).sum(1).astype(float), pool_blocks,
                                 mode="nearest")
        used = uniform_filter1d(noise_bins.sum(1).astype(float), pool_blocks, mode="nearest")
        lam = total / np.maximum(used, 1e-12)
        noise_bins = ~(_sf_every_cell(counts - 1, np.maximum(lam, 1e-12)[:, None]) < 1e-3)
    padded = np.pad(counts, ((0, 0), (1, 1)))
    neighbourhood = padded[:, :-2] + padded[:, 1:-1] + padded[:, 2:]
    mean = 3.0 * lam[:, None]
    p = np.where(mean > 0, _sf_every_cell(neighbourhood - 1, np.maximum(mean, 1e-300)), 0.0)
    cell = np.zeros(p.shape, np.int8)
    cell[p < 1e-2] = 2
    cell[p < 1e-4] = 3
    cell[p < 1e-6] = 4
    return cell[block, b], p[block, b], lam


def _track(rng, *, n_shots, signal, noise_per_shot, gate_m=30.0):
    """Photons of a sloping surface (``signal`` a shot, 0.1 m spread) and uniform noise over
    a 30 m gate, a few beyond it (clipped to the end bins), by shot."""
    z = 100.0 + 0.01 * np.arange(n_shots)
    n_sig, n_noise = rng.poisson(signal, n_shots), rng.poisson(noise_per_shot, n_shots)
    s_sig, s_noise = np.repeat(np.arange(n_shots), n_sig), np.repeat(np.arange(n_shots), n_noise)
    h = np.concatenate([z[s_sig] + rng.normal(0, 0.1, s_sig.size),
                        z[s_noise] + rng.uniform(-gate_m / 2 - 1, gate_m / 2 + 1, s_noise.size)])
    shot = np.concatenate([s_sig, s_noise])
    return shot, h, z + rng.normal(0, 0.3, n_shots)


@pytest.mark.parametrize("signal, noise, block_shots, order", [
    (3.0, 0.5, 20, "by shot"), (0.5, 3.0, 20, "shuffled"), (8.0, 0.0, 7, "by shot"),
    (0.0, 2.0, 20, "shuffled"), (1.0, 0.05, 50, "by shot")])
def test_histogram_test_on_photon_cells_is_the_test_on_every_cell(rng, signal, noise,
                                                                     block_shots, order):
    """Strong and weak signal, heavy and no noise, other block lengths, photons in any
    order and beyond the gate: every confidence, tail probability and noise level the
    same bits as the test over every cell."""
    shot, h, gate = _track(rng, n_shots=3000, signal=signal, noise_per_shot=noise)
    if order == "shuffled":
        p = rng.permutation(shot.size)
        shot, h = shot[p], h[p]
    kw = dict(shot=shot, h_m=h, gate_center_h_m=gate, range_gate_m=30.0,
              block_shots=block_shots)
    got = classify.histogram_test(**kw)
    conf, tail_p, lam = _test_every_cell(**kw)
    assert np.array_equal(got.conf, conf) and got.conf.dtype == np.int8
    assert np.array_equal(got.tail_p.view(np.int64), tail_p.view(np.int64))
    assert np.array_equal(got.noise_per_bin.view(np.int64), lam.view(np.int64))
    met = ({4} if signal else set()) | ({0} if noise else set())   # (the kinds were met)
    assert set(np.unique(conf)) >= met


def test_photon_cells_truncate_as_numpy_casts(rng):
    """The compiled pass's cells: numpy's ``astype(np.int64)`` (toward zero) and clip, for
    heights across the gate, below and above it, and NaN; the counts ``np.bincount``'s, the
    neighbourhoods the padded sums, the fullest bins ``argmax``'s."""
    n = 5000
    shot = np.sort(rng.integers(0, 400, n))
    gate = rng.normal(50.0, 3.0, 400)
    h = gate[shot] + rng.uniform(-20.0, 20.0, n)
    h[::97] = np.nan
    h[1::89] = 1e300
    slot, row, col, count, near, peak = classify._photon_cells(shot, h, gate, 15.0, 0.5, 60,
                                                               20, 20)
    with np.errstate(invalid="ignore"):
        b = np.clip(((h - gate[shot] + 15.0) / 0.5).astype(np.int64), 0, 59)
    cell = (shot // 20) * 60 + b
    counts = np.bincount(cell, minlength=20 * 60)
    full = np.flatnonzero(counts)
    assert np.array_equal(row * 60 + col, full) and np.array_equal(count, counts[full])
    assert np.array_equal(full[slot], cell)
    padded = np.pad(counts.reshape(20, 60), ((0, 0), (1, 1)))
    assert np.array_equal(near, (padded[:, :-2] + padded[:, 1:-1] + padded[:, 2:]).ravel()[full])
    assert np.array_equal(peak, counts.reshape(20, 60).argmax(1))


def test_atl03s_rule_gives_a_photon_its_own_bins_confidence():
    """ATL03 classifies all photons of a bin alike (ATBD release 006, 5.1.1;
    ``neighbourhood_bins=1``): a lone photon in the bin below a dense surface bin borrows that
    bin's count under our writer's rule (its neighbourhood holds 41 photons against Poisson(3
    lam): high confidence) and keeps its own under ATL03's (1 photon against Poisson(lam):
    P(K >= 1) = 1 - exp(-lam)), exactly; the surface's bin is high under both. The noise level
    estimated from a quiet gate is floored by ``min_noise_per_bin``."""
    shot = np.r_[np.arange(20).repeat(2), 7]                    # one 20-shot block
    h = np.r_[np.full(40, 0.25), -0.25]                         # bins 30 and 29 of 60
    kw = dict(shot=shot, h_m=h, gate_center_h_m=np.zeros(20), range_gate_m=30.0)
    lam = 2e-3
    ours = classify.histogram_test(**kw, noise_per_bin=lam)
    atl03 = classify.histogram_test(**kw, noise_per_bin=lam, neighbourhood_bins=1)
    assert np.all(ours.conf == 4) and np.all(atl03.conf[:40] == 4)
    assert atl03.tail_p[40] == pytest.approx(-np.expm1(-lam), rel=1e-12)
    assert atl03.conf[40] == 2                                  # 1e-4 <= 2e-3 < 1e-2
    assert ours.tail_p[40] == special.pdtrc(40, 3 * lam)
    # no photon outside the surface's bins: an estimate of nothing, lifted to the floor
    free = classify.histogram_test(**kw, neighbourhood_bins=1)
    floored = classify.histogram_test(**kw, neighbourhood_bins=1, min_noise_per_bin=lam)
    assert free.noise_per_bin[0] < 1e-9 and floored.noise_per_bin[0] == lam
    assert np.array_equal(floored.conf, atl03.conf)
    with pytest.raises(ValueError, match="neighbourhood_bins"):
        classify.histogram_test(**kw, neighbourhood_bins=2)
