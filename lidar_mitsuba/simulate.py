"""The Python API: simulate a ground track and get photons, references and statistics.

>>> import lidar_mitsuba
>>> from lidar_mitsuba.simulate import simulate
>>> from lidar_mitsuba.surface import SurfaceSpec
>>> from lidar_mitsuba.instrument import Instrument
>>> res = simulate(instrument=Instrument(beam="weak"), surface=SurfaceSpec(kind="fractal", p=1.8),
...                shots=1000, seed=1)                                    # doctest: +SKIP
>>> print(res.report().overall)                                          # doctest: +SKIP

One run: resolve the surface (:mod:`.surface`), lay out the track (:mod:`.track`), build the
scene over the track's corridor, choose the bounces (:mod:`.bounce_pilot`), then trace and
detect chunk by chunk (:mod:`.chunks`), and finally place and classify the photons.
"""
from __future__ import annotations

import dataclasses
import inspect
import pathlib
import time
import warnings
from dataclasses import dataclass, field

import mitsuba as mi
import numpy as np

from . import (bounce_pilot, chunks, classify, explain, materials, path_budget, radiometry,
               retrieval, scene as scn, snow_kernel, surface as surfaces, warmup)
from .constants import ParameterError, SimulationWarning
from .instrument import Instrument
from .photons import Detections, Returns
from .snow import SnowVolume, medium_events_cap
from .resources import check_memory
from .surface import SceneSurface, SurfaceSpec
from .geotrack import Geolocation, Site
from .track import Track, spread_shots
from .variant import set_variant

SNOW_MODELS = ("auto", "walk", "kernel")
"""How a snow volume is traced (``simulate(snow_model=...)``)."""


@dataclass
class SimulationResult:
    """Everything one run produced. Per-shot arrays have shape (shots,), per-photon (n_photons,).

    Attributes:
        instrument: the instrument simulated.
        config: the run's settings (JSON-serialisable).
        along_track_m: along-track distance of each footprint centre from the first [m].
        shot_x_m, shot_y_m: footprint centres in scene coordinates (the track's own frame,
            not folded into a tile) [m].
        surface_z_m: surface height at each footprint centre [m].
        z_ref_m: reference elevation, the Gaussian-footprint-weighted mean height [m].
        detections: the detected photon events (:class:`~lidar_mitsuba.photons.Detections`),
            scattering points in the frame of ``shot_x_m``, ``shot_y_m``.
        h_m: elevation of each detected photon [m].
        signal_conf: ATL03-style confidence of each photon, 0 (noise) to 4 (high), from
            :func:`lidar_mitsuba.classify.signal_confidence`.
        returns: the traced returns (:class:`~lidar_mitsuba.photons.Returns`, global shot
            indices), or ``None`` when not kept (``keep_returns``).
        timings_s: wall time of each stage [s].
        geolocation: each shot on the Earth (:class:`~lidar_mitsuba.geotrack.Geolocation`:
            latitude, longitude, direction of travel, time): the track's own (a DEM
            granule's) or the scene placed at the run's ``site``.
        radiometry: each shot's signal scale, background and sun
            (:class:`~lidar_mitsuba.radiometry.ShotRadiometry`) when the instrument has a link
            budget (``Instrument.atlas()``), else ``None``.
    """
    instrument: Instrument
    config: dict
    along_track_m: np.ndarray
    shot_x_m: np.ndarray
    shot_y_m: np.ndarray
    surface_z_m: np.ndarray
    z_ref_m: np.ndarray
    detections: Detections
    h_m: np.ndarray
    signal_conf: np.ndarray
    returns: Returns | None
    timings_s: dict = field(default_factory=dict)
    geolocation: Geolocation | None = None
    radiometry: radiometry.ShotRadiometry | None = None

    @property
    def n_shots(self) -> int:
        return int(self.along_track_m.size)

    @property
    def dh_m(self) -> np.ndarray:
        """(n_photons,) h - z_ref of every detected photon [m]."""
        return self.h_m - self.z_ref_m[self.detections.shot]

    def classification(self, *, min_conf: int = 2) -> dict:
        """Hit and false-alarm rates of ``signal_conf >= min_conf`` against the truth."""
        return classify.classification_rates(self.signal_conf, self.detections.is_signal,
                                             min_conf=min_conf)

    def report(self, *, window_shots: int = 1000) -> retrieval.StatsReport:
        """Bias and precision of the signal photons, overall, per window and per channel."""
        d = self.detections
        sig = d.is_signal
        return retrieval.elevation_report(
            dh_m=self.dh_m[sig], shot=d.shot[sig], channel=d.channel[sig], n_shots=self.n_shots,
            n_channels=self.instrument.channels, window_shots=window_shots)


