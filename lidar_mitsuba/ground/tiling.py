"""Tilings: the scenes a track's shots are traced in, chunk by chunk.

Every surface (:meth:`lidar_mitsuba.ground.surface.Surface.tiles`) yields a :class:`Tiling`:
:class:`OneTile` (one scene for every chunk: planes, heightfield tiles, Mitsuba scenes) or a
:class:`ChunkTiles` (a tile built per chunk of shots: a DEM's corridor tiles, a forest's).
Every name here is also importable from :mod:`lidar_mitsuba.ground.surface`.
"""
from __future__ import annotations

import numpy as np


class Tiling:
    """The scenes a track's shots are traced in, chunk by chunk: what every surface yields
    (:meth:`Surface.tiles`), so that nothing downstream asks which kind of surface it has.

    Attributes: ``scene``, ``x_local_m``, ``y_local_m`` and ``triangles``: the first
    chunk's scene, its shots' positions in it [m] (the bounce pilot's and the path scout's)
    and its size; ``chunk_shots``: the shots per chunk the stream must use."""
    scene = None
    x_local_m: np.ndarray
    y_local_m: np.ndarray
    triangles: int = 0
    chunk_shots: int = 1

    def tile(self, a: int, b: int, prepared=None):
        """``(scene, x_local_m, y_local_m, offsets_m)`` of shots ``a`` .. ``b - 1``: the scene
        they are traced in, their positions in it, and three arrays (dx, dy, dz) [m] that
        put the returns back on the track (the integrator's ``offset_m``); ``prepared``: what
        a tiling's ``prepare(a, b)`` gave, the numpy part done ahead (:class:`ChunkTiles`)."""
        raise NotImplementedError

    def release(self) -> None:
        """Let go of the first chunk's scene once the stream has it (a live stale scene joins
        every later tile's kernel calls)."""

    def first_scene(self):
        """The first chunk's scene (built again if released: a diagnosis that needs it)."""
        return self.scene

    def narrow(self, reach_m: float) -> bool:
        """Mesh later tiles only ``reach_m`` [m] about the track (the bounce pilot found one
        bounce enough: the footprints are all the photons reach). Returns whether it does:
        one scene for every chunk keeps its mesh."""
        return False

    def stats(self) -> dict:
        """What the tiles cost (for the run's config), after the stream."""
        return {}

    def attach(self, integrator) -> None:
        """The loaded integrator every chunk is traced with (a tiling that sets a tile's own
        state on it, as a forest's canopy table over a DEM, keeps it)."""


class OneTile(Tiling):
    """One scene for every chunk (planes, heightfield tiles, Mitsuba scenes)."""

    def __init__(self, scene, triangles: int, *, x_local_m, y_local_m, offsets_m,
                 chunk_shots: int):
        self.scene, self.triangles, self.chunk_shots = scene, int(triangles), int(chunk_shots)
        self.x_local_m, self.y_local_m = x_local_m, y_local_m
        self.offsets_m = tuple(np.asarray(d, np.float64) for d in offsets_m)

    def tile(self, a: int, b: int, prepared=None):
        return (self.scene, self.x_local_m[a:b], self.y_local_m[a:b],
                tuple(d[a:b] for d in self.offsets_m))


class ChunkTiles(Tiling):
    """A tile per chunk of shots, built when the chunk is launched and dropped with its trace
    (memory: one or two tiles for any track): a DEM's corridor tiles
    (:class:`~lidar_mitsuba.ground.dem.CorridorTiles`) and a forest's
    (:mod:`lidar_mitsuba.vegetation.forest`). A subclass says how one chunk's tile is built
    (:meth:`_build`); the first chunk's is built here (the pilot and the scout trace it) and
    handed to the stream once.

    Attributes: ``x_m``, ``y_m`` (n,) the track's footprint centres [m] (float64),
    ``reach_m`` the corridor meshed about them [m], ``bsdf`` the ground's BSDF; ``count`` and
    ``max_triangles``: the tiles the stream built and the largest (:meth:`stats`)."""

    def __init__(self, x_m, y_m, *, reach_m: float, bsdf, chunk_shots: int):
        self.reach_m, self.bsdf = float(reach_m), bsdf
        self.x_m = np.asarray(x_m, np.float64)
        self.y_m = np.asarray(y_m, np.float64)
        self.chunk_shots = n = max(1, int(chunk_shots))
        self._first = self._build(0, min(n, self.x_m.size))
        self.scene, self.x_local_m, self.y_local_m, _, self.triangles = self._first[:5]
        self.count, self.max_triangles = 0, 0

    def _build(self, a: int, b: int, prepared=None) -> tuple:
        """``(scene, x_local_m, y_local_m, offsets_m, triangles, ...)`` of shots ``a`` ..
        ``b - 1`` (:meth:`Tiling.tile`'s four, the tile's triangles, and whatever a
        subclass's :meth:`_use` needs), from :meth:`prepare`'s ``prepared`` if given."""
        raise NotImplementedError

    def _use(self, built: tuple) -> None:
        """Called with a tile's :meth:`_build` tuple as it is handed to the stream."""

    def tile(self, a: int, b: int, prepared=None):
        if a == 0 and self._first is not None:
            out, self._first = self._first, None
        else:
            out = self._build(a, b, prepared)
        self.count += 1
        self.max_triangles = max(self.max_triangles, out[4])
        self._use(out)
        return out[:4]

    def release(self) -> None:
        self.scene = None

    def narrow(self, reach_m: float) -> bool:
        self.reach_m = float(reach_m)
        return True

    def first_scene(self):
        if self.scene is not None:
            return self.scene
        return self._build(0, min(self.chunk_shots, self.x_m.size))[0]

    def stats(self) -> dict:
        return {"tiles": self.count, "max_tile_triangles": self.max_triangles}
