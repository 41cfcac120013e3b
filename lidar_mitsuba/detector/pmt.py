"""Radiometry and the multi-anode PMT: traced returns -> detected photon events. Pure numpy.

Per shot ``s`` with traced returns of weights ``w`` (``paths_per_shot`` photon paths):

1. the mean number of photons reaching the detector is
   ``mu_s = signal_photons * sum(w) / paths_per_shot`` (``signal_photons`` is defined for a flat,
   horizontal Lambertian plate of albedo 0.9 at nadir, where every weight is 1);
2. the number of arrivals is Poisson(``mu_s``), and the arrivals are distinct traced returns
   drawn in proportion to their weights (rejection sampling; arrival times are unbiased);
3. each arrival lands on a uniformly random anode, survives the fill factor, then the PDE;
4. anodes are summed into channels (``anodes / channels`` consecutive anodes each);
5. solar background and dark counts are added inside each shot's range gate, uniform in time
   and over the anodes (signal outside the gate is lost too);
6. each channel is dead for ``dead_time_ns`` after every detection (non-paralyzable) or after
   every arrival (paralyzable), unless the detector is ideal.

With ``pulse_shape="atlas"`` (:mod:`.impulse`) each signal photon also gets the receiver's
delay (the impulse response's tail and echoes) before step 5, and every recorded detection may
be followed by an afterpulse on its channel, on which dead time acts again.
"""
from __future__ import annotations

import numpy as np

from . import deadtime as _deadtime
from . import draws as _draws
from . import impulse as _impulse
from ..instrument import Instrument
from .records import Detections, Returns