def _check_run(shots, seed, paths_per_shot, max_depth, chunk_shots) -> None:
    def is_int(v):
        return isinstance(v, (int, np.integer)) and not isinstance(v, bool)
    if not is_int(shots) or not 1 <= shots <= 10 ** 8:
        raise ParameterError("shots", f"must be an integer in [1, 1e8] (got {shots!r})")
    if not is_int(seed) or not 0 <= seed < 2 ** 63:
        raise ParameterError("seed", f"must be an integer >= 0 (got {seed!r})")
    if paths_per_shot != "auto" and (not is_int(paths_per_shot)
                                     or not 1 <= paths_per_shot <= 10 ** 6):
        raise ParameterError("paths_per_shot", f"must be 'auto' or an integer in [1, 1e6] "
                             f"(got {paths_per_shot!r})")
    if not is_int(chunk_shots) or chunk_shots < 1:
        raise ParameterError("chunk_shots", f"must be an integer >= 1 (got {chunk_shots!r})")
    if max_depth != "auto" and (not is_int(max_depth) or not 1 <= max_depth <= 64):
        raise ParameterError("max_depth", f"must be 'auto' or an integer in [1, 64] "
                             f"(got {max_depth!r})")


def check_run(**kw) -> None:
    """Check ``simulate``'s run arguments (``shots``, ``seed``, ``paths_per_shot``,
    ``max_depth``, ``chunk_shots``) without running: those given in ``kw``, ``simulate``'s
    defaults for the others. Raises :class:`ParameterError` naming the bad one."""
    defaults = inspect.signature(simulate).parameters
    get = lambda name: kw.get(name, defaults[name].default)  # noqa: E731
    _check_run(get("shots"), get("seed"), get("paths_per_shot"), get("max_depth"),
               get("chunk_shots"))


#: bytes a run holds per shot (track, reference, gate, folding and per-shot detector arrays,
#: float64) and per detected photon (the Detections, heights, confidence, and the copies made
#: when chunks are joined and the output is written)
BYTES_PER_SHOT = 160
BYTES_PER_PHOTON = 150


def estimate_memory_bytes(instrument: Instrument, shots: int) -> float:
    """Peak memory of a run of ``shots`` shots [bytes], from the photons it expects to detect
    (signal at up to 1.5 times the flat plate's return, plus noise in the range gate)."""
    bg, dark = instrument.noise_per_shot
    photons = ((1.5 * instrument.signal_photons + bg) * instrument.fill_factor * instrument.pde
               + dark * instrument.channels)
    return shots * (BYTES_PER_SHOT + BYTES_PER_PHOTON * photons)


def _resolve_surface(*, surface, scene, scene_file, params, bsdf):
    """The run's :class:`~lidar_mitsuba.surface.Surface`, default BSDF and config."""
    given = [n for n, v in (("surface", surface), ("scene", scene), ("scene_file", scene_file))
             if v is not None]
    if len(given) > 1:
        raise ParameterError(given[1], f"give one of surface, scene and scene_file "
                             f"(got {' and '.join(given)})")
    if scene_file is not None and not isinstance(scene_file, (str, pathlib.PurePath)):
        raise ParameterError("scene_file", f"must be the path of a Mitsuba XML file (got a "
                             f"{type(scene_file).__name__}; pass a loaded scene as scene=)")
    source = scene if scene is not None else scene_file
    if source is not None:
        try:
            mi_scene, label = scn.load_scene(source, params=params)
        except ValueError as e:
            raise ParameterError("scene_file" if scene_file is not None else "scene",
                                 str(e)) from None
        surface = SceneSurface(mi_scene, source=label)
    elif params:
        raise ParameterError("params", "only apply to an XML scene (scene= or scene_file=)")
    surf, default_bsdf, cfg = surfaces.resolve(surface)
    if bsdf is not None and not surf.takes_bsdf:
        raise ParameterError("bsdf", "does not apply to a Mitsuba scene: it has its own BSDFs "
                             "(set them in the scene)")
    return surf, default_bsdf, cfg


