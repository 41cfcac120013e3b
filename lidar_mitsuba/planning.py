"""A run's plan: everything decided before a photon is traced (``lm.plan``).

:func:`plan` checks the arguments, resolves the surface and what a scene's materials need
(:mod:`.trace.materials`), lays out the track (positions, folding into a tile, the corridor
the photons can reach, heights and reference elevations), chooses the model (the bounces:
:mod:`.trace.pilot`; the integrator; the paths per shot: :mod:`.trace.path_budget`; a snow
kernel) and places the shots on the Earth (geolocation, radiometry). It returns a
:class:`RunPlan`: a frozen, printable value that :func:`lidar_mitsuba.run.stream` traces and
detects and :func:`lidar_mitsuba.run.assemble` turns into a result. ``simulate()`` is exactly
plan + stream + assemble.

>>> import lidar_mitsuba as lm
>>> p = lm.plan(surface=lm.SurfaceSpec(kind="fractal", p=1.8), shots=1000)  # doctest: +SKIP
>>> print(p)                   # the instrument, surface, depth, paths, integrator, ...
...                                                                       # doctest: +SKIP
>>> res = lm.assemble(p, lm.stream(p))                                    # doctest: +SKIP
"""
from __future__ import annotations

import dataclasses
import pathlib
import time
import types
from dataclasses import dataclass

import numpy as np

from . import radiometry
from .constants import ParameterError
from .geotrack import Geolocation, Site
from .ground import surface as surfaces
from .ground.snow import SnowVolume, medium_events_cap
from .ground.snow import kernel as snow_kernel
from .ground.surface import SceneSurface
from .instrument import Instrument
from .machine import check_memory
from .trace import path_budget, stream as chunks
from .trace.variant import ensure_renderer, set_variant
from .track import Track


SNOW_MODELS = ("auto", "walk", "kernel")
"""How a snow volume is traced (``simulate(snow_model=...)``)."""



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
    """The run's :class:`~lidar_mitsuba.ground.surface.Surface`, default BSDF and config."""
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
        from .trace import scene as scn
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


@dataclass(frozen=True, eq=False)
class RunPlan:
    """What a run will trace and how (:func:`plan`), frozen: ``print(plan)`` says it in words.

    Attributes (per-shot arrays have shape (shots,), lengths in [m]):
        instrument: the instrument after a scene's ``<integrator>`` overrides.
        surf, surf_cfg: the surface (:class:`~lidar_mitsuba.ground.surface.Surface`) and its
            config; default_bsdf, bsdf, bsdf_used: the built-in surface's BSDF, the one given,
            the one traced (a snow volume's boundary for snow).
        snow, snow_model, volume, kernel: a snow volume, walked or as a kernel (its table's
            summary), and whether the run traces a volume.
        materials: what a Mitsuba scene holds and needs (:mod:`.trace.materials`), or None.
        shots, seed, chunk_shots: the run's size and seed, shots per chunk.
        max_depth, pilot: vertices per path, and the pilot that chose them (or None).
        paths_per_shot, budget: paths per shot, and the scout that chose them (or None).
        integrator_dict, integrator: the integrator (its Mitsuba dict, and loaded).
        max_lanes, honoured: a scene's ``<integrator>`` settings kept.
        track, along, x, y: the track, along-track distance and footprint centres.
        x_loc, y_loc, dz: the centres folded into the traced tile, and the offsets back.
        reach, crop, triangles: the corridor meshed around the track, and its size.
        surface_z, z_ref, gate_z: surface height, footprint-mean reference elevation and
            range-gate centre of each shot.
        site, geoloc, rad: where on the Earth, each shot's place and time, and (a link
            budget) its radiometry.
        timings: wall time of each step [s] (the stream adds its own); t0: the start.
        tiling: the scenes the chunks trace (:class:`~lidar_mitsuba.ground.surface.Tiling`:
            one for every chunk, or a DEM's corridor tile per chunk); ``plan.scene`` is the
            first chunk's.
    """
    instrument: Instrument
    surf: surfaces.Surface
    surf_cfg: dict
    default_bsdf: dict | None
    bsdf: dict | None
    snow: SnowVolume | None
    shots: int
    seed: int
    paths_per_shot: int
    max_depth: int
    chunk_shots: int
    volume: bool
    snow_model: str
    materials: object
    max_lanes: int | None
    honoured: dict
    timings: dict
    t0: float
    track: object
    along: np.ndarray
    x: np.ndarray
    y: np.ndarray
    x_loc: np.ndarray
    y_loc: np.ndarray
    dz: np.ndarray
    reach: float
    bsdf_used: object
    triangles: int
    crop: bool
    surface_z: np.ndarray
    z_ref: np.ndarray
    gate_z: np.ndarray
    pilot: dict | None
    budget: dict | None
    integrator_dict: dict
    integrator: object
    kernel: dict | None
    site: Site
    geoloc: Geolocation
    rad: radiometry.ShotRadiometry | None
    tiling: object

    @property
    def scene(self):
        """The first chunk's Mitsuba scene (a DEM's first corridor tile: None once streamed)."""
        return self.tiling.scene

    def describe(self) -> list[str]:
        """The plan in words, one line per decision."""
        inst = self.instrument
        out = [f"{inst.beam} beam, {self.shots} shots (seed {self.seed}), "
               f"{inst.signal_photons:g} signal photons per shot from the reference plate, "
               f"{inst.channels} channels, dead time {inst.dead_time_ns:g} ns",
               f"surface: {self.surf_cfg.get('kind', type(self.surf).__name__)}"
               + (f" ({self.surf_cfg.get('scene_file')})" if self.surf_cfg.get("scene_file")
                  else "") + (f", {self.triangles} triangles" if self.triangles > 0 else "")]
        if self.materials is not None and self.materials.needs_media_tracer:
            out += self.materials.describe(max_depth=self.max_depth,
                                           fov_radius_m=inst.fov_diameter_m / 2)
        if self.snow is not None:
            out.append(f"snow: {self.snow.describe()} ({self.snow_model})")
        out.append(f"integrator {self.integrator_dict['type']}, max_depth {self.max_depth}"
                   + (" (the pilot's choice)" if self.pilot is not None else "")
                   + f", {self.paths_per_shot} paths per shot"
                   + (" (the scout's choice)" if self.budget is not None else ""))
        out.append(f"corridor: {self.reach:g} m around the track"
                   + ("" if self.crop else " (the whole tile)"))
        out.append(f"site: {self.site.to_dict()}" + ("" if self.rad is None else
                                                      ", radiometry from the link budget"))
        return out

    def __str__(self) -> str:
        return "\n".join(self.describe())


