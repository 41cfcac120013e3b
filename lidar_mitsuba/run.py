"""One beam's run: simulate a ground track and get photons, references and statistics
(``lm.simulate``, the front door's).

>>> import lidar_mitsuba as lm
>>> res = lm.simulate(instrument=lm.Instrument(beam="weak"),
...                   surface=lm.SurfaceSpec(kind="fractal", p=1.8), shots=1000, seed=1)
...                                                                      # doctest: +SKIP
>>> print(res.report().overall)                                          # doctest: +SKIP

One run: resolve the surface (:mod:`.ground.surface`) and what a scene's materials need
(:mod:`.trace.materials`), lay out the track (:mod:`.track`), build the scene over the
track's corridor, choose the bounces (:mod:`.trace.pilot`) and the paths
(:mod:`.trace.path_budget`), then trace and detect chunk by chunk (:mod:`.trace.stream`), and
finally place and classify the photons (:mod:`.products`). The renderer is set up by the
first run (:func:`~.trace.variant.ensure_renderer`): importing this module needs none.
"""
from __future__ import annotations

import inspect
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from . import diagnostics as explain, precompile as warmup
from . import radiometry  # noqa: F401  (SimulationResult.radiometry's type)
from .constants import SimulationWarning
from .detector.records import Detections, Returns
from .geotrack import Geolocation, Site
from .ground import surface as surfaces
from .ground.snow import SnowVolume
from .ground.surface import SurfaceSpec
from .instrument import Instrument
from .planning import RunPlan, _check_run, plan
from .products import classify, retrieval
from .trace import stream as chunks
from .trace.variant import ensure_renderer
from .track import Track

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
        detections: the detected photon events (:class:`~lidar_mitsuba.detector.records.Detections`),
            scattering points in the frame of ``shot_x_m``, ``shot_y_m``.
        h_m: elevation of each detected photon [m].
        signal_conf: ATL03-style confidence of each photon, 0 (noise) to 4 (high), from
            :func:`lidar_mitsuba.products.classify.signal_confidence`.
        returns: the traced returns (:class:`~lidar_mitsuba.detector.records.Returns`, global shot
            indices), or ``None`` when not kept (``keep_returns``).
        timings_s: wall time of each stage [s].
        geolocation: each shot on the Earth (:class:`~lidar_mitsuba.geotrack.Geolocation`:
            latitude, longitude, direction of travel, time): the track's own (a DEM
            granule's) or the scene placed at the run's ``site``.
        radiometry: each shot's signal scale, background and sun
            (:class:`~lidar_mitsuba.radiometry.ShotRadiometry`) when the instrument has a link
            budget (``Instrument.atlas()``), else ``None``.
        signal_test: the histogram test that gave ``signal_conf``
            (:class:`~lidar_mitsuba.products.classify.HistogramTest`: per-photon tail
            probabilities, per-block noise), which ATL03's writer reuses instead of running it
            again; ``None`` where not kept.
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
    signal_test: classify.HistogramTest | None = None

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


def check_run(**kw) -> None:
    """Check ``simulate``'s run arguments (``shots``, ``seed``, ``paths_per_shot``,
    ``max_depth``, ``chunk_shots``) without running: those given in ``kw``, ``simulate``'s
    defaults for the others. Raises :class:`ParameterError` naming the bad one."""
    defaults = inspect.signature(simulate).parameters
    get = lambda name: kw.get(name, defaults[name].default)  # noqa: E731
    _check_run(get("shots"), get("seed"), get("paths_per_shot"), get("max_depth"),
               get("chunk_shots"))


