"""A granule: up to six ICESat-2 beams along a real ground track over a GeoTIFF DEM, written
as ATL03 and ATL06 files with the field names, dtypes, units and attributes that ICESat-2
readers use.

>>> from lidar_mitsuba import dem, geotrack, granule
>>> g = granule.simulate_granule(surface=dem.DEMSurface(dem.DEM.open("dem.tif")),
...                              track=geotrack.GeoTrack(start_lat_deg=69.95, start_lon_deg=-45,
...                                                      azimuth_deg=0), shots=2000)  # doctest: +SKIP
>>> granule.write_atl03(g, "ATL03_sim.h5"); granule.write_atl06(g, "ATL06_sim.h5")  # doctest: +SKIP

**ATL03** (``write_atl03``; the writer is :mod:`lidar_mitsuba.products.atl03.beam` and
:mod:`lidar_mitsuba.products.atl03.file`, shared with the single-beam files of
:func:`lidar_mitsuba.products.atl03.write`): per beam group ``gtXx`` every dataset of a real granule's
``heights/``, ``geolocation/`` (20 m segments from the track's first shot), ``bckgrd_atlas/``
(every 50 shots), ``geophys_corr/`` and ``signal_find_output/<surface type>/``, with ATL03's
names, dtypes, shapes, units and fill values (:mod:`lidar_mitsuba.products.atl03.fields` lists them and
what the simulation writes in each); ``ancillary_data/``, ``atlas_impulse_response/``,
``orbit_info/``, ``METADATA/``; the beam attributes ``atlas_beam_type``,
``atlas_spot_number``, ``atlas_pce``, ``groundtrack_id``, ``sc_orientation``; and
``/truth/gtXx/{photons,shots}``, the simulation truth, with ``/truth`` attributes ``crs`` and
``frame_origin_m``: truth positions are in the DEM's CRS less that origin.

**ATL06** (``write_atl06``): ``gtXx/land_ice_segments/{h_li, h_li_sigma, latitude,
longitude, delta_time, segment_id, atl06_quality_summary, sigma_geo_h}`` and the subgroups
``fit_statistics``, ``bias_correction``, ``geophysical``, ``ground_track``, ``dem``, from
:func:`lidar_mitsuba.products.atl06.segments_from_result` (40 m segments every 20 m).
"""
from __future__ import annotations

import os
import pathlib
from dataclasses import dataclass, replace

import numpy as np

from . import geotrack, granule_writer, machine, precompile as warmup
from .ground.snow import kernel as snow_kernel
from .constants import ParameterError, check
from .ground.dem import DEMSurface
from .ground.snow import SnowVolume
from .geotrack import Beam, GeoTrack
from .products.record import SEGMENT_M, BeamRun, Granule
from .instrument import INSTRUMENT_PRESETS, Instrument


def simulate_granule(*, surface: DEMSurface, track: GeoTrack, shots: int,
                     beams: str | list[Beam] = "all", sc_orient: int = 0,
                     instrument_options: dict | None = None, instrument: str = "paper",
                     seed: int = 0, paths_per_shot: int | str = "auto",
                     max_depth: int | str = "auto", progress: bool = True,
                     **simulate_options) -> Granule:
    """Simulate ``shots`` shots of each of ``beams`` along ``track`` over a DEM.

    >>> import lidar_mitsuba as lm
    >>> dem = lm.DEMSurface(lm.DEM.open("demo_dem.tif"))                 # doctest: +SKIP
    >>> track = lm.GeoTrack.parse("69.97,-45,0")                         # doctest: +SKIP
    >>> g = lm.simulate_granule(surface=dem, track=track, shots=2000)   # doctest: +SKIP

    Args:
        surface: the DEM surface (its ``origin_m`` is set here, near the track's start).
        track: the reference ground track (:class:`~lidar_mitsuba.geotrack.GeoTrack`), or a
            real granule's shots (:class:`~lidar_mitsuba.twin.TwinGranule`: its twin).
        shots: shots per beam (a twin: at most that many of each beam's, ``None``: all).
        beams: ``"all"``, ``"strong"``, ``"weak"``, names (``"gt1l,gt2l"``) or a list of beams.
        sc_orient: 0 backward (left beams strong), 1 forward.
        instrument_options: :class:`~lidar_mitsuba.instrument.Instrument` fields shared by the
            beams (``beam`` is set per beam: strong beams carry four times the weak ones' energy).
        instrument: ``"paper"`` (Zhang & Kerekes' instrument, ``Instrument(**options)``) or
            ``"atlas"`` (ATLAS as flown, ``Instrument.atlas(beam, **options)``: signal and
            background from its link budget).
        seed: the granule's seed; each beam runs with its own stream.
        paths_per_shot, max_depth, progress, simulate_options: as
            :func:`~lidar_mitsuba.run.simulate`.
    """
    from .run import assemble, stream
    if isinstance(beams, str):
        beams = geotrack.select_beams(beams, sc_orient)
    ctx = _Context(surface, track, instrument_options, instrument, beams)
    keep = simulate_options.pop("keep_returns", False)
    runs = []
    for beam in _beam_bar(beams, progress):
        p = ctx.plan(beam, track.beam_shot_count(beam, shots), seed=_beam_seed(seed, beam),
                     progress=progress, paths_per_shot=paths_per_shot, max_depth=max_depth,
                     **simulate_options)
        runs.append(BeamRun(beam=beam, result=assemble(p, stream(p, keep_returns=keep,
                                                                 progress=progress))))
    return Granule(beams=runs, sc_orient=int(sc_orient), crs=ctx.surface.dem.crs.to_string(),
                   frame_origin_m=ctx.origin, track=track,
                   config=ctx.config(shots=shots, seed=seed, sc_orient=sc_orient, beams=beams))