def simulate(*, instrument: Instrument | None = None,
             surface: SurfaceSpec | surfaces.Surface | None = None,
             scene=None, scene_file: str | None = None, params: dict | None = None,
             bsdf: dict | None = None, shots: int = 1000, seed: int = 0,
             paths_per_shot: int | str = "auto", max_depth: int | str = "auto",
             track: Track | None = None, variant: str | None = None, progress: bool = True,
             chunk_shots: int = chunks.CHUNK_SHOTS, keep_returns: bool | None = None,
             crop_to_track: bool = True, snow: SnowVolume | None = None,
             snow_model: str = "auto", site: Site | None = None) -> SimulationResult:
    """Simulate ``shots`` laser shots along a ground track and detect their photons.

    Args:
        instrument: the lidar (default: strong beam, the paper's parameters).
        surface: a built-in surface (default: fractal p = 1.8, 10 m relief, Ward snow), or
            a ready :class:`~lidar_mitsuba.terrain.Heightfield` (e.g. your own DEM; periodic or
            not), :class:`~lidar_mitsuba.surface.Plane` (with the paper's Ward snow, or
            ``bsdf``) or :class:`~lidar_mitsuba.surface.SceneSurface`.
        scene: a Mitsuba scene instead of ``surface``: a loaded ``mi.Scene``, a scene dict or
            the path of an XML file (z up, metres; its own BSDFs). A ``<integrator
            type="pathlength">`` in it sets the run's max_depth, altitude, footprint, pulse
            and field of view wherever it gives them (giving another value here too is
            refused).
        scene_file: the path of a Mitsuba XML scene (the same as ``scene=`` with a path).
        params: values of the XML's ``<default name=...>`` parameters, e.g. ``{"slope_deg": 8}``.
        bsdf: a Mitsuba BSDF dict replacing a built-in surface's Ward BSDF.
        shots: number of laser shots (>= 1; as many as fit in memory, which is checked).
        seed: seed of the photon Monte Carlo and the detector (>= 0; same seed, same photons).
        paths_per_shot: photon paths traced per shot to sample its return, or ``"auto"``:
            the fewest (8 to 1024) that keep every detected photon on a path of its own and
            the Monte Carlo noise of each shot's mean photon count under 1 % of its Poisson
            variance, judged by a scout trace (:mod:`lidar_mitsuba.path_budget`; 16 for the
            strong beam on the default snow, 8 for the weak one). The choice and its numbers
            are in ``result.config["paths_per_shot"]`` and ``result.config["path_budget"]``.
        max_depth: surface interactions per photon path (1 = single bounce), or ``"auto"``
            (1 on a plane, where it is exact, elsewhere a two-bounce pilot decides: see
            :mod:`lidar_mitsuba.bounce_pilot`). The choice and its numbers are in
            ``result.config["max_depth"]`` and ``result.config["bounce_pilot"]``.
        track: where the shots go (:class:`~lidar_mitsuba.track.Track`; default: along +x
            through the middle of the surface).
        variant: Mitsuba variant (default: the active one, ``llvm_ad_mono``).
        progress: show a progress bar on runs longer than ~2 s.
        chunk_shots: shots traced and detected per chunk; memory stays bounded by the chunk
            (plus the detected photons) for any track length.
        keep_returns: keep every traced return in ``result.returns`` (default: only when the
            run traces at most 2^24 paths, about 0.5 GB).
        crop_to_track: mesh only the corridor the track's photons can reach (the footprints'
            5 sigma, or the receiver's field of view when ``max_depth > 1``) instead of the
            whole tile: the same answer from a much smaller mesh. ``False``: the full tile.
        snow: a snow volume under a built-in surface or a DEM
            (:func:`lidar_mitsuba.snow.snow_from_grains`), traced by the ``volpathlength``
            integrator instead of the surface BSDF (off by default). An XML scene gets its
            snow from a ``<medium>`` inside its terrain shape instead.
        snow_model: ``"walk"`` (the full random walk under each facet, the reference),
            ``"kernel"`` (the walk tabulated once per snowpack and cached,
            :mod:`lidar_mitsuba.snow_kernel`: the cost of a surface hit) or ``"auto"`` (the
            kernel). An XML scene's ``<medium>`` is always walked.
        site: where on the Earth and when the scene lies
            (:class:`~lidar_mitsuba.geotrack.Site`; default: the paper's site in northern
            Greenland at local noon on the June solstice, at sea level): photon latitudes,
            longitudes and times, and the sun and air of an instrument with a link budget. A
            track with its own geolocation (a DEM granule's) keeps its own places and times
            (only the site's height applies).

    Raises:
        ParameterError: a bad value, named (``.name``), before anything is traced.

    Warns:
        SimulationWarning: the run completed but deserves a look (no photons and why, shots
        with no surface under them, too few paths per shot, a mesh coarser than the footprint
        resolves); also listed in ``result.config["warnings"]``.
    """
    run = _resolve(instrument=instrument, surface=surface, scene=scene, scene_file=scene_file,
                   params=params, bsdf=bsdf, shots=shots, seed=seed,
                   paths_per_shot=paths_per_shot, max_depth=max_depth, variant=variant,
                   chunk_shots=chunk_shots, snow=snow, snow_model=snow_model)
    _lay_out(run, track or Track(), crop_to_track=crop_to_track)
    _choose_model(run, progress=progress)
    _place_on_earth(run, site or Site())
    chunked = _trace_and_detect(run, keep_returns=keep_returns, progress=progress)
    return _result(run, chunked)


