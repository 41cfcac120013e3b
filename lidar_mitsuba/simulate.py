"""The Python API: simulate a ground track and get photons, references and statistics.

>>> import lidar_mitsuba as lm
>>> from lidar_mitsuba.simulate import simulate, SurfaceSpec
>>> from lidar_mitsuba.instrument import Instrument
>>> res = simulate(instrument=Instrument(beam="weak"), surface=SurfaceSpec(kind="fractal", p=1.8),
...                shots=1000, seed=1)                                    # doctest: +SKIP
>>> print(res.report().overall)                                          # doctest: +SKIP
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import mitsuba as mi
import numpy as np

from . import classify, pmt, retrieval, scene as scn, terrain
from .instrument import C_M_PER_NS, Instrument, ParameterError
from .variant import set_variant

SURFACES = ("flat", "slope", "fractal")


@dataclass(frozen=True)
class SurfaceSpec:
    """A built-in surface and its Ward reflectance (the paper's snow by default).

    Attributes:
        kind: ``flat``, ``slope`` or ``fractal``.
        slope_deg: slope of the ``slope`` plane [deg], in [0, 90).
        slope_azimuth_deg: direction of steepest ascent [deg] (0 = along track).
        p: spectral exponent of the fractal (1/f^p filter).
        relief_m: max - min height of the fractal tile [m].
        size_m: side of the square tile [m].
        grid_m: fractal grid spacing [m].
        terrain_seed: seed of the fractal's white noise.
        rho_d, rho_s, alpha: Ward diffuse albedo, specular reflectance, roughness.
    """
    kind: str = "fractal"
    slope_deg: float = 0.0
    slope_azimuth_deg: float = 0.0
    p: float = 1.8
    relief_m: float = 10.0
    size_m: float = 1024.0
    grid_m: float = 1.0
    terrain_seed: int = 0
    rho_d: float = 0.9
    rho_s: float = 0.05
    alpha: float = 0.3

    def __post_init__(self):
        if self.kind not in SURFACES:
            raise ParameterError("surface", f"must be one of {', '.join(SURFACES)} (got {self.kind!r})")
        if not (math.isfinite(self.slope_deg) and 0 <= self.slope_deg < 90):
            raise ParameterError("slope_deg", f"must be in [0, 90) (got {self.slope_deg})")
        if self.kind != "slope" and self.slope_deg != 0:
            raise ParameterError("slope_deg", "only applies to --surface slope")
        for name in ("rho_d", "rho_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0 <= v <= 1):
                raise ParameterError(name, f"must be in [0, 1] (got {v})")
        if self.rho_d + self.rho_s > 1:
            raise ParameterError("rho_d", f"rho_d + rho_s must be <= 1 (got {self.rho_d} + {self.rho_s})")
        if not (math.isfinite(self.alpha) and self.alpha > 0):
            raise ParameterError("alpha", f"must be > 0 (got {self.alpha})")
        if not (math.isfinite(self.size_m) and 1 <= self.size_m <= 1e5):
            raise ParameterError("size_m", f"must be in [1, 1e5] (got {self.size_m})")
        if not (math.isfinite(self.grid_m) and self.grid_m > 0):
            raise ParameterError("grid_m", f"must be > 0 (got {self.grid_m})")
        if self.kind == "fractal":
            try:   # the fractal's own checks, without building it
                terrain.check_fractal_parameters(p=self.p, size_m=self.size_m,
                                                 grid_m=self.grid_m, relief_m=self.relief_m)
            except ValueError as e:   # name the option: the grid count is set by --grid-m
                text = str(e)
                name = "grid_m" if text.startswith("size_m / grid_m") else text.split()[0]
                raise ParameterError(name, text) from None
            if self.relief_m > 1e4:
                raise ParameterError("relief_m", f"must be in [0, 1e4] (got {self.relief_m})")

    def bsdf_dict(self) -> dict:
        return scn.ward_bsdf_dict(rho_d=self.rho_d, rho_s=self.rho_s, alpha=self.alpha)

    def build(self):
        """The surface object: :class:`~lidar_mitsuba.scene.Plane` or a periodic Heightfield."""
        if self.kind == "fractal":
            return terrain.fractal(p=self.p, size_m=self.size_m, grid_m=self.grid_m,
                                   relief_m=self.relief_m, seed=self.terrain_seed)
        return scn.Plane(slope_deg=self.slope_deg if self.kind == "slope" else 0.0,
                         azimuth_deg=self.slope_azimuth_deg, size_m=self.size_m)


@dataclass
class SimulationResult:
    """Everything one run produced. Per-shot arrays have shape (shots,), per-photon (n_photons,).

    Attributes:
        instrument: the instrument simulated.
        config: the run's settings (JSON-serialisable).
        along_track_m: along-track distance of each footprint centre from the first [m].
        shot_x_m, shot_y_m: footprint centres in scene coordinates (unwrapped) [m].
        surface_z_m: surface height at each footprint centre [m].
        z_ref_m: reference elevation, the Gaussian-footprint-weighted mean height [m].
        detections: the detected photon events (:class:`~lidar_mitsuba.pmt.Detections`).
        h_m: elevation of each detected photon [m].
        signal_conf: ATL03-style confidence of each photon, 0 (noise) to 4 (high), from
            :func:`lidar_mitsuba.classify.signal_confidence`.
        hit_xyz_m: (n_photons, 3) float32 scattering point of each photon [m] (NaN for noise).
        returns: the traced returns (see ``PathLengthIntegrator.trace``), with global shot
            indices, or ``None`` when not kept (``keep_returns``).
        timings_s: wall time of each stage [s].
    """
    instrument: Instrument
    config: dict
    along_track_m: np.ndarray
    shot_x_m: np.ndarray
    shot_y_m: np.ndarray
    surface_z_m: np.ndarray
    z_ref_m: np.ndarray
    detections: pmt.Detections
    h_m: np.ndarray
    signal_conf: np.ndarray
    hit_xyz_m: np.ndarray
    returns: dict | None
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


def _tile_size(surf) -> float:
    if isinstance(surf, terrain.Heightfield):
        if surf.size_x_m != surf.size_y_m:
            raise ParameterError("surface", "heightfields must be square tiles")
        return float(surf.size_x_m)
    return float(surf.size_m)


def track_positions(n_shots: int, *, spacing_m: float, centre_x_m: float, y_m: float):
    """(along_track_m, x_m, y_m) of ``n_shots`` footprints along +x, centred on ``centre_x_m``."""
    along = np.arange(n_shots) * float(spacing_m)
    x = centre_x_m - along[-1] / 2.0 + along if n_shots else along
    return along, x, np.full(n_shots, float(y_m))


def _progress(total: int, desc: str, enabled: bool):
    if not enabled:
        return None, None
    from tqdm.auto import tqdm
    bar = tqdm(total=total, desc=desc, unit="shot", delay=2.0, leave=False)
    return bar, bar.update

PILOT_SHOTS = 1024      # shots (spread along the track) of the multiple-scattering pilot
PILOT_SEED = 0x50494C4F54   # fixed: a scene's choice does not depend on the run's seed
#: single bounce is enough when the second bounce moves bias and precision by less than this
#: fraction of the run's Monte Carlo error: far from 1, so that neither the pilot's own noise
#: nor its asymptotic error model flips the choice on a borderline scene
PILOT_MARGIN = 0.25


def single_bounce_error(*, dh_m: np.ndarray, weight: np.ndarray, depth: np.ndarray,
                        n_photons: float) -> dict:
    """What leaving out the second bounce does to a run's bias and precision, against the
    Monte Carlo error of that run. Pure numpy: the input is a ``max_depth = 2`` pilot trace.

    The returns are weighted samples of the photon height error ``dh = h - z_ref``. Single
    bounce keeps the depth-1 returns only; the full model keeps all. Their weighted means and
    standard deviations differ by ``d_bias_m`` and ``d_std_m``. A run of the full model that
    detects ``n_photons`` signal photons has Monte Carlo errors ``sigma / sqrt(n)`` in the bias
    and ``sigma * sqrt((kurtosis - 1) / (4 n))`` in the precision (the standard error of a
    sample standard deviation), with ``sigma`` and the kurtosis of the full distribution: a
    late tail of twice-scattered photons makes the precision of a run noisy, and a
    simplification need only stay below that noise. Single bounce is enough when both
    differences are under ``PILOT_MARGIN`` (a quarter) of the Monte Carlo error.

    Args:
        dh_m: (n,) height error of each return [m].
        weight: (n,) return weights (>= 0).
        depth: (n,) surface interaction of each return (1 = first surface, 2 = second).
        n_photons: detected signal photons of the run the choice is for.

    Returns:
        dict: ``d_bias_m``, ``d_std_m`` [m] (full model minus single bounce), ``mc_bias_m``,
        ``mc_std_m`` [m] (Monte Carlo error of the run), ``depth2_weight_fraction`` and
        ``single_bounce_enough`` (both differences under ``PILOT_MARGIN`` of the Monte Carlo
        error).
    """
    dh = np.asarray(dh_m, np.float64)
    w = np.asarray(weight, np.float64)
    depth = np.asarray(depth)
    ok = np.isfinite(dh) & (w > 0)
    dh, w, depth = dh[ok], w[ok], depth[ok]
    one = depth == 1
    if not one.any():
        raise ValueError("the pilot has no first-surface returns")

    def moments(x, v):
        m = np.average(x, weights=v)
        var = np.average((x - m) ** 2, weights=v)
        kurt = np.average((x - m) ** 4, weights=v) / var ** 2 if var > 0 else 3.0
        return m, math.sqrt(var), kurt

    m1, s1, _ = moments(dh[one], w[one])
    m, s, k = moments(dh, w)
    n = max(float(n_photons), 1.0)
    mc_bias, mc_std = s / math.sqrt(n), s * math.sqrt(max(k - 1.0, 0.0) / (4.0 * n))
    d_bias, d_std = m - m1, s - s1
    return {"d_bias_m": float(d_bias), "d_std_m": float(d_std),
            "mc_bias_m": float(mc_bias), "mc_std_m": float(mc_std),
            "depth2_weight_fraction": float(w[~one].sum() / w.sum()),
            "single_bounce_enough": bool(abs(d_bias) <= PILOT_MARGIN * mc_bias
                                         and abs(d_std) <= PILOT_MARGIN * mc_std)}


def _pilot(*, scene, instrument: Instrument, x_loc, y_loc, dz, z_ref, shots: int,
           paths_per_shot: int) -> dict:
    """Trace a ``max_depth = 2`` pilot on up to ``PILOT_SHOTS`` shots spread along the track
    and judge whether single bounce keeps the answer (:func:`single_bounce_error`), from the
    returns inside the range gate and the signal photons the run is expected to detect."""
    idx = np.unique(np.linspace(0, shots - 1, min(shots, PILOT_SHOTS)).round().astype(np.int64))
    integrator = mi.load_dict(instrument.integrator_dict(max_depth=2))
    ret = integrator.trace(scene, shot_x_m=x_loc[idx], shot_y_m=y_loc[idx],
                           paths_per_shot=int(paths_per_shot), seed=PILOT_SEED)
    s = ret["shot"].astype(np.int64)
    t_ns = ret["time_ns"] - 2.0 * dz[idx][s] / C_M_PER_NS
    dh = retrieval.photon_heights_m(t_ns, altitude_m=instrument.altitude_m) - z_ref[idx][s]
    dh[np.abs(dh) > instrument.range_gate_m / 2.0] = np.nan     # the gate records none of these
    photons_per_shot = (instrument.signal_photons * ret["weight"].sum(dtype=np.float64)
                        / (idx.size * paths_per_shot))
    n_photons = shots * photons_per_shot * instrument.fill_factor * instrument.pde
    try:
        out = single_bounce_error(dh_m=dh, weight=ret["weight"], depth=ret["depth"],
                                  n_photons=n_photons)
    except ValueError:      # nothing returned inside the gate: nothing to judge, trace both
        out = dict.fromkeys(("d_bias_m", "d_std_m", "mc_bias_m", "mc_std_m",
                             "depth2_weight_fraction"), math.nan)
        out["single_bounce_enough"] = False
    out.update(pilot_shots=int(idx.size), n_photons=float(n_photons))
    return out


def simulate(*, instrument: Instrument | None = None,
             surface: SurfaceSpec | terrain.Heightfield | scn.Plane | None = None,
             scene_file: str | None = None, bsdf: dict | None = None, shots: int = 1000,
             seed: int = 0, paths_per_shot: int = 128, max_depth: int | str = "auto",
             variant: str | None = None, progress: bool = True, chunk_shots: int = 65536,
             keep_returns: bool | None = None, crop_to_track: bool = True) -> SimulationResult:
    """Simulate ``shots`` laser shots along a ground track and detect their photons.

    Args:
        instrument: the lidar (default: strong beam, the paper's parameters).
        surface: a built-in surface (default: fractal p = 1.8, 10 m relief, Ward snow), or
            a ready :class:`~lidar_mitsuba.terrain.Heightfield` (e.g. your own DEM; periodic or
            not) or :class:`~lidar_mitsuba.scene.Plane` with the paper's Ward snow (or ``bsdf``).
        scene_file: a Mitsuba XML scene to use instead of ``surface`` (its own BSDFs; z up,
            metres); the track runs along +x through the centre of its bounding box.
        bsdf: a Mitsuba BSDF dict replacing the surface's Ward BSDF (any Mitsuba BSDF).
        shots: number of laser shots (>= 1).
        seed: seed of the photon Monte Carlo and the detector (same seed, same photons).
        paths_per_shot: photon paths traced per shot to sample its return.
        max_depth: surface interactions per photon path (1 = single bounce), or ``"auto"``:
            1 on a plane (exact: nothing bounces twice); elsewhere a ``max_depth = 2`` pilot
            on up to 1024 of the shots (fixed random numbers: the choice depends on the scene
            and the run's size, not on ``seed``) decides: single bounce when leaving out the
            second bounce moves the bias and the precision by less than a quarter of this
            run's Monte Carlo error (:func:`single_bounce_error`), else 2. The choice and
            its numbers are in ``result.config["max_depth"]`` and
            ``result.config["bounce_pilot"]``.
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
    if not isinstance(shots, (int, np.integer)) or not 1 <= shots <= 10 ** 8:
        raise ParameterError("shots", f"must be an integer in [1, 1e8] (got {shots!r})")
    if not isinstance(paths_per_shot, (int, np.integer)) or not 1 <= paths_per_shot <= 10 ** 6:
        raise ParameterError("paths_per_shot", f"must be an integer in [1, 1e6] (got {paths_per_shot!r})")
    auto_depth = isinstance(max_depth, str) and max_depth == "auto"
    if not auto_depth and (isinstance(max_depth, bool)
                           or not isinstance(max_depth, (int, np.integer))
                           or not 1 <= max_depth <= 64):
        raise ParameterError("max_depth", f"must be 'auto' or an integer in [1, 64] "
                             f"(got {max_depth!r})")
    if scene_file is not None and surface is not None:
        raise ParameterError("scene", "give either a scene file or a built-in surface, not both")
    if variant is not None:
        try:
            set_variant(variant)
        except ValueError as e:
            raise ParameterError("variant", str(e)) from None
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    sigma = instrument.footprint_sigma_m
    margin = 5.0 * sigma + 1.0

    if scene_file is not None:
        scene = mi.load_file(str(scene_file))
        lo, hi = scn.scene_bounds(scene)
        cx, cy = 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])
        along, x, y = track_positions(shots, spacing_m=instrument.shot_spacing_m,
                                      centre_x_m=cx, y_m=cy)
        if x[0] - margin < lo[0] or x[-1] + margin > hi[0]:
            raise ParameterError("shots", f"a track of {along[-1]:.1f} m plus footprints does not "
                                 f"fit the scene's {hi[0] - lo[0]:.1f} m extent along x")
        x_loc, y_loc, dz = x, y, np.zeros(shots)
        surface_z = scn.cast_heights_m(scene, x, y)
        z_ref = scn.raycast_reference_elevation_m(scene, x, y, sigma_m=sigma)
        surf_cfg = {"scene_file": str(scene_file)}
    else:
        surface = surface or SurfaceSpec()
        if isinstance(surface, SurfaceSpec):
            surf = surface.build()
        else:   # a ready Heightfield or Plane
            surf = surface
            surface = SurfaceSpec(kind="fractal" if isinstance(surf, terrain.Heightfield)
                                  else "slope", size_m=_tile_size(surf),
                                  grid_m=getattr(surf, "grid_m", 1.0),
                                  slope_deg=getattr(surf, "slope_deg", 0.0))
        size = surface.size_m
        along, x, y = track_positions(shots, spacing_m=instrument.shot_spacing_m,
                                      centre_x_m=size / 2.0, y_m=size / 2.0)
        if isinstance(surf, scn.Plane):
            x_loc, y_loc, dz = surf.wrap(x, y)
        else:
            x_loc, y_loc, dz = scn.heightfield_wrap(surf, x, y)
        # mesh only the corridor the photons can reach: footprints (5 sigma) for single
        # bounce; the receiver's field of view when paths may bounce on
        if auto_depth and isinstance(surf, scn.Plane):
            max_depth, auto_depth = 1, False
        reach = margin if max_depth == 1 else max(margin, instrument.fov_diameter_m / 2 + 5.0)
        bounds = None
        if crop_to_track:
            bounds = (float(x_loc.min()) - reach, float(x_loc.max()) + reach,
                      float(y_loc.min()) - reach, float(y_loc.max()) + reach)
        if isinstance(surf, scn.Plane):
            tm = surf.to_trimesh(margin_m=reach, bounds_m=bounds)
        else:
            tm = scn.heightfield_to_trimesh(surf, margin_m=reach, bounds_m=bounds)
        scene = scn.scene_from_trimesh(tm, bsdf=bsdf if bsdf is not None else surface.bsdf_dict())
        surface_z = surf.height_m(x, y)
        z_ref = surf.reference_elevation_m(x, y, sigma_m=sigma)
        surf_cfg = asdict(surface)
        surf_cfg["mesh_triangles"] = int(len(tm.faces))
        surf_cfg["crop_to_track"] = bool(crop_to_track)
        if bsdf is not None:
            surf_cfg["bsdf"] = repr(bsdf)
    timings["scene_s"] = time.perf_counter() - t0

    pilot = None
    if auto_depth:
        t1 = time.perf_counter()
        pilot = _pilot(scene=scene, instrument=instrument, x_loc=x_loc, y_loc=y_loc, dz=dz,
                       z_ref=z_ref, shots=int(shots), paths_per_shot=int(paths_per_shot))
        max_depth = 1 if pilot["single_bounce_enough"] else 2
        timings["pilot_s"] = time.perf_counter() - t1
    integrator = mi.load_dict(instrument.integrator_dict(max_depth=max_depth))
    gate_center_ns = 2.0 * (instrument.altitude_m - z_ref) / C_M_PER_NS
    if keep_returns is None:
        keep_returns = shots * paths_per_shot * max_depth <= 2 ** 24
    per_chunk = max(1, int(chunk_shots))
    parts, kept_returns, n_returns = [], [], 0
    timings["trace_s"] = timings["detect_s"] = 0.0
    bar, update = _progress(shots, "simulating", progress)
    try:
        for k, a in enumerate(range(0, shots, per_chunk)):
            b = min(shots, a + per_chunk)
            chunk_seed = int(np.random.SeedSequence([int(seed), k]).generate_state(1)[0])
            t1 = time.perf_counter()
            ret = integrator.trace(scene, shot_x_m=x_loc[a:b], shot_y_m=y_loc[a:b],
                                   paths_per_shot=int(paths_per_shot), seed=chunk_seed)
            if np.any(dz[a:b]):   # fold the exact plane offset back in (float64)
                off = dz[a:b][ret["shot"]]
                ret["time_ns"] = ret["time_ns"] - 2.0 * off / C_M_PER_NS
                ret["z_m"] = (ret["z_m"] + off).astype(np.float32)
                ret["x_m"] = (ret["x_m"] + (x - x_loc)[a:b][ret["shot"]]).astype(np.float32)
            t2 = time.perf_counter()
            rng = np.random.default_rng([int(seed), 0x504D54, k])
            det = pmt.detect(ret, instrument, rng, gate_center_ns=gate_center_ns[a:b])
            sig = det.return_index >= 0
            hit = np.full((len(det), 3), np.nan, np.float32)
            for j, axis in enumerate(("x_m", "y_m", "z_m")):
                hit[sig, j] = ret[axis][det.return_index[sig]]
            parts.append((det, a, n_returns, hit))
            if keep_returns:
                ret["shot"] = ret["shot"].astype(np.int64) + a
                kept_returns.append(ret)
            n_returns += int(ret["weight"].size)
            timings["trace_s"] += t2 - t1
            timings["detect_s"] += time.perf_counter() - t2
            if update is not None:
                update(b - a)
    finally:
        if bar is not None:
            bar.close()
    det = pmt.Detections(
        shot=np.concatenate([d.shot + a for d, a, _, _ in parts]),
        channel=np.concatenate([d.channel for d, *_ in parts]),
        anode=np.concatenate([d.anode for d, *_ in parts]),
        time_ns=np.concatenate([d.time_ns for d, *_ in parts]),
        return_index=np.concatenate([np.where(d.return_index >= 0, d.return_index + off, -1)
                                     for d, _, off, _ in parts]),
        is_signal=np.concatenate([d.is_signal for d, *_ in parts]),
        arrivals_per_shot=np.concatenate([d.arrivals_per_shot for d, *_ in parts]),
        mean_photons_per_shot=np.concatenate([d.mean_photons_per_shot for d, *_ in parts]))
    hit_xyz = np.concatenate([h for *_, h in parts])
    returns = None
    if keep_returns:
        returns = {key: np.concatenate([r[key] for r in kept_returns])
                   for key in ("shot", "time_ns", "weight", "x_m", "y_m", "z_m", "depth")}
        returns.update(paths_per_shot=int(paths_per_shot), n_shots=int(shots))
    t3 = time.perf_counter()
    h = retrieval.photon_heights_m(det.time_ns, altitude_m=instrument.altitude_m)
    conf = classify.signal_confidence(shot=det.shot, h_m=h, gate_center_h_m=np.nan_to_num(z_ref),
                                      range_gate_m=instrument.range_gate_m)
    timings["detect_s"] += time.perf_counter() - t3
    timings["total_s"] = time.perf_counter() - t0

    choices = _explain(instrument=instrument, surface=surface, scene_file=scene_file,
                       max_depth=max_depth, pilot=pilot, paths_per_shot=paths_per_shot,
                       crop_to_track=crop_to_track, surf_cfg=surf_cfg, det=det)
    config = {"instrument": instrument.to_dict(), "surface": surf_cfg, "shots": int(shots),
              "seed": int(seed), "paths_per_shot": int(paths_per_shot), "max_depth": int(max_depth),
              "bounce_pilot": pilot, "variant": mi.variant(), "choices": choices}
    return SimulationResult(instrument=instrument, config=config, along_track_m=along,
                            shot_x_m=x, shot_y_m=y, surface_z_m=surface_z, z_ref_m=z_ref,
                            detections=det, h_m=h, signal_conf=conf, hit_xyz_m=hit_xyz,
                            returns=returns, timings_s=timings)


def _explain(*, instrument, surface, scene_file, max_depth, pilot, paths_per_shot,
             crop_to_track, surf_cfg, det) -> list[str]:
    """The modelling choices of a run, in words (``lidar-mitsuba simulate --explain``)."""
    out = []
    plane = scene_file is None and surface.kind != "fractal"
    if plane and max_depth == 1:
        out.append("single bounce (max_depth 1): exact for a plane, where nothing bounces twice")
    elif pilot is not None and not math.isfinite(pilot["d_bias_m"]):
        out.append(f"bounces: the max_depth 2 pilot on {pilot['pilot_shots']} shots saw no "
                   "first-surface return inside the range gate, so max_depth 2 to be safe")
    elif pilot is not None:
        cm = {k: 100 * pilot[k] for k in ("d_bias_m", "d_std_m", "mc_bias_m", "mc_std_m")}
        verdict = ("below a quarter of it: single bounce (max_depth 1) keeps the answer"
                   if max_depth == 1 else "not below a quarter of it: max_depth 2")
        out.append(f"bounces chosen by a max_depth 2 pilot on {pilot['pilot_shots']} shots: the "
                   f"second bounce carries {100 * pilot['depth2_weight_fraction']:.2f} % of the "
                   f"return and moves the bias by {cm['d_bias_m']:+.2f} cm and the precision by "
                   f"{cm['d_std_m']:+.2f} cm, against this run's Monte Carlo error of "
                   f"{cm['mc_bias_m']:.2f} / {cm['mc_std_m']:.2f} cm ({pilot['n_photons']:.0f} "
                   f"signal photons): {verdict}; --max-depth N sets it")
    elif max_depth == 1:
        out.append("single bounce (max_depth 1, the paper's model, as asked): each photon's "
                   "first-surface return, which at nadir comes back along its own incident ray; "
                   "it leaves out multiple scattering between terrain facets (--max-depth auto "
                   "checks whether that matters)")
    else:
        out.append(f"{max_depth} bounces per path with shadow-tested returns toward the receiver")
    if plane:
        out.append("plane: two triangles; a track of any length folds into the tile exactly")
    elif scene_file is None:
        tri = surf_cfg.get("mesh_triangles")
        if crop_to_track:
            out.append(f"mesh cropped to the track corridor: {tri} triangles (the footprints' "
                       f"5 sigma{'' if max_depth == 1 else ' / the field of view'}); "
                       f"--full-tile meshes the whole {surface.size_m:g} m tile")
        else:
            out.append(f"whole {surface.size_m:g} m tile meshed: {tri} triangles")
        ratio = instrument.footprint_sigma_m / surface.grid_m
        out.append(f"mesh spacing {surface.grid_m:g} m = footprint sigma / {ratio:.1f}"
                   + ("" if ratio >= 2 else ": coarser than the footprint resolves; "
                      "use a finer --grid-m"))
    peak = float(np.max(det.mean_photons_per_shot)) if det.mean_photons_per_shot.size else 0.0
    kept = peak * instrument.fill_factor * instrument.pde
    msg = (f"{paths_per_shot} paths per shot for up to {peak:.1f} photons per shot "
           f"({kept:.1f} after fill factor and PDE)")
    if paths_per_shot < 3 * max(kept, 1e-9):
        msg += ": too few, photons share paths; raise --paths-per-shot above 3x the photons"
    out.append(msg)
    return out