def _beam_seed(seed: int, beam: Beam, section: int | None = None) -> int:
    key = [int(seed), beam.spot] + ([] if section is None else [int(section)])
    return int(np.random.SeedSequence(key).generate_state(1)[0])


class _Context:
    """What every beam and section of a granule shares: the surface in a frame near the
    track's start, the CRS transform, the instrument options."""

    def __init__(self, surface: DEMSurface, track: GeoTrack, instrument_options: dict | None,
                 preset: str = "paper", beams: list[Beam] = ()):
        from pyproj import Transformer
        self.opts = dict(instrument_options or {})
        if "beam" in self.opts:
            raise ParameterError("beam", "is set per beam in a granule (use beams=)")
        check("instrument", preset, preset in INSTRUMENT_PRESETS,
              f"must be one of {', '.join(INSTRUMENT_PRESETS)}")
        self.preset = preset
        self.base = self.instrument(None)
        self.track = track
        self.to_crs = Transformer.from_crs("EPSG:4326", surface.dem.crs, always_xy=True)
        lat0, lon0 = track.start_lat_lon(spacing_m=self.base.shot_spacing_m)
        x0, y0 = self.to_crs.transform(lon0, lat0)
        self.origin = (float(np.round(x0, -3)), float(np.round(y0, -3)))
        self.surface = surface.with_origin(self.origin)     # a DEM, or a forest over one
        self.places = geotrack.SectionPlaces(track, self.to_crs, beams=beams,
                                             spacing_m=self.base.shot_spacing_m,
                                             prf_hz=self.base.prf_hz)

    def instrument(self, beam: Beam | None) -> Instrument:
        """The instrument of ``beam`` (``None``: a strong beam, for what all beams share)."""
        strength = "strong" if beam is None else beam.strength
        if self.preset == "atlas":
            return Instrument.atlas(strength, **self.opts)
        return Instrument(**self.opts, beam=strength)

    def projected(self, beam: Beam, first: int, n: int) -> geotrack.ProjectedTrack:
        """Shots ``first`` .. ``first + n - 1`` of ``beam`` in the granule's frame, with
        their geolocation."""
        geo, along, x, y = self.places(beam, first, n)      # (a section's beams together)
        if not (np.isfinite(x).all() and np.isfinite(y).all()):
            raise ParameterError("track", f"{beam.name}: the track leaves the DEM's projection "
                                 f"({self.surface.dem.crs.to_string()})")
        return geotrack.ProjectedTrack(
            x_m=np.asarray(x) - self.origin[0], y_m=np.asarray(y) - self.origin[1],
            along_m=along, info={"reference_track": self.track.to_dict(), "beam": beam.name,
                                 "across_m": beam.across_m, "first_shot": int(first)},
            geolocation=geo)

    def plan(self, beam: Beam, n: int, *, seed: int, first: int = 0, surface=None, **plan_kw):
        """The plan of ``beam``'s shots ``first`` .. ``first + n - 1``
        (:func:`lidar_mitsuba.planning.plan`) on ``surface`` (default the granule's)."""
        from .planning import plan
        try:
            return plan(instrument=self.instrument(beam),
                        surface=self.surface if surface is None else surface,
                        track=self.projected(beam, first, n), shots=n, seed=seed, **plan_kw)
        except ParameterError as e:
            raise ParameterError(e.name, f"{beam.name}: {e.message}") from None

    def config(self, *, shots, seed, sc_orient, beams, **extra) -> dict:
        return {"shots": int(shots), "seed": int(seed), "sc_orient": int(sc_orient),
                "beams": [b.name for b in beams], "track": self.track.to_dict(),
                "surface": self.surface.config(), "instrument": self.preset,
                "instrument_options": self.opts, **extra}


