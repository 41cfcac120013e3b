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

import inspect
import math
import pathlib
import time
import warnings
from dataclasses import dataclass, field

import mitsuba as mi
import numpy as np

from . import (bounce_pilot, chunks, classify, path_budget, radiometry, retrieval,
               scene as scn, surface as surfaces, warmup)
from .constants import FWHM_PER_SIGMA, ParameterError, SimulationWarning
from .instrument import Instrument
from .photons import Detections, Returns
from .snow import SnowVolume, medium_events_cap
from .resources import check_memory
from .surface import SceneSurface, SurfaceSpec
from .geotrack import Geolocation, Site
from .track import Track, spread_shots
from .variant import set_variant


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


# pathlength parameters a scene's <integrator> may set -> (Instrument field, factor to it)
_XML_GEOMETRY = {"altitude_m": ("altitude_m", 1.0),
                 "footprint_sigma_m": ("footprint_diameter_m", 4.0),
                 "pulse_sigma_ns": ("pulse_fwhm_ns", FWHM_PER_SIGMA),
                 "fov_radius_m": ("fov_diameter_m", 2.0)}


def _scene_settings(scene: mi.Scene, instrument: Instrument, max_depth):
    """Honour a ``<integrator type="pathlength">`` in the scene: the parameters it sets become
    the run's unless the instrument or ``max_depth`` set another value (refused: one place).
    Returns ``(instrument, max_depth, max_lanes, honoured)``."""
    explicit = getattr(scene.integrator(), "explicit", None)
    if not explicit:                 # no integrator, another one (for mi.render), or defaults
        return instrument, max_depth, None, {}
    nominal = Instrument(beam=instrument.beam)
    changes = {}
    for key, (name, factor) in _XML_GEOMETRY.items():
        if key not in explicit:
            continue
        value, given = explicit[key] * factor, getattr(instrument, name)
        if given != getattr(nominal, name) and not math.isclose(given, value, rel_tol=1e-9):
            raise ParameterError(name, f"the scene's <integrator type=\"pathlength\"> sets "
                                 f"{key} = {explicit[key]:g}, i.e. {name} = {value:g}, and "
                                 f"{given:g} was given too: set it in one place")
        changes[name] = value
    if "max_depth" in explicit:
        if max_depth == "auto":
            max_depth = int(explicit["max_depth"])
        elif max_depth != explicit["max_depth"]:
            raise ParameterError("max_depth", f"the scene's <integrator type=\"pathlength\"> "
                                 f"sets max_depth = {explicit['max_depth']} and {max_depth} "
                                 f"was given too: set it in one place")
    if changes:
        instrument = instrument.replace(**changes)
    return instrument, max_depth, explicit.get("max_lanes"), dict(explicit)


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
             site: Site | None = None) -> SimulationResult:
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
    instrument = instrument or Instrument()
    if snow is not None and not isinstance(snow, SnowVolume):
        raise ParameterError("snow", f"must be a SnowVolume (got {type(snow).__name__})")
    _check_run(shots, seed, paths_per_shot,
               "auto" if snow is not None and max_depth == snow.events_cap else max_depth,
               chunk_shots)
    if variant is not None:
        try:
            set_variant(variant)
        except ValueError as e:
            raise ParameterError("variant", str(e)) from None
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    surf, default_bsdf, surf_cfg = _resolve_surface(surface=surface, scene=scene,
                                                    scene_file=scene_file, params=params,
                                                    bsdf=bsdf)
    max_lanes, honoured = None, {}
    volume = snow is not None
    if volume:
        if isinstance(surf, SceneSurface):
            raise ParameterError("snow", "does not apply to a Mitsuba scene: put a <medium> "
                                 "inside its terrain shape (docs: README, snow)")
        if bsdf is not None:
            raise ParameterError("bsdf", "a snow volume replaces the surface BSDF: give one")
        if max_depth not in ("auto", snow.events_cap):
            raise ParameterError("max_depth", "with a snow volume the interactions per photon "
                                 "are the snow's max_events (--snow-max-events)")
        max_depth = snow.events_cap
    if isinstance(surf, SceneSurface):
        try:
            medium = scn.scene_medium(surf.scene)
        except ValueError as e:
            raise ParameterError("scene", str(e)) from None
        volume = medium is not None
        instrument, max_depth, max_lanes, honoured = _scene_settings(surf.scene, instrument,
                                                                     max_depth)
        if volume and max_depth == "auto":
            max_depth = medium_events_cap(medium)
    check_memory("shots", estimate_memory_bytes(instrument, shots), f"a run of {shots} shots",
                 "split the track into several runs")
    sigma = instrument.footprint_sigma_m
    margin = 5.0 * sigma + 1.0
    track = track or Track()
    along, x, y = track.positions(shots, spacing_m=instrument.shot_spacing_m,
                                  centre_xy_m=surf.centre_xy_m())
    x_loc, y_loc, dz = surf.fold(x, y, margin_m=margin)
    if max_depth == "auto" and surf.exact_single_bounce:
        max_depth = 1
    # mesh only the corridor the photons can reach: footprints (5 sigma) for single bounce;
    # the receiver's field of view when paths may bounce on
    reach = (margin if max_depth == 1 or volume
             else max(margin, instrument.fov_diameter_m / 2 + 5.0))
    bsdf_used = snow if snow is not None else bsdf if bsdf is not None else default_bsdf
    first_tile = None
    if surf.streamed:       # a DEM: every chunk traces its own corridor tile
        chunk_shots = min(chunk_shots, surf.tile_shots)
        first_tile = surf.corridor_tile(x[:chunk_shots], y[:chunk_shots], reach_m=reach,
                                        bsdf=bsdf_used)
        scene_, (ox, oy), triangles = first_tile
        x_loc, y_loc = x[:chunk_shots] - ox, y[:chunk_shots] - oy     # the pilot's tile
    else:
        bounds = None
        if crop_to_track:
            bounds = (float(x_loc.min()) - reach, float(x_loc.max()) + reach,
                      float(y_loc.min()) - reach, float(y_loc.max()) + reach)
        scene_, triangles = surf.mitsuba_scene(bsdf=bsdf_used, margin_m=reach, bounds_m=bounds)
    top = float(scn.scene_bounds(scene_)[1][2] + np.max(np.abs(dz), initial=0.0))
    if top + 1.0 >= instrument.altitude_m:
        raise ParameterError("altitude_m", f"the spacecraft ({instrument.altitude_m:g} m) must "
                             f"be above the scene, which reaches z = {top:g} m")
    surface_z = surf.height_m(x, y)
    z_ref = surf.reference_elevation_m(x, y, sigma_m=sigma)
    if surf.takes_bsdf:
        surf_cfg.update(mesh_triangles=triangles, crop_to_track=bool(crop_to_track))
    if bsdf is not None:
        surf_cfg["bsdf"] = repr(bsdf)
    timings["scene_s"] = time.perf_counter() - t0

    pilot = None
    lanes = {} if max_lanes is None else {"max_lanes": int(max_lanes)}
    if max_depth == "auto":
        t1 = time.perf_counter()
        n_pilot = x_loc.size           # a streamed surface's pilot runs on its first tile
        pilot = bounce_pilot.run_pilot(scene=scene_, instrument=instrument, x_m=x_loc, y_m=y_loc,
                                       dz_m=dz[:n_pilot], z_ref_m=z_ref[:n_pilot],
                                       paths_per_shot=(path_budget.SCOUT_PATHS
                                                       if paths_per_shot == "auto"
                                                       else int(paths_per_shot)))
        max_depth = 1 if pilot["single_bounce_enough"] else 2
        timings["pilot_s"] = time.perf_counter() - t1
    integrator_dict = instrument.integrator_dict(max_depth=max_depth, **lanes)
    if volume:             # one record per photon, whatever its interactions
        integrator_dict.update(snow.integrator_params() if snow is not None else
                               {"type": "volpathlength", **{
                                   k: v for k, v in honoured.items()
                                   if k in ("group_index", "snow_depth_m", "base_albedo")}})
        integrator_dict["max_depth"] = int(max_depth)
    integrator = mi.load_dict(integrator_dict)
    budget = None
    if paths_per_shot == "auto":
        t1 = time.perf_counter()
        budget = _scout(integrator, scene_, x_loc, y_loc, instrument,
                        returns_per_path=1 if volume else int(max_depth))
        paths_per_shot = budget["paths_per_shot"]
        timings["scout_s"] = time.perf_counter() - t1
    if keep_returns is None:
        keep_returns = shots * paths_per_shot * (1 if volume else max_depth) <= 2 ** 24
    gate_z = chunks.gate_heights_m(z_ref)
    site = site or Site()
    geoloc = getattr(track, "geolocation", None)
    if geoloc is None:
        geoloc = site.geolocation(x, y, prf_hz=instrument.prf_hz)
    rad = None
    if instrument.link_budget is not None:
        t1 = time.perf_counter()
        rad = _shot_radiometry(instrument, geoloc, gate_z + site.height_m, scene=scene_,
                               x_m=x_loc, y_m=y_loc, snow=snow)
        timings["radiometry_s"] = time.perf_counter() - t1
    if surf.streamed:
        source = chunks.CorridorSource(integrator, surf, x_m=x, y_m=y,
                                       paths_per_shot=int(paths_per_shot), reach_m=reach,
                                       bsdf=bsdf_used, first=first_tile)
        # the first tile goes with its chunk: a live stale scene would join every later
        # tile's kernel calls. The rare diagnosis that needs it builds it again.
        first_tile = scene_ = None
        n_first = x_loc.size

        def scene_of():
            return surf.corridor_tile(x[:n_first], y[:n_first], reach_m=reach,
                                      bsdf=bsdf_used)[0]
    else:
        source = chunks.traced(integrator, scene_, x_m=x_loc, y_m=y_loc,
                               paths_per_shot=int(paths_per_shot), dx_m=x - x_loc,
                               dy_m=y - y_loc, dz_m=dz)

        def scene_of():
            return scene_
    if progress:       # a first run on this machine compiles the detector: say so
        warmup.compile_kernels()
    run = chunks.run(
        source=source,
        detectors={"run": instrument}, z_ref_m=z_ref, seed=seed, chunk_shots=chunk_shots,
        keep_returns=keep_returns, progress=progress,
        detector_inputs=None if rad is None else rad.detector_inputs)
    timings.update(run.timings_s)
    det = run.detections["run"]
    t3 = time.perf_counter()
    h = retrieval.photon_heights_m(det.time_ns, altitude_m=instrument.altitude_m)
    conf = classify.signal_confidence(shot=det.shot, h_m=h, gate_center_h_m=gate_z,
                                      range_gate_m=instrument.range_gate_m)
    timings["detect_s"] += time.perf_counter() - t3
    timings["total_s"] = time.perf_counter() - t0

    choices, warns = _explain(instrument=instrument, surf=surf, max_depth=max_depth,
                              pilot=pilot, paths_per_shot=paths_per_shot, budget=budget,
                              crop=crop_to_track,
                              triangles=triangles, det=det, volume=volume, snow=snow,
                              shots=shots, timings=timings)
    if surf.streamed:
        surf_cfg.update(tiles=source.tiles, max_tile_triangles=source.triangles)
    warns += _diagnose(surf=surf, scene_of=scene_of, x_m=x_loc, y_m=y_loc,
                       surface_z=surface_z[:x_loc.size],
                       n_returns=run.n_returns, det=det, instrument=instrument)
    for w in warns:
        warnings.warn(w, SimulationWarning, stacklevel=2)
    config = {"instrument": instrument.to_dict(), "surface": surf_cfg, "track": track.to_dict(),
              "shots": int(shots), "seed": int(seed), "paths_per_shot": int(paths_per_shot),
              "path_budget": budget,
              "max_depth": int(max_depth), "bounce_pilot": pilot, "variant": mi.variant(),
              "scene_integrator": honoured, "choices": choices, "warnings": warns,
              "snow": snow.config() if snow is not None else None,
              "integrator": integrator_dict["type"],
              "site": site.to_dict(),
              "radiometry": None if rad is None else rad.summary()}
    return SimulationResult(instrument=instrument, config=config, along_track_m=along,
                            shot_x_m=x, shot_y_m=y, surface_z_m=surface_z, z_ref_m=z_ref,
                            detections=det, h_m=h, signal_conf=conf, returns=run.returns,
                            timings_s=timings, geolocation=geoloc, radiometry=rad)


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


