"""The two records that flow between the stages: traced :class:`Returns` (the integrator's
output, before any detector effect; defined with the plugins, in
``lidar_mitsuba_plugins.returns``) and detected :class:`Detections` (the PMT's output). Pure
numpy: plain typed containers with the few operations the chunk loop needs.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from lidar_mitsuba_plugins.returns import Returns  # noqa: F401 (re-exported)


@dataclass(frozen=True)
class Detections:
    """Detected photon events, sorted by shot then time. Arrays have shape (n_events,)
    unless stated.

    Attributes:
        shot: shot index (int64).
        channel: detector channel (int16), ``anode // anodes_per_channel``.
        anode: anode segment (int16).
        time_ns: round-trip time [ns] (float64).
        return_index: index of the traced return the photon came from (int64; -1 for noise).
        is_signal: True for laser photons (bool).
        hit_xyz_m: (n_events, 3) float32 scattering point of each photon [m] (NaN for noise).
        arrivals_per_shot: (n_shots,) photons that reached the detector (before fill factor,
            PDE and dead time).
        mean_photons_per_shot: (n_shots,) the Poisson mean ``mu_s`` of each shot.
        run_out_shots: (n_run_out,) int64 indices of the shots whose photons needed more
            distinct traced returns than the shot had (some reuse a path:
            :func:`lidar_mitsuba.detector.pmt.sample_arrivals`); empty in a well-sampled run.
    """
    shot: np.ndarray
    channel: np.ndarray
    anode: np.ndarray
    time_ns: np.ndarray
    return_index: np.ndarray
    is_signal: np.ndarray
    hit_xyz_m: np.ndarray
    arrivals_per_shot: np.ndarray
    mean_photons_per_shot: np.ndarray
    run_out_shots: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    #: the fields :meth:`concatenate` makes global (each joined once, shifted)
    _GLOBAL = ("shot", "run_out_shots", "return_index")

    def __len__(self) -> int:
        return int(self.shot.size)

    @classmethod
    def concatenate(cls, parts: list[tuple["Detections", int, int]]) -> "Detections":
        """Join chunk detections ``[(detections, first_shot, first_return), ...]``: shots and
        return indices become global."""
        if len(parts) == 1 and parts[0][1] == 0 and parts[0][2] == 0:   # one chunk: as it is
            return parts[0][0]
        out = {f.name: np.concatenate([getattr(d, f.name) for d, *_ in parts])
               for f in fields(cls) if f.name not in cls._GLOBAL}
        out["shot"] = np.concatenate([d.shot + a for d, a, _ in parts])
        out["run_out_shots"] = np.concatenate([d.run_out_shots + a for d, a, _ in parts])
        out["return_index"] = np.concatenate(
            [np.where(d.return_index >= 0, d.return_index + r0, -1) for d, _, r0 in parts])
        return cls(**out)