def simulate(*, instrument: Instrument | None = None,
             surface: SurfaceSpec | surfaces.Surface | None = None,
             scene=None, scene_file: str | None = None, params: dict | None = None,
             bsdf: dict | None = None, shots: int = 1000, seed: int = 0,
             paths_per_shot: int | str = "auto", max_depth: int | str = "auto",
             track: Track | None = None, variant: str | None = None, progress: bool = True,
             chunk_shots: int = chunks.CHUNK_SHOTS, keep_returns: bool | None = None,
             crop_to_track: bool = True, snow: SnowVolume | None = None,
             snow_model: str = "auto", site: Site | None = None, cloud=None
             ) -> SimulationResult:
    """Simulate ``shots`` laser shots along a ground track and detect their photons.

    >>> lm.simulate(scene="scenes/fog.xml", params={"tau": 0.5}).report()  # doctest: +SKIP

    Args:
        instrument: the lidar (default: strong beam, the paper's parameters).
        surface: a built-in surface (default: fractal p = 1.8, 10 m relief, Ward snow), or
            a ready :class:`~lidar_mitsuba.ground.terrain.Heightfield` (e.g. your own DEM; periodic or
            not), :class:`~lidar_mitsuba.ground.surface.Plane` (with the paper's Ward snow, or
            ``bsdf``) or :class:`~lidar_mitsuba.ground.surface.SceneSurface`.
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
            variance, judged by a scout trace (:mod:`lidar_mitsuba.trace.path_budget`; 16 for the
            strong beam on the default snow, 8 for the weak one). The choice and its numbers
            are in ``result.config["paths_per_shot"]`` and ``result.config["path_budget"]``.
        max_depth: surface interactions per photon path (1 = single bounce), or ``"auto"``
            (1 on a plane, where it is exact, elsewhere a two-bounce pilot decides: see
            :mod:`lidar_mitsuba.trace.pilot`). The choice and its numbers are in
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
            (:func:`lidar_mitsuba.ground.snow.snow_from_grains`), traced by the ``volpathlength``
            integrator instead of the surface BSDF (off by default). An XML scene gets its
            snow from a ``<medium>`` inside its terrain shape instead.
        snow_model: ``"walk"`` (the full random walk under each facet, the reference),
            ``"kernel"`` (the walk tabulated once per snowpack and cached,
            :mod:`lidar_mitsuba.ground.snow.kernel`: the cost of a surface hit) or ``"auto"`` (the
            kernel). An XML scene's ``<medium>`` is always walked.
        site: where on the Earth and when the scene lies
            (:class:`~lidar_mitsuba.geotrack.Site`; default: the paper's site in northern
            Greenland at local noon on the June solstice, at sea level): photon latitudes,
            longitudes and times, and the sun and air of an instrument with a link budget. A
            track with its own geolocation (a DEM granule's) keeps its own places and times
            (only the site's height applies).
        cloud: a cloud over the track (:class:`~lidar_mitsuba.atmosphere.cloud_layer.Cloud`, or a
            dict of its fields; None: clear sky): :mod:`lidar_mitsuba.atmosphere.cloud_kernel`.

    Raises:
        ParameterError: a bad value, named (``.name``), before anything is traced.
    Warns:
        SimulationWarning: the run completed but deserves a look (no photons and why, too few
        paths per shot, ...); also listed in ``result.config["warnings"]``.
    """
    p = plan(instrument=instrument, surface=surface, scene=scene, scene_file=scene_file,
             params=params, bsdf=bsdf, shots=shots, seed=seed, paths_per_shot=paths_per_shot,
             max_depth=max_depth, track=track, variant=variant, progress=progress,
             chunk_shots=chunk_shots, crop_to_track=crop_to_track, snow=snow,
             snow_model=snow_model, site=site, cloud=cloud)
    return assemble(p, stream(p, keep_returns=keep_returns, progress=progress))


def stream(run: RunPlan, *, keep_returns: bool | None = None,
           progress: bool = False) -> chunks.ChunkedRun:
    """Trace and detect the plan chunk by chunk (:func:`lidar_mitsuba.trace.stream.run`) over
    its surface's tiling: every chunk in the scene it is given (one for every chunk, or a
    DEM's corridor tile per chunk; the first plan's scene is let go once the stream has it:
    a live stale scene would join every later tile's kernel calls)."""
    ppp, mat = int(run.paths_per_shot), run.material
    if keep_returns is None:
        keep_returns = run.shots * ppp * mat.returns_per_path(run.max_depth) <= 2 ** 24
    source = chunks.TiledSource(run.integrator, run.tiling, paths_per_shot=ppp)
    run.tiling.release()
    if mat.gated:
        source = chunks.GatedSource(source, gate_ns=run.instrument.range_gate_ns,
                                    gate_center_ns=chunks.gate_center_ns(run.instrument,
                                                                         run.z_ref_m))
    if progress:       # a first run on this machine compiles the detector: say so
        warmup.compile_kernels()
    if run.cloud is not None:     # the cloud on every traced return (atmosphere.cloud_kernel)
        from .atmosphere import cloud_kernel
        source = cloud_kernel.CloudSource(
            source, run.cloud, run.cloud_table,
            instrument=run.instrument,
            gate_center_ns=chunks.gate_center_ns(run.instrument, run.z_ref_m))
    rad = run.radiometry
    chunked = chunks.run(
        source=source, detectors={"run": run.instrument}, z_ref_m=run.z_ref_m, seed=run.seed,
        chunk_shots=run.chunk_shots, keep_returns=keep_returns, progress=progress,
        detector_inputs=None if rad is None else rad.detector_inputs)
    run.timings_s.update(chunked.timings_s)
    run.surface_config.update(run.tiling.stats())
    return chunked