def _scout(integrator, scene, x_m, y_m, instrument: Instrument, *,
           returns_per_path: int) -> dict:
    """``paths_per_shot="auto"``: trace the run's own model on up to
    :data:`~lidar_mitsuba.path_budget.SCOUT_SHOTS` shots spread along the track (fixed random
    numbers) and choose the paths per shot from its weights (:func:`path_budget.choose`)."""
    idx = spread_shots(x_m.size, path_budget.SCOUT_SHOTS)
    ret = integrator.trace(scene, shot_x_m=x_m[idx], shot_y_m=y_m[idx],
                           paths_per_shot=path_budget.SCOUT_PATHS, seed=path_budget.SCOUT_SEED)
    moments = path_budget.shot_moments(ret.shot, ret.weight, ret.depth, n_shots=idx.size,
                                       paths_per_shot=path_budget.SCOUT_PATHS,
                                       max_depth=returns_per_path)
    return path_budget.choose(moments=moments, kept_per_weight=(
        instrument.signal_photons * instrument.fill_factor * instrument.pde))


def _explain(*, instrument, surf, max_depth, pilot, paths_per_shot, crop, triangles,
             det, volume=False, snow=None, shots=0, timings=None, budget=None
             ) -> tuple[list[str], list[str]]:
    """The modelling choices of a run in words (``lidar-mitsuba simulate --explain``), and
    the ones that deserve a warning."""
    out = []
    if volume:
        out.append(snow.describe() if snow is not None else
                   f"snow volume on (the scene's <medium>), up to {max_depth} interactions "
                   f"per photon")
        if timings and "total_s" in timings:
            rate = shots / max(timings["total_s"], 1e-9)
            out.append(f"its cost: {rate:.3g} shots/s end to end ({timings['total_s']:.3g} s "
                       f"for {shots} shots), some hundred times slower than the surface "
                       f"alone (`lidar-mitsuba bench` measures the ratio); "
                       + ("--snow-similarity-g 0 traces ~9x fewer scatterings, with h_li "
                          "within ~1 cm in bench's check"
                          if snow is None or snow.similar_to_g is None else
                          "similarity-rescaled: h_li within ~1 cm of the exact phase "
                          "function in bench's check"))
    elif surf.exact_single_bounce and max_depth == 1:
        out.append("single bounce (max_depth 1): exact for a plane, where nothing bounces twice")
    elif pilot is not None:
        out.append(bounce_pilot.explain(pilot, max_depth))
    elif max_depth == 1:
        out.append("single bounce (max_depth 1, the paper's model, as asked): each photon's "
                   "first-surface return, which at nadir comes back along its own incident ray; "
                   "it leaves out multiple scattering between terrain facets (--max-depth auto "
                   "checks whether that matters)")
    else:
        out.append(f"{max_depth} bounces per path with shadow-tested returns toward the receiver")
    out += surf.notes(instrument=instrument, max_depth=1 if volume else max_depth, crop=crop,
                      triangles=triangles)
    warns = surf.warnings(instrument=instrument)
    peak = float(np.max(det.mean_photons_per_shot)) if det.mean_photons_per_shot.size else 0.0
    kept = peak * instrument.fill_factor * instrument.pde
    if budget is not None:
        out.append(path_budget.explain(budget))
    msg = (("" if budget is not None else f"{paths_per_shot} paths per shot for ")
           + f"up to {peak:.1f} photons per shot ({kept:.1f} after fill factor and PDE); "
           f"{det.run_out_shots.size} of {shots} shots ran out of distinct paths")
    out.append(msg)
    ran_out = path_budget.run_out_warning(int(det.run_out_shots.size), int(shots))
    if ran_out is not None:
        warns.append(ran_out)
    return out, warns


