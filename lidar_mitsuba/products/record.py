"""The records the product writers read: one beam's run (:class:`BeamRun`) and a granule's
beams with what their files' headers say (:class:`Granule`).

Every writer takes these and nothing else: a single-beam run
(:func:`lidar_mitsuba.products.atl03.write`), a granule over a DEM
(:mod:`lidar_mitsuba.granule`, whole or section by section) and a real granule's twin
(:mod:`lidar_mitsuba.twin`) all hand the ATL03 and ATL06 writers a :class:`BeamRun` per beam
(or per section of a beam).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geotrack import Beam, GeoTrack, beam_layout

#: ATL03 geolocation segment length [m] (ATL03 ATBD: 20 m along-track geolocation segments);
#: here, with no h5py, for the simulating side's sections (lidar_mitsuba.granule)
SEGMENT_M = 20.0

#: the beam group a single-beam file uses for each beam strength (spacecraft orientation 0)
BEAM_GROUPS = {"strong": "gt1l", "weak": "gt1r"}


@dataclass
class BeamRun:
    """One beam's run, or one section of it.

    Attributes:
        beam: the :class:`~lidar_mitsuba.geotrack.Beam`.
        result: its :class:`~lidar_mitsuba.run.SimulationResult`; its ``geolocation`` places
            the shots on the Earth.
        first_shot: index of the result's first shot in the beam's whole track (a granule
            streamed in sections; else 0).
    """
    beam: Beam
    result: object
    first_shot: int = 0

    @classmethod
    def single(cls, result) -> BeamRun:
        """A single-beam run as beam ``gt1l`` (strong) or ``gt1r`` (weak) of a granule at
        spacecraft orientation 0."""
        if result.geolocation is None:
            raise ValueError("the result has no geolocation (simulate() gives every run one)")
        name = BEAM_GROUPS[result.instrument.beam]
        return cls(beam={b.name: b for b in beam_layout(0)}[name], result=result)

    @property
    def lat_deg(self) -> np.ndarray:
        """(n_shots,) footprint centres' latitude [deg]."""
        return self.result.geolocation.lat_deg

    @property
    def lon_deg(self) -> np.ndarray:
        """(n_shots,) footprint centres' longitude [deg]."""
        return self.result.geolocation.lon_deg

    @property
    def azimuth_deg(self) -> np.ndarray:
        """(n_shots,) direction of travel [deg clockwise from north]."""
        return self.result.geolocation.azimuth_deg

    @property
    def delta_time_s(self) -> np.ndarray:
        """(n_shots,) transmit times [s since 2018-01-01T00:00:00Z]."""
        return self.result.geolocation.delta_time_s


@dataclass
class Granule:
    """Beams simulated along one reference ground track.

    Attributes:
        beams: the :class:`BeamRun` of each beam simulated.
        sc_orient: spacecraft orientation (0 backward, 1 forward).
        crs: the CRS of the positions in ``/truth``; frame_origin_m: its (x, y) [m] at the
            simulation frame's origin.
        track: the reference ground track (None for a single-beam run).
        config: the run's settings (the files' ``config`` attribute).
        orbit: ``orbit_info`` labels of a repeat-orbit track (``rgt``, ``cycle_number``,
            ``orbit_number``), or empty (0 in the files: a track of one's own).
    """
    beams: list[BeamRun]
    sc_orient: int
    crs: str
    frame_origin_m: tuple[float, float]
    track: GeoTrack | None = None
    config: dict = field(default_factory=dict)
    orbit: dict = field(default_factory=dict)

    @classmethod
    def single(cls, result) -> Granule:
        """A single-beam run as a one-beam granule, its scene's frame an azimuthal
        equidistant projection about the run's site."""
        site = result.config.get("site")
        crs = ("unknown" if site is None else f"+proj=aeqd +lat_0={site['lat_deg']!r} "
               f"+lon_0={site['lon_deg']!r} +x_0=0 +y_0=0 +ellps=WGS84 +units=m")
        return cls(beams=[BeamRun.single(result)], sc_orient=0, crs=crs,
                   frame_origin_m=(0.0, 0.0), config=result.config)

    def span(self) -> tuple[list, float, float]:
        """``([(beam, instrument), ...], t_first, t_last)``: the files' headers' beams and
        first and last shot times [s since 2018-01-01]."""
        return ([(r.beam, r.result.instrument) for r in self.beams],
                min(float(r.delta_time_s[0]) for r in self.beams),
                max(float(r.delta_time_s[-1]) for r in self.beams))
