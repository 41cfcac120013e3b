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

import time
from dataclasses import dataclass, field

import mitsuba as mi
import numpy as np

from . import bounce_pilot, chunks, classify, retrieval, surface as surfaces
from .constants import ParameterError
from .instrument import Instrument
from .photons import Detections, Returns
from .surface import SceneSurface, SurfaceSpec
from .track import Track
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


def _check_run(shots, paths_per_shot, max_depth) -> None:
    if isinstance(shots, bool) or not isinstance(shots, (int, np.integer)) or not 1 <= shots <= 10 ** 8:
        raise ParameterError("shots", f"must be an integer in [1, 1e8] (got {shots!r})")
    if (isinstance(paths_per_shot, bool) or not isinstance(paths_per_shot, (int, np.integer))
            or not 1 <= paths_per_shot <= 10 ** 6):
        raise ParameterError("paths_per_shot", f"must be an integer in [1, 1e6] "
                             f"(got {paths_per_shot!r})")
    if max_depth != "auto" and (isinstance(max_depth, bool)
                                or not isinstance(max_depth, (int, np.integer))
                                or not 1 <= max_depth <= 64):
        raise ParameterError("max_depth", f"must be 'auto' or an integer in [1, 64] "
                             f"(got {max_depth!r})")


def simulate(*, instrument: Instrument | None = None,
             surface: SurfaceSpec | surfaces.Surface | None = None,
             scene_file: str | None = None, bsdf: dict | None = None, shots: int = 1000,
             seed: int = 0, paths_per_shot: int = 128, max_depth: int | str = "auto",
             track: Track | None = None, variant: str | None = None, progress: bool = True,
             chunk_shots: int = chunks.CHUNK_SHOTS, keep_returns: bool | None = None,
             crop_to_track: bool = True) -> SimulationResult:
    """Simulate ``shots`` laser shots along a ground track and detect their photons.

    Args:
        instrument: the lidar (default: strong beam, the paper's parameters).
        surface: a built-in surface (default: fractal p = 1.8, 10 m relief, Ward snow), or
            a ready :class:`~lidar_mitsuba.terrain.Heightfield` (e.g. your own DEM; periodic or
            not), :class:`~lidar_mitsuba.surface.Plane` (with the paper's Ward snow, or
            ``bsdf``) or :class:`~lidar_mitsuba.surface.SceneSurface`.
        scene_file: a Mitsuba XML scene to use instead of ``surface`` (its own BSDFs; z up,
            metres).
        bsdf: a Mitsuba BSDF dict replacing the surface's Ward BSDF (any Mitsuba BSDF).
        shots: number of laser shots (>= 1).
        seed: seed of the photon Monte Carlo and the detector (same seed, same photons).
        paths_per_shot: photon paths traced per shot to sample its return.
        max_depth: surface interactions per photon path (1 = single bounce), or ``"auto"``:
            1 on a plane (exact: nothing bounces twice); elsewhere a two-bounce pilot decides
            (:mod:`lidar_mitsuba.bounce_pilot`). The choice and its numbers are in
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
    """
    instrument = instrument or Instrument()
    _check_run(shots, paths_per_shot, max_depth)
    if scene_file is not None and surface is not None:
        raise ParameterError("scene", "give either a scene file or a built-in surface, not both")
    if variant is not None:
        try:
            set_variant(variant)
        except ValueError as e:
            raise ParameterError("variant", str(e)) from None
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    if scene_file is not None:
        surface = SceneSurface(mi.load_file(str(scene_file)), source=str(scene_file))
    surf, default_bsdf, surf_cfg = surfaces.resolve(surface)
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
    reach = margin if max_depth == 1 else max(margin, instrument.fov_diameter_m / 2 + 5.0)
    bounds = None
    if crop_to_track:
        bounds = (float(x_loc.min()) - reach, float(x_loc.max()) + reach,
                  float(y_loc.min()) - reach, float(y_loc.max()) + reach)
    scene, triangles = surf.mitsuba_scene(bsdf=bsdf if bsdf is not None else default_bsdf,
                                          margin_m=reach, bounds_m=bounds)
    surface_z = surf.height_m(x, y)
    z_ref = surf.reference_elevation_m(x, y, sigma_m=sigma)
    if surf.takes_bsdf:
        surf_cfg.update(mesh_triangles=triangles, crop_to_track=bool(crop_to_track))
    if bsdf is not None:
        surf_cfg["bsdf"] = repr(bsdf)
    timings["scene_s"] = time.perf_counter() - t0

    pilot = None
    if max_depth == "auto":
        t1 = time.perf_counter()
        pilot = bounce_pilot.run_pilot(scene=scene, instrument=instrument, x_m=x_loc, y_m=y_loc,
                                       dz_m=dz, z_ref_m=z_ref, paths_per_shot=int(paths_per_shot))
        max_depth = 1 if pilot["single_bounce_enough"] else 2
        timings["pilot_s"] = time.perf_counter() - t1
    integrator = mi.load_dict(instrument.integrator_dict(max_depth=max_depth))
    if keep_returns is None:
        keep_returns = shots * paths_per_shot * max_depth <= 2 ** 24
    run = chunks.run(
        source=chunks.traced(integrator, scene, x_m=x_loc, y_m=y_loc,
                             paths_per_shot=int(paths_per_shot), dx_m=x - x_loc,
                             dy_m=y - y_loc, dz_m=dz),
        detectors={"run": instrument}, z_ref_m=z_ref, seed=seed, chunk_shots=chunk_shots,
        keep_returns=keep_returns, progress=progress)
    timings.update(run.timings_s)
    det = run.detections["run"]
    t3 = time.perf_counter()
    h = retrieval.photon_heights_m(det.time_ns, altitude_m=instrument.altitude_m)
    conf = classify.signal_confidence(shot=det.shot, h_m=h, gate_center_h_m=np.nan_to_num(z_ref),
                                      range_gate_m=instrument.range_gate_m)
    timings["detect_s"] += time.perf_counter() - t3
    timings["total_s"] = time.perf_counter() - t0

    choices = _explain(instrument=instrument, surf=surf, max_depth=max_depth, pilot=pilot,
                       paths_per_shot=paths_per_shot, crop=crop_to_track, triangles=triangles,
                       det=det)
    config = {"instrument": instrument.to_dict(), "surface": surf_cfg, "track": track.to_dict(),
              "shots": int(shots), "seed": int(seed), "paths_per_shot": int(paths_per_shot),
              "max_depth": int(max_depth), "bounce_pilot": pilot, "variant": mi.variant(),
              "choices": choices}
    return SimulationResult(instrument=instrument, config=config, along_track_m=along,
                            shot_x_m=x, shot_y_m=y, surface_z_m=surface_z, z_ref_m=z_ref,
                            detections=det, h_m=h, signal_conf=conf, returns=run.returns,
                            timings_s=timings)


def _explain(*, instrument, surf, max_depth, pilot, paths_per_shot, crop, triangles,
             det) -> list[str]:
    """The modelling choices of a run, in words (``lidar-mitsuba simulate --explain``)."""
    out = []
    if surf.exact_single_bounce and max_depth == 1:
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
    out += surf.notes(instrument=instrument, max_depth=max_depth, crop=crop, triangles=triangles)
    peak = float(np.max(det.mean_photons_per_shot)) if det.mean_photons_per_shot.size else 0.0
    kept = peak * instrument.fill_factor * instrument.pde
    msg = (f"{paths_per_shot} paths per shot for up to {peak:.1f} photons per shot "
           f"({kept:.1f} after fill factor and PDE)")
    if paths_per_shot < 3 * max(kept, 1e-9):
        msg += ": too few, photons share paths; raise --paths-per-shot above 3x the photons"
    out.append(msg)
    return out