class _Run(types.SimpleNamespace):
    """A plan as :func:`plan`'s steps build it: :class:`RunPlan`'s fields, settable (those a
    step has not set yet are None); :func:`_freeze` makes the :class:`RunPlan`."""

    def __init__(self, **given):
        super().__init__(**{**dict.fromkeys(f.name for f in dataclasses.fields(RunPlan)),
                            "snow_model": "walk", "honoured": {}, "timings": {}, **given})

    @property
    def scene(self):
        return self.tiling.scene


def _freeze(run: _Run) -> RunPlan:
    """The finished builder as a :class:`RunPlan`."""
    return RunPlan(**{f.name: getattr(run, f.name) for f in dataclasses.fields(RunPlan)})


def plan(*, instrument: Instrument | None = None, surface=None, scene=None,
         scene_file: str | None = None, params: dict | None = None, bsdf: dict | None = None,
         shots: int = 1000, seed: int = 0, paths_per_shot: int | str = "auto",
         max_depth: int | str = "auto", track: Track | None = None,
         variant: str | None = None, progress: bool = True, chunk_shots: int = chunks.CHUNK_SHOTS,
         crop_to_track: bool = True, snow: SnowVolume | None = None, snow_model: str = "auto",
         site: Site | None = None) -> RunPlan:
    """Everything :func:`~lidar_mitsuba.run.simulate` decides before tracing, as a
    :class:`RunPlan`. Arguments as ``simulate``'s (``progress``: show the snow kernel's
    tabulation). Raises :class:`~lidar_mitsuba.constants.ParameterError` naming a bad value.
    """
    run = _resolve(instrument=instrument, surface=surface, scene=scene, scene_file=scene_file,
                   params=params, bsdf=bsdf, shots=shots, seed=seed,
                   paths_per_shot=paths_per_shot, max_depth=max_depth, variant=variant,
                   chunk_shots=chunk_shots, snow=snow, snow_model=snow_model)
    _lay_out(run, track or Track(), crop_to_track=crop_to_track)
    _choose_model(run, progress=progress)
    _place_on_earth(run, site or Site())
    return _freeze(run)


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
    ensure_renderer()              # the first run sets the renderer up
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
    """A scene's materials choose its model (:mod:`.trace.materials`): snow under a surface is
    walked (``volpathlength``); water and layers in the air take ``mediapathlength`` with the
    vertices they need; the scene's ``<integrator>`` settings are honoured."""
    from .trace import materials
    surf = run.surf
    try:
        run.materials = mats = materials.inspect(surf.scene)
    except ValueError as e:
        raise ParameterError("scene", str(e)) from None
    medium = mats.snow
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
    from .trace import materials, scene as scn
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
    # the scenes every chunk traces: one for a plane, a tile or a scene; a corridor tile
    # per chunk for a DEM (the first is built here: the pilot and the scout trace it)
    run.tiling = surf.tiles(run.x, run.y, x_local_m=run.x_loc, y_local_m=run.y_loc,
                            dz_m=run.dz, reach_m=run.reach, bsdf=run.bsdf_used,
                            crop=crop_to_track, chunk_shots=run.chunk_shots)
    run.chunk_shots, run.triangles = run.tiling.chunk_shots, run.tiling.triangles
    run.x_loc, run.y_loc = run.tiling.x_local_m, run.tiling.y_local_m   # the pilot's shots
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
    from .trace import pilot as bounce_pilot
    mi = ensure_renderer()
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
        run.rad = radiometry.run_radiometry(run.instrument, run.geoloc, run.gate_z + site.height_m,
                                   scene=run.scene, x_m=run.x_loc, y_m=run.y_loc,
                                   snow=run.snow)
        run.timings["radiometry_s"] = time.perf_counter() - t1