def sample_arrivals(shot: np.ndarray, weight: np.ndarray, *, n_shots: int, paths_per_shot: int,
                    signal_photons: float, rng: np.random.Generator, exchangeable: bool = False,
                    keep_probability: float = 1.0, signal_scale: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poisson photon arrivals per shot, each a distinct traced return drawn by weight.

    The traced paths of a shot are iid samples of its footprint and pulse; a path's weight
    is its probability of returning to the receiver. Per shot, ``N ~ Poisson(mu)`` photons
    arrive, of which ``Binomial(N, keep_probability)`` survive (fill factor and PDE); each
    survivor is a distinct return, accepted with probability ``w / w_max`` while the shot's
    returns are visited in random order (rejection sampling, ``w_max`` the largest weight of
    the track), so the picks are iid draws from the weighted return distribution. Distinct
    paths matter: drawing with replacement would let two photons share one path with
    probability ~1/paths_per_shot and bias the first-photon statistics. Only when a shot runs
    out of returns (it needs about ``paths_per_shot * mean(w) / w_max`` picks) are its extra
    picks drawn with replacement; trace more paths per shot than photons per shot.

    Args:
        shot: (n_returns,) shot index of each traced return, non-decreasing.
        weight: (n_returns,) return weights (>= 0).
        n_shots, paths_per_shot: the trace's shot count and paths traced per shot.
        signal_photons: mean photons per shot from the reference plate.
        exchangeable: the returns of a shot are already in random order (true for single-bounce
            traces: one return per iid path), so no shuffle is needed. Multi-bounce traces put
            a path's returns side by side and must leave this False.
        keep_probability: probability that an arriving photon is kept (fill factor x PDE).
        signal_scale: (n_shots,) factor on ``signal_photons`` per shot, or ``None``.

    Returns:
        ``(return_index, mu, counts, run_out)``: (n_kept,) index of the chosen return per kept
        photon, grouped by shot; (n_shots,) Poisson means ``signal_photons * sum(w) /
        paths_per_shot``; (n_shots,) photons arriving per shot (before fill factor and PDE);
        (n_shots,) bool, the shots whose picks ran out of distinct returns.
    """
    return _arrivals(shot, weight, n_shots=n_shots, paths_per_shot=paths_per_shot,
                     signal_photons=signal_photons, rng=rng, exchangeable=exchangeable,
                     keep_probability=keep_probability, signal_scale=signal_scale)[:4]


def _arrivals(shot, weight, *, n_shots, paths_per_shot, signal_photons, rng, exchangeable,
              keep_probability, signal_scale):
    """:func:`sample_arrivals`, and the (n_shots + 1,) offsets of each shot's picks in its
    ``return_index`` (the picks come grouped by shot)."""
    shot = np.asarray(shot)
    w = np.asarray(weight)
    w_sum, start, w_max, ordered = _deadtime.shot_stats(shot, w, int(n_shots))
    if not ordered:
        raise ValueError("returns must be sorted by shot")
    mu = signal_photons * w_sum / paths_per_shot
    if signal_scale is not None:
        mu = mu * np.asarray(signal_scale, np.float64)
    counts = rng.poisson(mu)
    kept = (_draws.binomial(rng, counts, keep_probability) if keep_probability < 1
            else counts)                       # (numpy's draws: rng.binomial's, compiled)
    if kept.sum() == 0:
        return (np.zeros(0, np.int64), mu, counts, np.zeros(mu.size, bool),
                np.zeros(mu.size + 1, np.int64))
    idx, run_out, offsets = _deadtime.choose_returns(
        start, w, float(w_max), kept.astype(np.int64), bool(exchangeable),
        int(rng.integers(0, 2 ** 62)))
    return idx, mu, counts, run_out, offsets


def nonparalyzable_mask(group: np.ndarray, time_ns: np.ndarray, dead_time_ns: float) -> np.ndarray:
    """Which events a non-paralyzable detector records: within each ``group`` (a channel of a
    shot), those at least ``dead_time_ns`` after the previous *recorded* event. Events need not
    be sorted. Returns (n_events,) bool."""
    return _mask(group, time_ns, dead_time_ns, paralyzable=False)


def paralyzable_mask(group: np.ndarray, time_ns: np.ndarray, dead_time_ns: float) -> np.ndarray:
    """Which events a paralyzable (extending) detector records: those at least
    ``dead_time_ns`` after the previous event of their group, recorded or not. (n_events,) bool."""
    return _mask(group, time_ns, dead_time_ns, paralyzable=True)


def _mask(group, time_ns, dead_time_ns, *, paralyzable):
    """Both masks run on the detector's own kernel (one group = one 'shot' of one channel,
    no gate, no noise), so the plain-loop tests of the masks test what ``detect`` uses."""
    group = np.asarray(group, np.int64)
    time_ns = np.asarray(time_ns, np.float64)
    if group.size == 0:
        return np.zeros(0, bool)
    if dead_time_ns <= 0:
        return np.ones(group.size, bool)
    _, inverse = np.unique(group, return_inverse=True)
    order = np.argsort(inverse, kind="stable")        # grouped, input order kept for ties
    n_groups = int(inverse.max()) + 1
    start = np.searchsorted(inverse[order], np.arange(n_groups + 1)).astype(np.int64)
    *_, index, _ = _deadtime.detect_shots(
        start, time_ns[order], np.zeros(group.size, np.int16), order.astype(np.int64),
        np.full(n_groups, float(time_ns.min())), np.inf, np.zeros(n_groups), 1, 1,
        float(dead_time_ns),
        paralyzable, 0)
    keep = np.zeros(group.size, bool)
    keep[index] = True
    return keep


def noise_rate_per_ns(instrument: Instrument, background_mhz=None):
    """Rate of noise events inside the range gate [1/ns]: background photons reaching the
    detector (``background_mhz``: the instrument's, or (n_shots,) per shot [MHz]) thinned by
    fill factor and PDE, plus the dark counts of every channel (``dark_count_hz``, not
    thinned). Both are Poisson processes, and so is their sum."""
    bg = instrument.background_mhz if background_mhz is None else background_mhz
    return (np.asarray(bg) * 1e-3 * instrument.fill_factor * instrument.pde
            + instrument.dark_count_hz * 1e-9 * instrument.channels)


def detect(returns: Returns, instrument: Instrument, rng: np.random.Generator, *,
           gate_center_ns: np.ndarray | None = None, signal_scale: np.ndarray | None = None,
           background_mhz: np.ndarray | None = None) -> Detections:
    """Turn traced returns into detected photon events, with noise and the range gate.

    Args:
        returns: the traced returns (``PathLengthIntegrator.trace``), sorted by shot.
        instrument: signal level, anodes, channels, fill factor, PDE, dead time and its model,
            noise rates and range gate.
        rng: numpy random generator (seed it for reproducible runs).
        gate_center_ns: (n_shots,) round-trip time of each shot's reference surface [ns]; the
            gate is ``gate_center_ns +- range_gate_ns / 2``. ``None``: no gate (then the
            instrument must have no noise).
        signal_scale: (n_shots,) factor on ``signal_photons`` per shot (a link budget's range
            and air at each shot: :mod:`lidar_mitsuba.radiometry`); ``None``: 1.
        background_mhz: (n_shots,) background reaching the detector per shot [MHz] instead of
            the instrument's ``background_mhz``.
    """
    n_shots = int(returns.n_shots)
    noise_rate = noise_rate_per_ns(instrument, background_mhz)
    if gate_center_ns is None and np.any(noise_rate > 0):
        raise ValueError("noise needs a range gate: pass gate_center_ns")
    # fill factor then PDE: two independent thinnings, i.e. one with probability ff * pde
    idx, mu, counts, run_out, sig_start = _arrivals(
        returns.shot, returns.weight, n_shots=n_shots,
        paths_per_shot=int(returns.paths_per_shot),
        signal_photons=float(instrument.signal_photons), rng=rng,
        exchangeable=returns.single_bounce, signal_scale=signal_scale,
        keep_probability=instrument.fill_factor * instrument.pde)
    anode = rng.integers(0, instrument.anodes, idx.size)
    response = _impulse.response_of(instrument)
    sig_time = np.asarray(returns.time_ns, np.float64)[idx]
    if response.adds_delay:            # the receiver's tail and echoes (none: the paper's),
        sig_time = sig_time + (response.sample_delay_ns(idx.size, rng)      # calibrated
                               - response.calibration_ns())
    if gate_center_ns is not None:
        gate_start = np.asarray(gate_center_ns, np.float64) - instrument.range_gate_ns / 2.0
        gate_ns = instrument.range_gate_ns
        # a writable copy always: a per-shot rate given as it is would reach the kernel as
        # a read-only view (broadcast_to's), a numba signature of its own to compile
        noise_rate = np.array(np.broadcast_to(np.asarray(noise_rate, np.float64), (n_shots,)))
    else:
        gate_start, gate_ns, noise_rate = np.zeros(n_shots), np.inf, np.zeros(n_shots)
    # narrow types: less memory to touch (the stage is memory-bound)
    index_type = np.int32 if len(returns) < 2 ** 31 else np.int64
    shot, time_ns, anode, index, _ = _deadtime.detect_shots(
        sig_start, sig_time, anode.astype(np.int16),
        idx.astype(index_type), _nan_to_inf(gate_start), float(gate_ns), noise_rate,
        instrument.anodes, instrument.channels, float(instrument.effective_dead_time_ns),
        instrument.paralyzable, int(rng.integers(0, 2 ** 62)), 1)   # spare given: the
    # signature set-up compiles and tests share (an omitted default is a type of its own)
    if response.afterpulse_probability > 0:
        shot, time_ns, anode, index = _with_afterpulses(
            shot, time_ns, anode, index, instrument=instrument, response=response, rng=rng,
            gate_end_ns=None if gate_center_ns is None else gate_start + gate_ns)
    hit = _deadtime.signal_hits(index, *(np.asarray(a, np.float32)
                                         for a in (returns.x_m, returns.y_m, returns.z_m)))
    index = index.astype(np.int64)
    return Detections(shot=shot, channel=(anode // instrument.anodes_per_channel).astype(np.int16),
                      anode=anode, time_ns=time_ns, return_index=index, is_signal=index >= 0,
                      hit_xyz_m=hit, arrivals_per_shot=counts, mean_photons_per_shot=mu,
                      run_out_shots=np.flatnonzero(run_out).astype(np.int64))


def _nan_to_inf(x: np.ndarray) -> np.ndarray:
    """``np.nan_to_num(x, nan=np.inf)`` (NaN to inf, +-inf to +-the largest float), and ``x``
    itself when every value is finite (nothing to replace: the kernels only read it), without
    ``nan_to_num``'s set-up (17 us against 3 us a 4 096-shot chunk)."""
    return x if np.isfinite(x).all() else np.nan_to_num(x, nan=np.inf)


def _with_afterpulses(shot, time_ns, anode, index, *, instrument, response, rng, gate_end_ns):
    """The recorded events with their afterpulses (:func:`.impulse.add_afterpulses`; noise-like:
    index -1) merged in by shot then time, and dead time applied again to the channels that
    got one (an afterpulse blinds its channel, and needs a live channel to be recorded). The
    recorded events are already ``dead_time_ns`` apart on each channel, so only those
    channels can change; the others are left as they are. Returns ``(shot, time_ns, anode,
    index)``."""
    parent, delay = _impulse.add_afterpulses(shot, time_ns, response=response, rng=rng,
                                             gate_end_ns=gate_end_ns)
    if parent.size == 0:
        return shot, time_ns, anode, index
    per_ch = instrument.anodes_per_channel
    group = shot * instrument.channels + anode // per_ch
    ap_shot, ap_time, ap_anode = shot[parent], time_ns[parent] + delay, anode[parent]
    ap_group = group[parent]
    touched = np.flatnonzero(np.isin(group, ap_group))       # events on those channels
    n_t = touched.size
    with _deadtime.serial_while(True):     # a few events: a parallel region costs more
        keep_all = _mask(np.concatenate([group[touched], ap_group]),
                         np.concatenate([time_ns[touched], ap_time]),
                         instrument.effective_dead_time_ns, paralyzable=instrument.paralyzable)
    keep = np.ones(shot.size, bool)
    keep[touched] = keep_all[:n_t]
    ap = keep_all[n_t:]
    ap_shot, ap_time, ap_anode = ap_shot[ap], ap_time[ap], ap_anode[ap]
    order = np.lexsort((ap_time, ap_shot))
    ap_shot, ap_time, ap_anode = ap_shot[order], ap_time[order], ap_anode[order]
    shot, time_ns, anode, index = shot[keep], time_ns[keep], anode[keep], index[keep]
    # insertion points: (shot, time) is sorted, so a structured searchsorted finds them
    key = np.dtype([("s", np.int64), ("t", np.float64)])
    old, new = np.empty(shot.size, key), np.empty(ap_shot.size, key)
    old["s"], old["t"], new["s"], new["t"] = shot, time_ns, ap_shot, ap_time
    at = np.searchsorted(old, new, side="right")
    return (np.insert(shot, at, ap_shot), np.insert(time_ns, at, ap_time),
            np.insert(anode, at, ap_anode), np.insert(index, at, np.asarray(-1, index.dtype)))