def _beam_bar(beams, progress):
    if not progress or len(beams) < 2:
        return beams
    from tqdm.auto import tqdm
    return tqdm(beams, desc="beams", unit="beam", leave=False)


# --------------------------------------------------------------------------- files
def write_atl03(granule: Granule, path: str | os.PathLike) -> pathlib.Path:
    """Write ``granule`` as an ATL03 file (see the module docstring), atomically
    (:func:`lidar_mitsuba.granule_products.write_atl03`)."""
    from . import granule_products
    return granule_products.write_atl03(granule, path)


def write_atl06(granule: Granule, path: str | os.PathLike, **options) -> pathlib.Path:
    """Fit ATL06 segments to every beam and write them with ATL06's names, atomically
    (:func:`lidar_mitsuba.granule_products.write_atl06`, ``options`` passed on)."""
    from . import granule_products
    return granule_products.write_atl06(granule, path, **options)


# --------------------------------------------------------------------------- streamed granules
SECTION_SHOTS = 1 << 16
"""Shots per section of a streamed granule (about 46 km): memory is bounded by a section."""


@dataclass
class BeamSummary:
    """Running statistics of one beam of a streamed granule (signal photons' h - z_ref).

    Attributes: beam; shots; photons (signal); bias_m, std_m [m]; bias_se_m [m];
    config: the first section's run config (its modelling choices).
    """
    beam: Beam
    shots: int = 0
    photons: int = 0
    sum_m: float = 0.0
    sum2_m2: float = 0.0
    config: dict | None = None

    def add(self, res) -> None:
        dh = res.dh_m[res.detections.is_signal]
        dh = dh[np.isfinite(dh)]
        self.shots += res.n_shots
        self.photons += int(dh.size)
        self.sum_m += float(dh.sum())          # (dh is centimetres to metres: sums of
        self.sum2_m2 += float(np.sum(dh * dh))  # squares lose nothing in float64)
        if self.config is None:
            self.config = res.config

    @property
    def bias_m(self) -> float:
        return self.sum_m / self.photons if self.photons else float("nan")

    @property
    def std_m(self) -> float:
        n = self.photons
        if n < 2:
            return float("nan")
        return float(np.sqrt(max(self.sum2_m2 - n * self.bias_m ** 2, 0.0) / (n - 1)))

    @property
    def bias_se_m(self) -> float:
        return self.std_m / np.sqrt(self.photons) if self.photons > 1 else float("nan")


def section_bounds(n_shots: int, *, spacing_m: float, section_shots: int,
                   along_m: np.ndarray | None = None) -> list[tuple[int, int]]:
    """``[(first, stop), ...]`` shot ranges of about ``section_shots`` shots, each starting
    on the first shot of a 20 m geolocation segment (so sections hold whole segments); shots
    are ``spacing_m`` apart along the track, or at ``along_m`` [m] ((n_shots,)) when given."""
    if along_m is None:
        seg = lambda i: int(np.floor(i * spacing_m / SEGMENT_M))    # noqa: E731 (as _segments)
    else:
        seg = lambda i: int(np.floor(along_m[i] / SEGMENT_M))      # noqa: E731
    cuts = [0]
    i = section_shots
    while i < n_shots:
        k = seg(i)
        j = i
        while j > cuts[-1] and seg(j - 1) == k:     # back to the segment's first shot
            j -= 1
        if j > cuts[-1]:
            cuts.append(j)
        i += section_shots
    cuts.append(n_shots)
    return list(zip(cuts[:-1], cuts[1:]))


def _along_of(track, beam: Beam, n_shots: int, spacing_m: float) -> np.ndarray | None:
    """A reference track's along-track distances of ``beam``'s shots when they are not
    ``spacing_m`` apart (a real granule's twin), else ``None``."""
    if isinstance(track, GeoTrack):
        return None
    return track.beam_geolocation(beam, 0, n_shots)[1]


