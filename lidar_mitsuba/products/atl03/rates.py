"""What an ATL03 file says of one beam's photons, read by the same code for a real granule and
for ours (``validate`` and the sea-ice study compare them): shots, signal photons per shot,
the spread of the signal about each 20 m segment's median, the background rate. Pure (h5py).
"""
from __future__ import annotations

import numpy as np


def atl03_rates(path, beam: str = "gt1l") -> dict:
    """What an ATL03 file (real or ours) says of one beam's photons, by the same code.

    Shots are the pulses between each piece's first and last pulse with a photon (a piece: no
    gap of more than 1000 pulses), from ``pce_mframe_cnt`` and ``ph_id_pulse``. Signal photons
    are those with ``signal_conf_ph >= 3`` in any surface class. The spread is the robust
    standard deviation (1.4826 x MAD) of the signal photons' heights about their segment's
    median; the background the ``bckgrd_atlas/bckgrd_rate`` rows within 50 ms of the photons.
    """
    import h5py
    with h5py.File(path, "r") as f:
        g = f[beam]
        h = g["heights/h_ph"][()].astype(np.float64)
        conf = g["heights/signal_conf_ph"][()].max(axis=1)
        frame = g["heights/pce_mframe_cnt"][()].astype(np.int64)
        pid = g["heights/ph_id_pulse"][()].astype(np.int64)
        pulse = frame * 200 + pid - 1
        t_ph = g["heights/delta_time"][()]
        cnt = g["geolocation/segment_ph_cnt"][()].astype(np.int64)
        beg = g["geolocation/ph_index_beg"][()].astype(np.int64) - 1
        bg_t = g["bckgrd_atlas/delta_time"][()] if "bckgrd_atlas/delta_time" in g else None
        bg = g["bckgrd_atlas/bckgrd_rate"][()] if bg_t is not None else None
    ids = (pid >= 1) & (pid <= 200) & (frame >= 0) & (frame < 2 ** 31)   # (not fill)
    pulses = np.unique(pulse[ids])
    cut = np.flatnonzero(np.diff(pulses) > 1000) + 1
    pieces = np.split(pulses, cut)
    n_shots = int(sum(p[-1] - p[0] + 1 for p in pieces if p.size))
    sig = conf >= 3
    seg_rate, resid = [], []
    for b, c in zip(beg, cnt):
        if c <= 0 or b < 0 or b > h.size - c:      # (no photons, or an index that is fill)
            continue
        p, s = pulse[b:b + c][ids[b:b + c]], sig[b:b + c]
        shots = int(p.max() - p.min() + 1) if p.size else 0
        if shots >= 10:                          # whole segments (not a piece's ragged end)
            seg_rate.append(s.sum() / shots)
        if s.sum() >= 3:
            hs = h[b:b + c][s]
            resid.append(hs - np.median(hs))
    resid = np.concatenate(resid) if resid else np.zeros(0)
    out = {"shots": n_shots, "signal_photons": int(sig.sum()), "photons": int(h.size),
           "signal_per_shot": sig.sum() / max(n_shots, 1),
           "photons_per_shot": h.size / max(n_shots, 1),
           "no_photon_fraction": 1.0 - pulses.size / max(n_shots, 1),
           "no_signal_fraction": 1.0 - np.unique(pulse[sig & ids]).size / max(n_shots, 1),
           "segment_signal_per_shot": [float(v) for v in seg_rate],
           "spread_robust_m": float(1.4826 * np.median(np.abs(resid))) if resid.size else None,
           "spread_std_m": float(np.std(resid)) if resid.size else None,
           "residuals_m": resid}
    if bg is not None and t_ph.size:
        near = np.zeros(bg_t.size, bool)
        for p in pieces:
            if not p.size:
                continue
            sel = ids & (pulse >= p[0]) & (pulse <= p[-1])
            near |= (bg_t >= t_ph[sel].min() - 0.05) & (bg_t <= t_ph[sel].max() + 0.05)
        rates = bg[near].astype(np.float64)
        if rates.size:
            out["background_hz"] = {"median": float(np.median(rates)), "min": float(rates.min()),
                                    "max": float(rates.max()), "rows": int(rates.size)}
    return out