@dataclass
class _Run:
    """A run's state as ``simulate``'s steps build it: what was asked (after checks), then the
    laid-out track and scene, the chosen model, the sky, and the timings of each step."""
    instrument: Instrument
    surf: surfaces.Surface
    surf_cfg: dict
    default_bsdf: dict | None
    bsdf: dict | None
    snow: SnowVolume | None
    shots: int
    seed: int
    paths_per_shot: int | str
    max_depth: int | str
    chunk_shots: int
    volume: bool
    snow_model: str = "walk"
    materials: materials.SceneMaterials | None = None
    max_lanes: int | None = None
    honoured: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    t0: float = field(default_factory=time.perf_counter)
    # _lay_out
    track: object = None
    along: np.ndarray | None = None
    x: np.ndarray | None = None
    y: np.ndarray | None = None
    x_loc: np.ndarray | None = None
    y_loc: np.ndarray | None = None
    dz: np.ndarray | None = None
    reach: float = 0.0
    bsdf_used: object = None
    scene: object = None
    first_tile: tuple | None = None
    triangles: int = 0
    crop: bool = True
    surface_z: np.ndarray | None = None
    z_ref: np.ndarray | None = None
    gate_z: np.ndarray | None = None
    # _choose_model
    pilot: dict | None = None
    budget: dict | None = None
    integrator_dict: dict | None = None
    integrator: object = None
    kernel: dict | None = None
    # _place_on_earth
    site: Site | None = None
    geoloc: Geolocation | None = None
    rad: radiometry.ShotRadiometry | None = None