def stream_granule(*, surface: DEMSurface, track: GeoTrack, shots: int,
                   atl03_path: str | os.PathLike, atl06_path: str | os.PathLike | None = None,
                   beams: str | list[Beam] = "all", sc_orient: int = 0,
                   instrument_options: dict | None = None, instrument: str = "paper",
                   seed: int = 0, paths_per_shot: int | str = "auto",
                   max_depth: int | str = "auto", atl08_path: str | os.PathLike | None = None,
                   progress: bool = True, section_shots: int = SECTION_SHOTS,
                   segment_options: dict | None = None, orbit_info: dict | None = None,
                   writer: str | None = None, **simulate_options) -> list[BeamSummary]:
    """Simulate a granule section by section straight into its ATL03 (and ATL06) files, so
    memory is bounded by a section (``section_shots`` shots) for a track of any length.

    Arguments as :func:`simulate_granule`. Each beam is planned once, on its first section
    (:func:`lidar_mitsuba.planning.plan`: the material, depth, paths per shot and integrator; with
    ``max_depth="auto"`` and ``paths_per_shot="auto"``, its pilot and scout trace its first tile);
    every later section is laid out with that model
    (:meth:`~lidar_mitsuba.planning.RunPlan.section`), each section an independent draw with its
    own seed. ATL06 segments are fitted across section boundaries
    (:class:`lidar_mitsuba.granule_products._SegmentStream`, in the process that writes).
    Both files are written atomically: a failure leaves neither. ``snow`` may be a function
    ``snow(beam, k)`` giving the :class:`~lidar_mitsuba.ground.snow.SnowVolume` (or None) of
    section ``k`` of ``beam`` (``section_bounds`` gives the sections): snow that varies along and
    across the track, a section planned anew where its snow differs from the one before (equal
    snow: the same plan). Likewise ``roughness(beam, k)``: the roughness heightfield (or None) of
    the section, on ``surface``, planned anew where it is not the same object as the one before.
    ``orbit_info``: the files' ``orbit_info`` labels. ``writer``: where the files are written
    (:func:`lidar_mitsuba.granule_writer.writer`: ``"process"`` beside the simulation, the POSIX
    default, or ``"inline"``; the same files). ``atl08_path``: also our ATL08 of the ATL03
    (:mod:`lidar_mitsuba.products.atl08.granule`). Returns each beam's statistics.
    """
    simulate_options.pop("keep_returns", None)     # sections keep no traced returns
    if isinstance(beams, str):
        beams = geotrack.select_beams(beams, sc_orient)
    if not (isinstance(section_shots, (int, np.integer)) and section_shots >= 1):
        raise ParameterError("section_shots", f"must be an integer >= 1 (got {section_shots!r})")
    ctx = _Context(surface, track, instrument_options, instrument, beams)
    spacing = ctx.base.shot_spacing_m
    streams = [_BeamStream(b, track, shots, spacing=spacing, section_shots=int(section_shots))
               for b in beams]
    n_sections = max(len(st.bounds) for st in streams)
    t_first, t_last = track.time_span_s(shots, prf_hz=ctx.base.prf_hz)
    meta = Granule(beams=[], sc_orient=int(sc_orient), crs=ctx.surface.dem.crs.to_string(),
                   frame_origin_m=ctx.origin, track=track, orbit=dict(orbit_info or {}),
                   config=ctx.config(shots=shots, seed=seed, sc_orient=sc_orient, beams=beams,
                                     sections=n_sections))
    instruments = [(b, ctx.instrument(b)) for b in beams]
    seg_options = _segment_options(segment_options, n_segments=max(
        st.n_shots for st in streams) * spacing / SEGMENT_M)
    snow = simulate_options.get("snow")
    if isinstance(snow, SnowVolume) and simulate_options.get("snow_model", "auto") != "walk":
        snow_kernel.table(snow, progress=progress)    # the snow's kernel, before the bar
    bar = None
    if progress:      # a first run on this machine compiles the kernels: say so
        from tqdm.auto import tqdm
        warmup.compile_kernels(atl06=seg_options.get("engine") == "compiled", atl03=True)
        bar = tqdm(total=sum(st.n_shots for st in streams), desc="granule", unit="shot",
                   delay=2.0, leave=False)
    files = granule_writer.writer(writer)
    try:
        opened = dict(meta=meta, instruments=instruments, t_first=t_first, t_last=t_last,
                      atl03_path=atl03_path, atl06_path=atl06_path, sc_orient=sc_orient,
                      segment_options=seg_options, beams=beams)
        if files is None:                   # in this thread
            files = granule_writer.GranuleFiles(**opened)
        else:                               # in the writer process
            files.open(**opened)
        _sections(streams, n_sections, ctx, files, bar, seed=seed, sc_orient=sc_orient,
                  paths_per_shot=paths_per_shot, max_depth=max_depth, **simulate_options)
        files.close()
    except BaseException:
        if files is not None:
            files.abort()
        raise
    finally:
        if bar is not None:
            bar.close()
    if atl08_path is not None:                   # the land product, from the ATL03 file
        _atl08().write_from_atl03(atl03_path, atl08_path, instrument=instruments[0][1])
    return [st.summary for st in streams]


