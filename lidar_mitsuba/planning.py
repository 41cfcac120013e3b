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
from .ground.materials import Material, Reflector, Snow
from .ground.snow import SnowVolume
from .ground.surface import SceneSurface
from .instrument import Instrument
from .machine import check_memory
from .trace import path_budget as budgets, stream as chunks
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

    Attributes (per-shot arrays have shape (shots,)):
        instrument: the instrument after a scene's ``<integrator>`` overrides.
        surface, surface_config: the surface (:class:`~lidar_mitsuba.ground.surface.Surface`)
            and its config.
        material: what the surface is made of and what it needs from the tracer
            (:class:`~lidar_mitsuba.ground.materials.Material`: a reflector's BSDF, a snow
            volume, or a scene's own materials).
        shots, seed, chunk_shots: the run's size and seed, shots per chunk.
        max_depth, bounce_pilot: vertices per path, and the pilot that chose them (or None).
        paths_per_shot, path_budget: paths per shot, and the scout that chose them (or None).
        integrator_dict, integrator: the integrator (its Mitsuba dict, and loaded).
        max_lanes, scene_integrator: a scene's ``<integrator>`` settings kept.
        track, along_m, x_m, y_m: the track, along-track distance and footprint centres [m].
        x_local_m, y_local_m, dz_m: the centres folded into the traced tile, and the height
            offsets back [m].
        reach_m, crop_to_track, triangles: the corridor meshed around the track [m], whether
            it is cropped, and its size.
        surface_z_m, z_ref_m, gate_z_m: surface height, footprint-mean reference elevation
            and range-gate centre of each shot [m].
        site, geolocation, radiometry: where on the Earth, each shot's place and time, and (a
            link budget) its radiometry.
        timings_s: wall time of each step [s] (the stream adds its own); t0: the start.
        tiling: the scenes the chunks trace (:class:`~lidar_mitsuba.ground.tiling.Tiling`:
            one for every chunk, or a DEM's corridor tile per chunk); ``plan.scene`` is the
            first chunk's.
        cloud: the cloud over the track (:class:`~lidar_mitsuba.atmosphere.cloud_layer.Cloud`), or
            None (clear sky).
        cloud_table: its kernel's table at this instrument's geometry
            (:class:`~lidar_mitsuba.atmosphere.cloud_kernel.CloudTable`, made once by
            :func:`plan`), or None.
    """
    instrument: Instrument
    surface: surfaces.Surface
    surface_config: dict
    material: Material
    shots: int
    seed: int
    paths_per_shot: int
    max_depth: int
    chunk_shots: int
    max_lanes: int | None
    scene_integrator: dict
    timings_s: dict
    t0: float
    track: object
    along_m: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    x_local_m: np.ndarray
    y_local_m: np.ndarray
    dz_m: np.ndarray
    reach_m: float
    triangles: int
    crop_to_track: bool
    surface_z_m: np.ndarray
    z_ref_m: np.ndarray
    gate_z_m: np.ndarray
    bounce_pilot: dict | None
    path_budget: dict | None
    integrator_dict: dict
    integrator: object
    site: Site
    geolocation: Geolocation
    radiometry: radiometry.ShotRadiometry | None
    tiling: object
    cloud: object = None
    cloud_table: object = None

    @property
    def scene(self):
        """The first chunk's Mitsuba scene (a DEM's first corridor tile: None once streamed)."""
        return self.tiling.scene

    @property
    def snow(self) -> SnowVolume | None:
        """The snow volume traced (a built-in surface's), or None."""
        return self.material.snow

    def describe(self) -> list[str]:
        """The plan in words, one line per decision."""
        inst, cfg = self.instrument, self.surface_config
        out = [f"{inst.beam} beam, {self.shots} shots (seed {self.seed}), "
               f"{inst.signal_photons:g} signal photons per shot from the reference plate, "
               f"{inst.channels} channels, dead time {inst.dead_time_ns:g} ns",
               f"surface: {cfg.get('kind', type(self.surface).__name__)}"
               + (f" ({cfg.get('scene_file')})" if cfg.get("scene_file") else "")
               + (f", {self.triangles} triangles" if self.triangles > 0 else "")]
        out += self.material.describe(max_depth=self.max_depth,
                                      fov_radius_m=inst.fov_diameter_m / 2)
        out.append(f"integrator {self.integrator_dict['type']}, max_depth {self.max_depth}"
                   + (" (the pilot's choice)" if self.bounce_pilot is not None else "")
                   + f", {self.paths_per_shot} paths per shot"
                   + (" (the scout's choice)" if self.path_budget is not None else ""))
        if self.cloud is not None:
            tab = self.cloud_table
            out.append(f"cloud: {self.cloud.describe()}; forward-scattered light in the field "
                       f"of view {tab.forward:.3g} of the clear ground's (mean delay "
                       f"{tab.mean_delay_ns:.3g} ns), tabulated once by mediapathlength")
        out.append(f"corridor: {self.reach_m:g} m around the track"
                   + ("" if self.crop_to_track else " (the whole tile)"))
        out.append(f"site: {self.site.to_dict()}" + ("" if self.radiometry is None else
                                                      ", radiometry from the link budget"))
        return out

    def __str__(self) -> str:
        return "\n".join(self.describe())

    def section(self, track, *, shots: int, seed: int) -> RunPlan:
        """The ``shots`` shots of ``track`` (the next section of a long track) laid out with
        this plan's model, seeded ``seed``: the material, depth, paths per shot and
        integrator are this plan's; the positions, tiles, heights, references, places on the
        Earth and radiometry are the section's own (:func:`_lay_out`, :func:`_place_on_earth`).
        A granule plans each beam once, on its first section, and streams the rest with this
        (:mod:`lidar_mitsuba.granule`): memory stays a section's."""
        run = _Run(**{f.name: getattr(self, f.name) for f in dataclasses.fields(RunPlan)})
        run.shots, run.seed, run.t0 = int(shots), int(seed), time.perf_counter()
        run.timings_s, run.surface_config = {}, dict(self.surface_config)
        run.radiometry = None
        _lay_out(run, track, crop_to_track=self.crop_to_track)
        _place_on_earth(run, self.site)
        return _freeze(run)


class _Run(types.SimpleNamespace):
    """A plan as :func:`plan`'s steps build it: :class:`RunPlan`'s fields, settable (those a
    step has not set yet are None); :func:`_freeze` makes the :class:`RunPlan`."""

    def __init__(self, **given):
        super().__init__(**{**dict.fromkeys(f.name for f in dataclasses.fields(RunPlan)),
                            "scene_integrator": {}, "timings_s": {}, **given})

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
         site: Site | None = None, cloud=None) -> RunPlan:
    """Everything :func:`~lidar_mitsuba.run.simulate` decides before tracing, as a
    :class:`RunPlan`. Arguments as ``simulate``'s (``progress``: show the snow kernel's
    tabulation). Raises :class:`~lidar_mitsuba.constants.ParameterError` naming a bad value.
    """
    run = _resolve(instrument=instrument, surface=surface, scene=scene, scene_file=scene_file,
                   params=params, bsdf=bsdf, shots=shots, seed=seed,
                   paths_per_shot=paths_per_shot, max_depth=max_depth, variant=variant,
                   chunk_shots=chunk_shots, snow=snow, snow_model=snow_model)
    run.cloud, run.cloud_table = _cloud(cloud, run)
    _lay_out(run, track or Track(), crop_to_track=crop_to_track)
    _choose_model(run, progress=progress)
    _place_on_earth(run, site or Site())
    return _freeze(run)