def _resolve(*, instrument, surface, scene, scene_file, params, bsdf, shots, seed,
             paths_per_shot, max_depth, variant, chunk_shots, snow, snow_model) -> _Run:
    """Check the run's arguments, activate the variant, resolve the surface; a snow volume or
    a scene's medium and ``<integrator>`` settle the model's inputs."""
    instrument = instrument or Instrument()
    if snow is not None and not isinstance(snow, SnowVolume):
        raise ParameterError("snow", f"must be a SnowVolume (got {type(snow).__name__})")
    if snow_model not in SNOW_MODELS:
        raise ParameterError("snow_model", f"must be one of {', '.join(SNOW_MODELS)} "
                             f"(got {snow_model!r})")
    if snow_model != "auto" and snow is None:
        raise ParameterError("snow_model", "only applies with a snow volume (snow=, "
                             "--snow-grain-um)")
    _check_run(shots, seed, paths_per_shot,
               "auto" if snow is not None and max_depth == snow.events_cap else max_depth,
               chunk_shots)
    if variant is not None:
        try:
            set_variant(variant)
        except ValueError as e:
            raise ParameterError("variant", str(e)) from None
    t0 = time.perf_counter()
    surf, default_bsdf, surf_cfg = _resolve_surface(surface=surface, scene=scene,
                                                    scene_file=scene_file, params=params,
                                                    bsdf=bsdf)
    run = _Run(instrument=instrument, surf=surf, surf_cfg=surf_cfg, default_bsdf=default_bsdf,
               bsdf=bsdf, snow=snow, shots=shots, seed=seed, paths_per_shot=paths_per_shot,
               max_depth=max_depth, chunk_shots=chunk_shots, volume=snow is not None, t0=t0)
    if snow is not None:
        if isinstance(surf, SceneSurface):
            raise ParameterError("snow", "does not apply to a Mitsuba scene: put a <medium> "
                                 "inside its terrain shape (docs: README, snow)")
        if bsdf is not None:
            raise ParameterError("bsdf", "a snow volume replaces the surface BSDF: give one")
        if max_depth not in ("auto", snow.events_cap):
            raise ParameterError("max_depth", "with a snow volume the interactions per photon "
                                 "are the snow's max_events (--snow-max-events)")
        run.max_depth = snow.events_cap
        run.snow_model = "walk" if snow_model == "walk" else "kernel"
    if isinstance(surf, SceneSurface):
        _scene_materials(run)
    check_memory("shots", estimate_memory_bytes(run.instrument, shots),
                 f"a run of {shots} shots", "split the track into several runs")
    return run


def _scene_materials(run: _Run) -> None:
    """A scene's materials choose its model (:mod:`.materials`): snow under a surface is
    walked (``volpathlength``); water and layers in the air take ``mediapathlength`` with the
    vertices they need; the scene's ``<integrator>`` settings are honoured."""
    surf = run.surf
    try:
        run.materials = mats = materials.inspect(surf.scene)
        medium = scn.scene_medium(surf.scene) if mats.snow is not None else None
    except ValueError as e:
        raise ParameterError("scene", str(e)) from None
    run.volume = medium is not None
    run.instrument, run.max_depth, run.max_lanes, run.honoured = materials.scene_settings(
        surf.scene, run.instrument, run.max_depth)
    if run.volume and run.max_depth == "auto":
        run.max_depth = medium_events_cap(medium)
    if mats.needs_media_tracer:
        if run.max_depth == "auto":
            run.max_depth = mats.min_depth(run.instrument.fov_diameter_m / 2)
        if mats.air_layers:      # heights and references: the ground under the layers
            run.surf = dataclasses.replace(surf, through_null=True)


