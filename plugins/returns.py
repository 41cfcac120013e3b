"""The integrators' output record: traced photon returns (:class:`Returns`), before any
detector effect. Pure numpy: a typed container with the few operations a chunked pipeline
needs (select, slice by shot, move a folded trace back, join chunks). ``lidar_mitsuba``
re-exports it from ``lidar_mitsuba.detector.records``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .constants import C_M_PER_NS


@dataclass
class Returns:
    """Photon returns traced by the ``pathlength`` integrator, sorted by shot.

    Arrays have shape (n_returns,): one entry per surface interaction that sends light back
    toward the receiver with a non-zero weight (misses and zero weights are dropped).

    Attributes:
        shot: shot index (uint32 from a trace, int64 once chunks are joined).
        time_ns: round-trip time [ns] from the pulse centre's emission (float64).
        weight: return weight (float32): pi f_r cos(theta_o) / 0.9 times the path throughput,
            1 for a flat Lambertian 0.9 plate at nadir.
        x_m, y_m, z_m: scattering point [m] (float32), in the frame of the shot positions.
        depth: surface interaction of the return, 1 = first surface (uint8); for a snow volume
            (``volpathlength``), the interactions before the photon's drawn return, capped
            at 255.
        n_shots: shots traced (including shots with no return).
        paths_per_shot: photon paths traced per shot.
    """
    shot: np.ndarray
    time_ns: np.ndarray
    weight: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    z_m: np.ndarray
    depth: np.ndarray
    n_shots: int
    paths_per_shot: int

    ARRAYS = ("shot", "time_ns", "weight", "x_m", "y_m", "z_m", "depth")

    def __len__(self) -> int:
        return int(self.weight.size)

    @property
    def single_bounce(self) -> bool:
        """True when every return is a first-surface return (one iid return per path)."""
        return not np.any(np.asarray(self.depth) > 1)

    @classmethod
    def empty(cls, *, n_shots: int, paths_per_shot: int) -> "Returns":
        f32 = np.zeros(0, np.float32)
        return cls(shot=np.zeros(0, np.uint32), time_ns=np.zeros(0), weight=f32, x_m=f32,
                   y_m=f32, z_m=f32, depth=np.zeros(0, np.uint8), n_shots=int(n_shots),
                   paths_per_shot=int(paths_per_shot))

    @classmethod
    def at_times(cls, time_ns: np.ndarray, *, paths_per_shot: int,
                 weight: np.ndarray | None = None) -> "Returns":
        """Synthetic first-surface returns for detector studies without rendering:
        ``paths_per_shot`` paths per shot, one return each, with round-trip times ``time_ns``
        ((n_shots * paths_per_shot,) shot by shot [ns]), weights 1 unless given, scattering
        points at the origin."""
        t = np.asarray(time_ns, np.float64).ravel()
        k = int(paths_per_shot)
        if k < 1 or t.size % k:
            raise ValueError(f"time_ns holds {t.size} times: not a whole number of shots of "
                             f"{k} paths")
        n_shots = t.size // k
        zero = np.zeros(t.size, np.float32)
        return cls(shot=np.repeat(np.arange(n_shots), k), time_ns=t,
                   weight=np.ones(t.size, np.float32) if weight is None else np.asarray(weight),
                   x_m=zero, y_m=zero, z_m=zero, depth=np.ones(t.size, np.uint8),
                   n_shots=n_shots, paths_per_shot=k)

    def select(self, index) -> "Returns":
        """The returns at ``index`` (a boolean mask or indices; keep them sorted by shot)."""
        return Returns(**{k: getattr(self, k)[index] for k in self.ARRAYS},
                       n_shots=self.n_shots, paths_per_shot=self.paths_per_shot)

    def slice_shots(self, start: int, stop: int) -> "Returns":
        """Shots ``start`` .. ``stop - 1`` as a trace of their own (shot indices from 0)."""
        i0, i1 = np.searchsorted(self.shot, [start, stop])
        out = {k: getattr(self, k)[i0:i1] for k in self.ARRAYS}
        out["shot"] = (out["shot"] - start).astype(np.uint32)
        return Returns(**out, n_shots=int(stop - start), paths_per_shot=self.paths_per_shot)

    def moved(self, *, dx_m: np.ndarray, dy_m: np.ndarray, dz_m: np.ndarray) -> "Returns":
        """The returns of a trace made on a copy of the surface displaced by (-dx, -dy, -dz)
        per shot, put back in place: the scattering points move by (dx, dy, dz) and the
        round-trip times by -2 dz / c (float64). ``dx_m``, ``dy_m``, ``dz_m``: (n_shots,) [m]."""
        s = self.shot
        out = {k: getattr(self, k) for k in self.ARRAYS}
        dz = np.asarray(dz_m, np.float64)[s]
        if np.any(dz):
            out["time_ns"] = self.time_ns - 2.0 * dz / C_M_PER_NS
            out["z_m"] = (self.z_m + dz).astype(np.float32)
        for key, d in (("x_m", dx_m), ("y_m", dy_m)):
            d = np.asarray(d, np.float64)[s]
            if np.any(d):
                out[key] = (getattr(self, key) + d).astype(np.float32)
        return Returns(**out, n_shots=self.n_shots, paths_per_shot=self.paths_per_shot)

    @classmethod
    def concatenate(cls, parts: list[tuple["Returns", int]], *, n_shots: int) -> "Returns":
        """Join chunk traces ``[(returns, first_shot), ...]`` into one with global shots."""
        if not parts:
            return cls.empty(n_shots=n_shots, paths_per_shot=1)
        if len(parts) == 1 and parts[0][1] == 0:      # one chunk: no copy but the shots
            r = parts[0][0]
            out = {k: getattr(r, k) for k in cls.ARRAYS}
            out["shot"] = r.shot.astype(np.int64)
            return cls(**out, n_shots=int(n_shots), paths_per_shot=r.paths_per_shot)
        out = {k: np.concatenate([getattr(r, k) for r, _ in parts]) for k in cls.ARRAYS
               if k != "shot"}
        shot = np.empty(sum(len(r) for r, _ in parts), np.int64)   # one pass: widen and shift
        i = 0
        for r, a in parts:
            np.add(r.shot, a, out=shot[i:i + len(r)], casting="unsafe")
            i += len(r)
        return cls(**out, shot=shot, n_shots=int(n_shots),
                   paths_per_shot=parts[0][0].paths_per_shot)