def _cloud(cloud, run: _Run):
    """``(cloud, table)``: the run's cloud checked (None or optical depth 0: clear sky:
    ``(None, None)``) and its kernel's table (:mod:`.atmosphere.cloud_kernel`, cached: a
    later plan of the same cloud and geometry reuses it; the plan holds it)."""
    from .atmosphere import cloud_layer as clouds
    cloud = clouds.as_cloud(cloud)
    if cloud is None or cloud.clear:
        return None, None
    from .trace import materials
    if isinstance(run.material, materials.SceneMaterials) and run.material.air_layers:
        raise ParameterError("cloud", "the scene holds its own layer in the air: give the "
                             "cloud in one place")
    from .atmosphere import cloud_kernel
    t1 = time.perf_counter()
    table = cloud_kernel.table_for(cloud, run.instrument)
    run.timings_s["cloud_kernel_s"] = time.perf_counter() - t1
    return cloud, table


def _check_snow(snow, snow_model, *, surf, bsdf, max_depth) -> None:
    if snow is not None and not isinstance(snow, SnowVolume):
        raise ParameterError("snow", f"must be a SnowVolume (got {type(snow).__name__})")
    if snow_model not in SNOW_MODELS:
        raise ParameterError("snow_model", f"must be one of {', '.join(SNOW_MODELS)} "
                             f"(got {snow_model!r})")
    if snow_model != "auto" and snow is None:
        raise ParameterError("snow_model", "only applies with a snow volume (snow=, "
                             "--snow-grain-um)")
    if snow is None or surf is None:
        return
    if isinstance(surf, SceneSurface):
        raise ParameterError("snow", "does not apply to a Mitsuba scene: put a <medium> "
                             "inside its terrain shape (docs/guide/snow.md)")
    if bsdf is not None:
        raise ParameterError("bsdf", "a snow volume replaces the surface BSDF: give one")
    if max_depth not in ("auto", snow.events_cap):
        raise ParameterError("max_depth", "with a snow volume the interactions per photon "
                             "are the snow's max_events (--snow-max-events)")