def _lay_out(run: _Run, track, *, crop_to_track: bool) -> None:
    """The shots along the track, folded into the surface; the scene over the corridor the
    photons can reach (a streamed DEM: its first tile); heights and reference elevations."""
    inst, surf = run.instrument, run.surf
    margin = 5.0 * inst.footprint_sigma_m + 1.0
    run.track, run.crop = track, bool(crop_to_track)
    run.along, run.x, run.y = track.positions(run.shots, spacing_m=inst.shot_spacing_m,
                                              centre_xy_m=surf.centre_xy_m())
    run.x_loc, run.y_loc, run.dz = surf.fold(run.x, run.y, margin_m=margin)
    if run.max_depth == "auto" and surf.exact_single_bounce:
        run.max_depth = 1
    # mesh only the corridor the photons can reach: footprints (5 sigma) for single bounce;
    # the receiver's field of view when paths may bounce on
    run.reach = (margin if run.max_depth == 1 or run.volume
                 else max(margin, inst.fov_diameter_m / 2 + 5.0))
    run.bsdf_used = (run.snow if run.snow is not None else run.bsdf if run.bsdf is not None
                     else run.default_bsdf)
    if surf.streamed:       # a DEM: every chunk traces its own corridor tile
        run.chunk_shots = n = min(run.chunk_shots, surf.tile_shots)
        run.first_tile = surf.corridor_tile(run.x[:n], run.y[:n], reach_m=run.reach,
                                            bsdf=run.bsdf_used)
        run.scene, (ox, oy), run.triangles = run.first_tile
        run.x_loc, run.y_loc = run.x[:n] - ox, run.y[:n] - oy     # the pilot's tile
    else:
        bounds = None
        if crop_to_track:
            bounds = (float(run.x_loc.min()) - run.reach, float(run.x_loc.max()) + run.reach,
                      float(run.y_loc.min()) - run.reach, float(run.y_loc.max()) + run.reach)
        run.scene, run.triangles = surf.mitsuba_scene(bsdf=run.bsdf_used, margin_m=run.reach,
                                                      bounds_m=bounds)
    top = float(scn.scene_bounds(run.scene)[1][2] + np.max(np.abs(run.dz), initial=0.0))
    if top + 1.0 >= inst.altitude_m:
        raise ParameterError("altitude_m", f"the spacecraft ({inst.altitude_m:g} m) must "
                             f"be above the scene, which reaches z = {top:g} m")
    if run.materials is not None:
        try:
            materials.refuse_mirrors(run.materials, run.scene, run.x_loc, run.y_loc, inst)
        except ValueError as e:
            raise ParameterError("scene", str(e)) from None
    run.surface_z = surf.height_m(run.x, run.y)
    run.z_ref = surf.reference_elevation_m(run.x, run.y, sigma_m=inst.footprint_sigma_m)
    run.gate_z = chunks.gate_heights_m(run.z_ref)
    if surf.takes_bsdf:
        run.surf_cfg.update(mesh_triangles=run.triangles, crop_to_track=run.crop)
    if run.bsdf is not None:
        run.surf_cfg["bsdf"] = repr(run.bsdf)
    run.timings["scene_s"] = time.perf_counter() - run.t0


def _choose_model(run: _Run, *, progress: bool = False) -> None:
    """The bounces (``max_depth="auto"``: the pilot), the integrator, and the paths per shot
    (``"auto"``: the scout)."""
    inst, ppp = run.instrument, run.paths_per_shot
    if run.max_depth == "auto":
        t1 = time.perf_counter()
        n_pilot = run.x_loc.size           # a streamed surface's pilot runs on its first tile
        run.pilot = bounce_pilot.run_pilot(
            scene=run.scene, instrument=inst, x_m=run.x_loc, y_m=run.y_loc,
            dz_m=run.dz[:n_pilot], z_ref_m=run.z_ref[:n_pilot],
            paths_per_shot=path_budget.SCOUT_PATHS if ppp == "auto" else int(ppp))
        run.max_depth = 1 if run.pilot["single_bounce_enough"] else 2
        run.timings["pilot_s"] = time.perf_counter() - t1
    lanes = {} if run.max_lanes is None else {"max_lanes": int(run.max_lanes)}
    d = inst.integrator_dict(max_depth=run.max_depth, **lanes)
    if run.volume and run.snow_model == "kernel":      # the walk, tabulated
        t1 = time.perf_counter()
        path, run.kernel = snow_kernel.table(run.snow, progress=progress)
        d = inst.integrator_dict(max_depth=1, **lanes)
        d.update(type="snowkernel", filename=str(path))
        run.timings["kernel_table_s"] = time.perf_counter() - t1
    elif run.materials is not None and run.materials.needs_media_tracer:
        d.update(type="mediapathlength", max_depth=int(run.max_depth),
                 **{k: v for k, v in run.honoured.items() if k == "group_index"})
    elif run.volume:             # one record per photon, whatever its interactions
        d.update(run.snow.integrator_params() if run.snow is not None else
                 {"type": "volpathlength", **{k: v for k, v in run.honoured.items()
                                              if k in ("group_index", "snow_depth_m",
                                                       "base_albedo")}})
        d["max_depth"] = int(run.max_depth)
    run.integrator_dict, run.integrator = d, mi.load_dict(d)
    if ppp == "auto":
        t1 = time.perf_counter()
        run.budget = path_budget.scout(run.integrator, run.scene, run.x_loc, run.y_loc, inst,
                            returns_per_path=1 if run.volume else int(run.max_depth),
                            per_path=d["type"] == "mediapathlength",
                            gate_z_m=run.gate_z if d["type"] == "mediapathlength" else None)
        run.paths_per_shot = run.budget["paths_per_shot"]
        run.timings["scout_s"] = time.perf_counter() - t1