def _segment_options(options: dict | None, *, n_segments: float) -> dict:
    """The ATL06 fits' options: the compiled fit for every section of a track of at least
    :data:`~lidar_mitsuba.products.atl06.COMPILE_MIN_SEGMENTS` 20 m segments (one engine for
    every section of a long track, its short last section too), unless ``options`` say."""
    from .products.atl06 import COMPILE_MIN_SEGMENTS     # (numpy and scipy only: no h5py)
    options = dict(options or {})
    if n_segments >= COMPILE_MIN_SEGMENTS:
        options.setdefault("engine", "compiled")
    return options


def _atl08():
    """:mod:`lidar_mitsuba.products.atl08.granule`, imported when a granule asks for ATL08
    (its classifier's scipy.stats would add ~0.5 s to every process's start)."""
    from .products.atl08 import granule
    return granule


def _sections(streams, n_sections: int, ctx, files, bar, **kw) -> None:
    """Simulate every beam's sections, section by section (a section's beams in turn), into
    ``files`` (a :class:`~lidar_mitsuba.granule_writer.GranuleFiles` or the writer process),
    the progress ``bar`` following, with Dr.Jit's pool one thread short of the cores
    (:func:`lidar_mitsuba.machine.trace_threads`: its idle workers spin for the CPU that
    this thread and the writer need)."""
    with machine.trace_threads():
        for k in range(n_sections):
            for st in streams:
                done = st.section(k, ctx, files, **kw)
                if bar is not None:
                    bar.update(done)


class _BeamStream:
    """One beam of a streamed granule: planned once, on its first section (the pilot and the
    scout trace its first tile), every later section laid out with that plan's model
    (:meth:`~lidar_mitsuba.planning.RunPlan.section`) and its own seed; its ATL06 segments
    across sections and its running statistics."""

    def __init__(self, beam: Beam, track, shots: int, *, spacing: float, section_shots: int):
        self.beam = beam
        self.n_shots = track.beam_shot_count(beam, shots)
        self.bounds = section_bounds(self.n_shots, spacing_m=spacing,
                                     section_shots=section_shots,
                                     along_m=_along_of(track, beam, self.n_shots, spacing))
        self.plan = None
        self.summary = BeamSummary(beam=beam)

    def section(self, k: int, ctx: _Context, files, *, seed: int, sc_orient: int,
                **plan_kw) -> int:
        """Simulate section ``k`` (if the beam has it) and hand it to ``files`` (its ATL03
        rows and ATL06 fit); returns its shots."""
        from .run import assemble, stream
        if k >= len(self.bounds):
            return 0
        a, b = self.bounds[k]
        snow = plan_kw.pop("snow", None)
        if callable(snow):                      # the snow of this beam's section
            snow = snow(self.beam, k)
        if snow is not None:
            plan_kw["snow"] = snow
        else:
            plan_kw.pop("snow_model", None)
        rough = plan_kw.pop("roughness", None)  # the roughness of this beam's section
        surface = ctx.surface if rough is None else replace(ctx.surface,
                                                            roughness=rough(self.beam, k))
        replanned = self.plan is not None and (
            snow != self.plan.snow or surface.roughness is not self.plan.surface.roughness)
        if self.plan is None or replanned:
            # the first section's plan decides the beam's model, and so does a section whose
            # snow (a new material) or roughness (a new surface) differs
            part = self.plan = ctx.plan(self.beam, b - a, first=a, progress=False,
                                        surface=surface, seed=_beam_seed(seed, self.beam, k),
                                        **plan_kw)
        else:
            part = self.plan.section(ctx.projected(self.beam, a, b - a), shots=b - a,
                                     seed=_beam_seed(seed, self.beam, k))
        run = BeamRun(beam=self.beam, result=assemble(part, stream(part, keep_returns=False)),
                      first_shot=a)
        files.section(run, replanned=replanned, last=k == len(self.bounds) - 1)
        self.summary.add(run.result)
        return b - a