def _resolve(*, instrument, surface, scene, scene_file, params, bsdf, shots, seed,
             paths_per_shot, max_depth, variant, chunk_shots, snow, snow_model) -> _Run:
    """Check the run's arguments, activate the variant, resolve the surface and its material
    (a reflector's BSDF, a snow volume, or a scene's own materials)."""
    instrument = instrument or Instrument()
    _check_snow(snow, snow_model, surf=None, bsdf=bsdf, max_depth=max_depth)
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
    _check_snow(snow, snow_model, surf=surf, bsdf=bsdf, max_depth=max_depth)
    run = _Run(instrument=instrument, surface=surf, surface_config=surf_cfg, shots=shots,
               seed=seed, paths_per_shot=paths_per_shot, max_depth=max_depth,
               chunk_shots=chunk_shots, t0=t0)
    if snow is not None:
        run.material = Snow(snow, "walk" if snow_model == "walk" else "kernel")
    elif isinstance(surf, SceneSurface):
        _scene_materials(run)
    else:
        run.material = Reflector(bsdf if bsdf is not None else default_bsdf,
                                 given=bsdf is not None)
    run.max_depth = run.material.depth(run.max_depth,
                                       fov_radius_m=run.instrument.fov_diameter_m / 2)
    check_memory("shots", estimate_memory_bytes(run.instrument, shots),
                 f"a run of {shots} shots", "split the track into several runs")
    return run


def _scene_materials(run: _Run) -> None:
    """A scene's materials (:mod:`.trace.materials`), with the scene's ``<integrator>``
    settings honoured; the ground under layers in the air is what heights refer to."""
    from .trace import materials
    surf = run.surface
    try:
        mats = materials.inspect(surf.scene)
    except ValueError as e:
        raise ParameterError("scene", str(e)) from None
    run.instrument, run.max_depth, run.max_lanes, run.scene_integrator = (
        materials.scene_settings(surf.scene, run.instrument, run.max_depth))
    run.material = dataclasses.replace(mats, settings=dict(run.scene_integrator))
    if mats.air_layers:      # heights and references: the ground under the layers
        run.surface = dataclasses.replace(surf, through_null=True)


def _footprint_reach_m(inst: Instrument) -> float:
    """How far from its centre a footprint's photons land [m]: 5 sigma, and a metre."""
    return 5.0 * inst.footprint_sigma_m + 1.0


def _lay_out(run: _Run, track, *, crop_to_track: bool) -> None:
    """The shots along the track, folded into the surface; the scene over the corridor the
    photons can reach (a streamed DEM: its first tile); heights and reference elevations."""
    from .trace import materials, scene as scn
    inst, surf, mat = run.instrument, run.surface, run.material
    margin = _footprint_reach_m(inst)
    run.track, run.crop_to_track = track, bool(crop_to_track)
    run.along_m, run.x_m, run.y_m = track.positions(run.shots, spacing_m=inst.shot_spacing_m,
                                                    centre_xy_m=surf.centre_xy_m())
    run.x_local_m, run.y_local_m, run.dz_m = surf.fold(run.x_m, run.y_m, margin_m=margin)
    if run.max_depth == "auto" and surf.exact_single_bounce:
        run.max_depth = 1
    # mesh only the corridor the photons can reach: footprints (5 sigma) for single bounce;
    # the receiver's field of view when paths may bounce on
    run.reach_m = (margin if run.max_depth == 1 or mat.volume
                   else max(margin, inst.fov_diameter_m / 2 + 5.0))
    # the scenes every chunk traces: one for a plane, a tile or a scene; a corridor tile
    # per chunk for a DEM (the first is built here: the pilot and the scout trace it)
    run.tiling = surf.tiles(run.x_m, run.y_m, x_local_m=run.x_local_m,
                            y_local_m=run.y_local_m, dz_m=run.dz_m, reach_m=run.reach_m,
                            bsdf=mat.mesh_bsdf, crop=crop_to_track, chunk_shots=run.chunk_shots)
    run.chunk_shots, run.triangles = run.tiling.chunk_shots, run.tiling.triangles
    if run.integrator is not None:                  # a later section: the plan's integrator
        run.tiling.attach(run.integrator)
    run.x_local_m, run.y_local_m = run.tiling.x_local_m, run.tiling.y_local_m  # pilot's shots
    top = float(scn.scene_bounds(run.scene)[1][2] + np.max(np.abs(run.dz_m), initial=0.0))
    if top + 1.0 >= inst.altitude_m:
        raise ParameterError("altitude_m", f"the spacecraft ({inst.altitude_m:g} m) must "
                             f"be above the scene, which reaches z = {top:g} m")
    if isinstance(mat, materials.SceneMaterials):
        try:
            materials.refuse_mirrors(mat, run.scene, run.x_local_m, run.y_local_m, inst)
        except ValueError as e:
            raise ParameterError("scene", str(e)) from None
    run.surface_z_m = surf.height_m(run.x_m, run.y_m)
    run.z_ref_m = surf.reference_elevation_m(run.x_m, run.y_m, sigma_m=inst.footprint_sigma_m)
    run.gate_z_m = chunks.gate_heights_m(run.z_ref_m)
    if surf.takes_bsdf:
        run.surface_config.update(mesh_triangles=run.triangles, crop_to_track=run.crop_to_track)
    if isinstance(mat, Reflector) and mat.given:
        run.surface_config["bsdf"] = repr(mat.bsdf)
    run.timings_s["scene_s"] = time.perf_counter() - run.t0