def _place_on_earth(run: _Run, site: Site) -> None:
    """Each shot's place and time (the track's own, or the scene at ``site``) and, for an
    instrument with a link budget, its signal scale and background."""
    run.site = site
    run.geoloc = getattr(run.track, "geolocation", None)
    if run.geoloc is None:
        run.geoloc = site.geolocation(run.x, run.y, prf_hz=run.instrument.prf_hz)
    if run.instrument.link_budget is not None:
        t1 = time.perf_counter()
        run.rad = _shot_radiometry(run.instrument, run.geoloc, run.gate_z + site.height_m,
                                   scene=run.scene, x_m=run.x_loc, y_m=run.y_loc,
                                   snow=run.snow)
        run.timings["radiometry_s"] = time.perf_counter() - t1


def _trace_and_detect(run: _Run, *, keep_returns: bool | None,
                      progress: bool) -> chunks.ChunkedRun:
    """The chunk loop over the run's source: the scene, or a DEM's corridor tiles (the first
    tile goes with its chunk: a live stale scene would join every later tile's kernel calls;
    the rare diagnosis that needs it builds it again)."""
    ppp = int(run.paths_per_shot)
    if keep_returns is None:
        keep_returns = run.shots * ppp * (1 if run.volume else run.max_depth) <= 2 ** 24
    if run.surf.streamed:
        source = chunks.CorridorSource(run.integrator, run.surf, x_m=run.x, y_m=run.y,
                                       paths_per_shot=ppp, reach_m=run.reach,
                                       bsdf=run.bsdf_used, first=run.first_tile)
        run.first_tile = run.scene = None
    else:
        source = chunks.traced(run.integrator, run.scene, x_m=run.x_loc, y_m=run.y_loc,
                               paths_per_shot=ppp, dx_m=run.x - run.x_loc,
                               dy_m=run.y - run.y_loc, dz_m=run.dz)
    if run.materials is not None and run.materials.air_layers:
        source = chunks.GatedSource(source, gate_ns=run.instrument.range_gate_ns,
                                    gate_center_ns=chunks.gate_center_ns(run.instrument,
                                                                         run.z_ref))
    if progress:       # a first run on this machine compiles the detector: say so
        warmup.compile_kernels()
    chunked = chunks.run(
        source=source, detectors={"run": run.instrument}, z_ref_m=run.z_ref, seed=run.seed,
        chunk_shots=run.chunk_shots, keep_returns=keep_returns, progress=progress,
        detector_inputs=None if run.rad is None else run.rad.detector_inputs)
    run.timings.update(chunked.timings_s)
    if run.surf.streamed:
        run.surf_cfg.update(tiles=source.tiles, max_tile_triangles=source.triangles)
    return chunked


def _scene_of(run: _Run):
    """The scene of the run's first shots (a streamed DEM's first tile, built again)."""
    if run.scene is not None:
        return run.scene
    n = run.x_loc.size
    return run.surf.corridor_tile(run.x[:n], run.y[:n], reach_m=run.reach,
                                  bsdf=run.bsdf_used)[0]