def _diagnose(*, surf, scene_of, x_m, y_m, surface_z, n_returns, det,
              instrument) -> list[str]:
    """Warnings for shots with no surface under them and for a run that detected no signal
    photon, with the likely cause. ``scene_of()``: the scene of the shots ``x_m``, ``y_m``
    (called only when a warning needs it)."""
    out = []
    missing = ~np.isfinite(surface_z)
    n = surface_z.size
    if missing.all():
        lo, hi = scn.scene_bounds(scene_of())
        return [f"no surface under any of the {n} footprint centres: the track (x "
                f"{np.min(x_m):g} .. {np.max(x_m):g} m, y {np.min(y_m):g} .. {np.max(y_m):g} m) "
                f"misses the geometry (x {lo[0]:g} .. {hi[0]:g} m, y {lo[1]:g} .. {hi[1]:g} m); "
                "its shots record background noise only"]
    if missing.any():
        out.append(f"{int(missing.sum())} of the {n} shots have no surface under their footprint "
                   "centre: they record background noise only")
    if det.is_signal.any():
        return out
    if n_returns == 0:
        _, nz = scn.cast_down(scene_of(), x_m[~missing], y_m[~missing])
        if np.nanmean(nz < 0) > 0.5:
            out.append("no photon came back: the surfaces under the track face down, away from "
                       "the lidar (a face-down rectangle, or a mesh whose triangles wind the "
                       "other way); Mitsuba's BSDFs are one-sided and return nothing from the "
                       "back: flip the shape (rotate it, or reverse its faces)")
        else:
            out.append("no photon came back: the surfaces' BSDF sends no light back toward the "
                       "receiver (e.g. a smooth conductor or dielectric reflects only in the "
                       "mirror direction); use a rough or diffuse BSDF")
    else:
        mu = float(np.mean(det.mean_photons_per_shot))
        out.append(f"returns were traced but no signal photon was detected: {mu:.3g} photons "
                   f"per shot reach the detector on average ({instrument.signal_photons:g} "
                   f"from the reference plate); raise --signal-photons or the shot count")
    return out
