"""The ground track: where each shot's footprint centre lies, in scene coordinates [m].

Shots are ``shot_spacing_m`` apart along a straight line. By default the line runs along +x
(heading 0) through the middle of the surface (the centre of a built-in tile, or of an XML
scene's bounding box), centred on it; ``start_xy_m`` puts the first footprint elsewhere,
``heading_deg`` turns the line (counter-clockwise from +x: 90 runs along +y) and
``offset_m`` shifts it sideways (positive to the left of the direction of travel).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .constants import check


@dataclass(frozen=True)
class Track:
    """A straight ground track.

    Attributes:
        start_xy_m: (x, y) of the first footprint centre [m]; ``None``: the track is centred on
            the surface's middle.
        heading_deg: direction of travel [deg], counter-clockwise from +x.
        offset_m: across-track shift [m], positive to the left of the direction of travel.
    """
    start_xy_m: tuple[float, float] | None = None
    heading_deg: float = 0.0
    offset_m: float = 0.0

    def __post_init__(self):
        if self.start_xy_m is not None:
            xy = _numbers(self.start_xy_m)
            check("start_xy_m", self.start_xy_m, xy is not None and len(xy) == 2,
                  "must be two finite numbers (x, y)")
            object.__setattr__(self, "start_xy_m", xy)
        for name, bound in (("heading_deg", math.inf), ("offset_m", 1e7)):
            v = _numbers([getattr(self, name)])
            check(name, getattr(self, name), v is not None and abs(v[0]) <= bound,
                  "must be a finite number" + (f" of magnitude <= {bound:g}"
                                               if math.isfinite(bound) else ""))
            object.__setattr__(self, name, v[0])

    @property
    def direction(self) -> tuple[float, float]:
        """Unit vector of the direction of travel (x, y)."""
        h = math.radians(self.heading_deg)
        return math.cos(h), math.sin(h)

    def positions(self, n_shots: int, *, spacing_m: float,
                  centre_xy_m: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(along_track_m, x_m, y_m)``, each (n_shots,) float64 [m]: the distance of each
        footprint from the first, and its centre. ``centre_xy_m`` is the surface's middle,
        used when ``start_xy_m`` is None."""
        along = np.arange(int(n_shots)) * float(spacing_m)
        ux, uy = self.direction
        if self.start_xy_m is None:
            half = along[-1] / 2.0 if along.size else 0.0
            x0 = centre_xy_m[0] - half * ux - self.offset_m * uy
            y0 = centre_xy_m[1] - half * uy + self.offset_m * ux
        else:
            x0 = self.start_xy_m[0] - self.offset_m * uy
            y0 = self.start_xy_m[1] + self.offset_m * ux
        return along, x0 + along * ux, y0 + along * uy

    def to_dict(self) -> dict:
        return {"start_xy_m": None if self.start_xy_m is None else list(self.start_xy_m),
                "heading_deg": float(self.heading_deg), "offset_m": float(self.offset_m)}


def _numbers(values) -> tuple[float, ...] | None:
    """``values`` as a tuple of finite floats, or None when any is not one."""
    try:
        out = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        return None
    return out if all(math.isfinite(v) for v in out) else None


def spread_shots(n_shots: int, at_most: int) -> np.ndarray:
    """Indices of up to ``at_most`` shots spread evenly along a track of ``n_shots`` (first
    and last included; sorted, unique): where the bounce pilot and the path scout trace."""
    return np.unique(np.linspace(0, n_shots - 1, min(n_shots, at_most)).round()
                     .astype(np.int64))