def _scene_of(run: RunPlan):
    """The scene of the run's first shots (a DEM's first tile, built again)."""
    return run.tiling.first_scene()


def assemble(run: RunPlan, chunked: chunks.ChunkedRun) -> SimulationResult:
    """Place and classify the photons, explain the run's choices and warn where it deserves
    a look, and gather the result."""
    mi = ensure_renderer()
    inst, det, mat, timings = run.instrument, chunked.detections["run"], run.material, run.timings_s
    t3 = time.perf_counter()
    h = retrieval.photon_heights_m(det.time_ns, altitude_m=inst.altitude_m)
    test = classify.histogram_test(shot=det.shot, h_m=h, gate_center_h_m=run.gate_z_m,
                                   range_gate_m=inst.range_gate_m)
    timings["detect_s"] += time.perf_counter() - t3
    timings["total_s"] = time.perf_counter() - run.t0
    cfg = run.surface_config
    choices, warns = explain.choices_and_warnings(
        instrument=inst, surf=run.surface, max_depth=run.max_depth, pilot=run.bounce_pilot,
        paths_per_shot=run.paths_per_shot, budget=run.path_budget, crop=run.crop_to_track,
        triangles=run.triangles, det=det, material=mat, shots=run.shots, timings=timings,
        facet_m=cfg.get("grid_m") or cfg.get("mesh_grid_m"))
    n_local = run.x_local_m.size
    warns += explain.diagnose(surf=run.surface, scene_of=lambda: _scene_of(run),
                              x_m=run.x_local_m, y_m=run.y_local_m,
                              surface_z=run.surface_z_m[:n_local], n_returns=chunked.n_returns,
                              det=det, instrument=inst)
    if run.cloud is not None and run.cloud.base_m < inst.range_gate_m / 2:
        warns.append(f"the cloud's base ({run.cloud.base_m:g} m) is inside the range gate: "
                     f"its kernel misses the light the layer scatters many times there (the "
                     f"surface ~10 cm too high under fog of optical depth 0.5, "
                     f"docs/guide/clouds.md); trace the layer in a scene (scenes/fog.xml)")
    for w in warns:
        warnings.warn(w, SimulationWarning, stacklevel=3)
    config = {"instrument": inst.to_dict(), "surface": cfg,
              "track": run.track.to_dict(), "shots": int(run.shots), "seed": int(run.seed),
              "paths_per_shot": int(run.paths_per_shot), "path_budget": run.path_budget,
              "max_depth": int(run.max_depth), "bounce_pilot": run.bounce_pilot,
              "variant": mi.variant(), "scene_integrator": run.scene_integrator,
              "plan": run.describe(), "choices": choices, "warnings": warns,
              **mat.config(), "integrator": run.integrator_dict["type"],
              "site": run.site.to_dict(),
              "radiometry": None if run.radiometry is None else run.radiometry.summary()}
    if run.cloud is not None:        # (a clear run's config is as it was)
        config["cloud"] = {**run.cloud.to_dict(), "kernel": run.cloud_table.summary()}
    return SimulationResult(instrument=inst, config=config, along_track_m=run.along_m,
                            shot_x_m=run.x_m, shot_y_m=run.y_m, surface_z_m=run.surface_z_m,
                            z_ref_m=run.z_ref_m, detections=det, h_m=h, signal_conf=test.conf,
                            returns=chunked.returns, timings_s=timings,
                            geolocation=run.geolocation, radiometry=run.radiometry,
                            signal_test=test)