def _result(run: _Run, chunked: chunks.ChunkedRun) -> SimulationResult:
    """Place and classify the photons, explain the run's choices and warn where it deserves
    a look, and gather the result."""
    inst, det = run.instrument, chunked.detections["run"]
    t3 = time.perf_counter()
    h = retrieval.photon_heights_m(det.time_ns, altitude_m=inst.altitude_m)
    conf = classify.signal_confidence(shot=det.shot, h_m=h, gate_center_h_m=run.gate_z,
                                      range_gate_m=inst.range_gate_m)
    run.timings["detect_s"] += time.perf_counter() - t3
    run.timings["total_s"] = time.perf_counter() - run.t0
    facet_m = run.surf_cfg.get("grid_m") or run.surf_cfg.get("mesh_grid_m")
    choices, warns = explain.choices_and_warnings(
        instrument=inst, surf=run.surf, max_depth=run.max_depth, pilot=run.pilot,
        paths_per_shot=run.paths_per_shot, budget=run.budget, crop=run.crop,
        triangles=run.triangles, det=det, volume=run.volume, snow=run.snow, shots=run.shots,
        timings=run.timings, kernel=run.kernel, facet_m=facet_m,
        media=(run.materials.describe(max_depth=run.max_depth,
                                      fov_radius_m=inst.fov_diameter_m / 2)
               if run.materials is not None and run.materials.needs_media_tracer else None))
    warns += explain.diagnose(surf=run.surf, scene_of=lambda: _scene_of(run), x_m=run.x_loc,
                       y_m=run.y_loc, surface_z=run.surface_z[:run.x_loc.size],
                       n_returns=chunked.n_returns, det=det, instrument=inst)
    for w in warns:
        warnings.warn(w, SimulationWarning, stacklevel=3)
    config = {"instrument": inst.to_dict(), "surface": run.surf_cfg,
              "track": run.track.to_dict(), "shots": int(run.shots), "seed": int(run.seed),
              "paths_per_shot": int(run.paths_per_shot), "path_budget": run.budget,
              "max_depth": int(run.max_depth), "bounce_pilot": run.pilot,
              "variant": mi.variant(), "scene_integrator": run.honoured, "choices": choices,
              "warnings": warns, "snow": run.snow.config() if run.snow is not None else None,
              "snow_model": run.snow_model if run.volume else None,
              "snow_kernel": snow_kernel.summary(run.kernel) if run.kernel is not None else None,
              "integrator": run.integrator_dict["type"], "site": run.site.to_dict(),
              "radiometry": None if run.rad is None else run.rad.summary()}
    return SimulationResult(instrument=inst, config=config, along_track_m=run.along,
                            shot_x_m=run.x, shot_y_m=run.y, surface_z_m=run.surface_z,
                            z_ref_m=run.z_ref, detections=det, h_m=h, signal_conf=conf,
                            returns=chunked.returns, timings_s=run.timings,
                            geolocation=run.geoloc, radiometry=run.rad)


def _shot_radiometry(instrument: Instrument, geoloc: Geolocation, z_m: np.ndarray, *, scene,
                     x_m, y_m, snow) -> radiometry.ShotRadiometry:
    """Each shot's signal scale and background (:func:`radiometry.shot_radiometry`): the sun
    where and when the shot is, the surface's albedo for sunlight from its own BSDF (a snow
    volume: diffusion theory's albedo), the air above the surface height ``z_m``."""
    if geoloc.solar_elevation_deg is not None:            # a real granule's own
        elev, azim = geoloc.solar_elevation_deg, geoloc.solar_azimuth_deg
    else:
        elev, azim = radiometry.solar_angles(geoloc.lat_deg, geoloc.lon_deg,
                                             geoloc.delta_time_s)
    if snow is not None:
        albedo = float(snow.diffusion().total_reflectance())
    else:
        pick = spread_shots(np.size(x_m), 5)
        albedo = scn.sunlit_albedo(scene, np.asarray(x_m)[pick], np.asarray(y_m)[pick],
                                   solar_elevation_deg=float(np.median(elev)),
                                   solar_azimuth_deg=float(np.median(azim)))
        if not np.isfinite(albedo):       # an XML scene's medium, or no surface in reach
            albedo = radiometry.DEFAULT_ALBEDO
    return radiometry.shot_radiometry(instrument, delta_time_s=geoloc.delta_time_s, z_m=z_m,
                                      albedo=albedo, solar_elevation_deg=elev,
                                      solar_azimuth_deg=azim)