def _choose_model(run: _Run, *, progress: bool = False) -> None:
    """The bounces (``max_depth="auto"``: the pilot), the material's integrator, and the
    paths per shot (``"auto"``: the scout)."""
    from .trace import pilot
    mi = ensure_renderer()
    inst, ppp = run.instrument, run.paths_per_shot
    if run.max_depth == "auto":
        t1 = time.perf_counter()
        n_pilot = run.x_local_m.size        # a streamed surface's pilot runs on its first tile
        run.bounce_pilot = pilot.run_pilot(
            scene=run.scene, instrument=inst, x_m=run.x_local_m, y_m=run.y_local_m,
            dz_m=run.dz_m[:n_pilot], z_ref_m=run.z_ref_m[:n_pilot],
            paths_per_shot=budgets.SCOUT_PATHS if ppp == "auto" else int(ppp))
        run.max_depth = 1 if run.bounce_pilot["single_bounce_enough"] else 2
        # the footprints are all the photons reach: later tiles mesh only those
        if run.max_depth == 1 and run.tiling.narrow(_footprint_reach_m(inst)):
            run.reach_m = _footprint_reach_m(inst)
        run.timings_s["pilot_s"] = time.perf_counter() - t1
    run.material, t_prep = run.material.prepared(progress=progress)
    if t_prep:
        run.timings_s["kernel_table_s"] = t_prep
    lanes = {} if run.max_lanes is None else {"max_lanes": int(run.max_lanes)}
    d = run.material.integrator(inst.integrator_dict(max_depth=run.max_depth, **lanes),
                                max_depth=run.max_depth)
    if hasattr(run.surface, "integrator_dict"):      # a forest's turbid or gap canopy
        d = run.surface.integrator_dict(d)
    run.integrator_dict, run.integrator = d, mi.load_dict(d)
    run.tiling.attach(run.integrator)
    if ppp == "auto":
        t1 = time.perf_counter()
        per_path = d["type"] == "mediapathlength"
        run.path_budget = budgets.scout(
            run.integrator, run.scene, run.x_local_m, run.y_local_m, inst,
            returns_per_path=run.material.returns_per_path(run.max_depth), per_path=per_path,
            gate_z_m=run.gate_z_m if per_path else None)
        run.paths_per_shot = run.path_budget["paths_per_shot"]
        run.timings_s["scout_s"] = time.perf_counter() - t1


def _place_on_earth(run: _Run, site: Site) -> None:
    """Each shot's place and time (the track's own, or the scene at ``site``) and, for an
    instrument with a link budget, its signal scale and background."""
    run.site = site
    run.geolocation = getattr(run.track, "geolocation", None)
    if run.geolocation is None:
        run.geolocation = site.geolocation(run.x_m, run.y_m, prf_hz=run.instrument.prf_hz)
    if run.instrument.link_budget is not None:
        t1 = time.perf_counter()
        run.radiometry = radiometry.run_radiometry(
            run.instrument, run.geolocation, run.gate_z_m + site.height_m, scene=run.scene,
            x_m=run.x_local_m, y_m=run.y_local_m, snow=run.material.snow,
            albedo=getattr(run.surface, "sunlit_albedo", None))
        if run.cloud is not None:     # the sun under the cloud (atmosphere.cloud_layer)
            from .atmosphere.cloud_layer import clouded_radiometry
            run.radiometry = clouded_radiometry(
                run.radiometry, run.cloud, run.instrument,
                delta_time_s=run.geolocation.delta_time_s, z_m=run.gate_z_m + site.height_m)
        run.timings_s["radiometry_s"] = time.perf_counter() - t1
