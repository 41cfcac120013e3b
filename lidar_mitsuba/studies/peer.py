"""Peer comparison with mitransient: the transient return of flat and sloped plates.

mitransient (the transient-rendering extension of Mitsuba 3, ``pip install mitransient``; our
``bench`` extra) renders time-resolved images with a camera-driven path tracer. Here it renders
the lidar return of the plates our closed forms cover, and both tools are charted as histogram
error against wall time (``bench``: ``peer.png``, ``bench.json["peer"]``).

The set-up, the same for both tools where the tools allow it:

- A Lambertian plate (albedo 0.9) through ``(0, 0, z0)``, flat or rising at 5 degrees along x,
  a 120 m square mesh. ``z0 = 123.45 m``: real surfaces do not sit at ``z = 0``.
- A nadir lidar at ``altitude_m`` above the plate centre with a Gaussian footprint
  (``sigma = 2.5 m``) and a Gaussian pulse (1 ns FWHM).
- **Ours**: ``pathlength`` traces photons from the footprint (importance-sampled) and returns
  per-photon round-trip times; legs to the spacecraft are float64.
- **mitransient** (``transient_path``, ``max_depth = 2``: direct illumination, its minimum):
  a one-pixel ``perspective`` camera and a co-located ``projector`` emitter whose irradiance
  texture is the Gaussian footprint (1024^2 texels over +-4 sigma), both looking down;
  ``transient_hdr_film`` bins the optical path length (OPL). Camera rays are spread uniformly
  over the +-4 sigma window and weighted by the footprint (camera-driven sampling), and each
  sample casts three rays (camera, shadow, continuation). ``near_clip`` shortens the camera leg
  and ``far_clip`` (default 10 km) must exceed the range; both are set and accounted for.
  Two placements: the camera 1 km above the plate (a careful user, float32 is then fine) and at
  the orbital 496 km (what the scene describes).

mitransient has no temporal filter other than the box (1.3.1), so both tools produce the
*impulse response* binned at 0.5 mm OPL, then the same code convolves it with the pulse
(cloud-in-cell deposit for our photons, which carry exact float64 OPLs; mitransient's bins are
what it gives). A third curve is our per-photon pipeline as the detector uses it: the pulse
sampled per photon, histogrammed directly.

Reference: the exact pulse-convolved waveform in 0.1 ns (3 cm OPL) bins, by Gauss quadrature
over each tool's own footprint geometry (parallel rays for ours; rays from the projector,
truncated to its +-4 sigma window, with its 1/r^2 and incidence-cosine weights for mitransient).
Error = relative L2 norm of (estimate - reference), both normalised to unit mass, RMS over
seeds; plus the centroid (mean range) error. Time = median wall time of render + histogram +
convolution, kernels compiled beforehand.
"""
from __future__ import annotations

import importlib.util
import math
import statistics
import time

import numpy as np
from scipy.signal import fftconvolve
from scipy.special import ndtr

from ..constants import C_M_PER_NS
from ..trace import lazy
from ..trace.lazy import dr, mi

scn = lazy.module("lidar_mitsuba.trace.scene")

PULSE_SIGMA_NS = 1.0 / (2.0 * math.sqrt(2.0 * math.log(2.0)))
PULSE_SIGMA_M = C_M_PER_NS * PULSE_SIGMA_NS          # pulse sigma in OPL [m]
FOOTPRINT_SIGMA_M = 2.5
PLATE_Z0_M = 123.45
PLATE_HALF_M = 60.0
ALBEDO = 0.9
FINE_BIN_M = 5e-4                                     # OPL bin of the impulse responses [m]
FINE_PER_COARSE = 60
COARSE_BIN_M = FINE_PER_COARSE * FINE_BIN_M           # 3 cm OPL = 0.1 ns comparison bins [m]
WINDOW_SIGMAS = 4.0                                   # projector / camera half-width [sigma]
ORBIT_M = 496e3
NEAR_M = 1e3
NEAR_CLIP_M = 1.0


def available() -> bool:
    """Whether mitransient is installed (``pip install 'lidar_mitsuba[bench]'``)."""
    return importlib.util.find_spec("mitransient") is not None


def _import_mitransient():
    import mitransient  # noqa: F401  (registers transient_path / transient_hdr_film)
    return mitransient


# --------------------------------------------------------------------------- geometry
def _plate_mesh(slope_deg: float, z0_m: float = PLATE_Z0_M) -> mi.Mesh:
    t = math.tan(math.radians(slope_deg))
    h = PLATE_HALF_M
    v = np.array([[-h, -h, z0_m - h * t], [h, -h, z0_m + h * t],
                  [h, h, z0_m + h * t], [-h, h, z0_m - h * t]])
    return scn.mitsuba_mesh(v, [[0, 1, 2], [0, 2, 3]],
                        bsdf={"type": "diffuse", "reflectance": {"type": "spectrum",
                                                                 "value": ALBEDO}})


def _window(slope_deg: float) -> tuple[float, float]:
    """Half-width [m of OPL] of the histogram window around the nominal OPL, and the
    return's OPL standard deviation (pulse and footprint on the slope)."""
    spread = 2 * FOOTPRINT_SIGMA_M * math.tan(math.radians(slope_deg))
    sd = math.hypot(PULSE_SIGMA_M, spread)
    return 7.0 * sd + 0.3, sd


def _nodes_parallel(slope_deg: float, altitude_m: float, n: int = 96):
    """Gauss-Hermite nodes of our footprint: OPL [m] and weight per node."""
    x, w = np.polynomial.hermite_e.hermegauss(n)
    x = x * FOOTPRINT_SIGMA_M
    X, Y = np.meshgrid(x, x, indexing="ij")
    W = np.outer(w, w)
    t = math.tan(math.radians(slope_deg))
    dz = altitude_m - X * t                            # spacecraft above the vertex
    leg = np.sqrt(X * X + Y * Y + dz * dz)
    cos_o = (t * X + dz) / (leg * math.sqrt(1 + t * t))      # n . (S - P) / |S - P|
    return 2.0 * leg, W * cos_o


def _nodes_projector(slope_deg: float, altitude_m: float, n: int = 160):
    """Gauss-Legendre nodes over the projector window in tan-angle space: OPL as mitransient
    accumulates it (two legs minus the near clip) and the weight (footprint texture x incidence
    cosine / r^2; the camera weights its window uniformly)."""
    half = WINDOW_SIGMAS * FOOTPRINT_SIGMA_M / altitude_m
    u, w = np.polynomial.legendre.leggauss(n)
    a = u * half
    A, B = np.meshgrid(a, a, indexing="ij")
    W = np.outer(w, w) * np.exp(-0.5 * (A * A + B * B) * (altitude_m / FOOTPRINT_SIGMA_M) ** 2)
    t = math.tan(math.radians(slope_deg))
    s = altitude_m / (1.0 + A * t)                     # ray parameter along (a, b, -1)
    norm = np.sqrt(1.0 + A * A + B * B)
    leg = s * norm
    cos_i = (t * A + 1.0) / (norm * math.sqrt(1 + t * t))
    opl = 2.0 * leg - NEAR_CLIP_M * norm
    return opl, W * cos_i / (leg * leg)


def reference(edges_m: np.ndarray, *, slope_deg: float, altitude_m: float,
              geometry: str) -> np.ndarray:
    """Exact pulse-convolved waveform: mass per OPL bin (``edges_m``, shape (k+1,), [m]),
    normalised to unit sum over the bins. ``geometry``: ``"parallel"`` (ours) or
    ``"projector"`` (mitransient's camera/projector pair)."""
    opl, w = (_nodes_parallel if geometry == "parallel" else _nodes_projector)(
        slope_deg, altitude_m)
    opl, w = opl.ravel(), w.ravel() / w.sum()
    cdf = np.stack([ndtr((e - opl) / PULSE_SIGMA_M) @ w for e in edges_m])
    mass = np.diff(cdf)
    return mass / mass.sum()


def _pulse_kernel() -> np.ndarray:
    m = np.arange(-int(6 * PULSE_SIGMA_M / FINE_BIN_M), int(6 * PULSE_SIGMA_M / FINE_BIN_M) + 1)
    k = ndtr((m + 0.5) * FINE_BIN_M / PULSE_SIGMA_M) - ndtr((m - 0.5) * FINE_BIN_M / PULSE_SIGMA_M)
    return k / k.sum()


def _coarse(fine: np.ndarray) -> np.ndarray:
    """Pulse-convolve a fine impulse histogram and sum it into the coarse bins."""
    per = FINE_PER_COARSE
    conv = fftconvolve(fine, _pulse_kernel(), mode="same")
    n = conv.size // per
    out = conv[:n * per].reshape(n, per).sum(axis=1)
    return out / out.sum() if out.sum() > 0 else out


# --------------------------------------------------------------------------- the two tools
class _Tool:
    """The OPL window of one tool on one plate: ``n_fine`` impulse bins of ``FINE_BIN_M``
    from ``lo`` [m], the coarse comparison ``edges`` [m], and the exact ``reference()``."""
    geometry = ""

    def __init__(self, slope_deg: float, *, range_m: float, centre_m: float,
                 float32_start: bool = False):
        self.slope_deg, self.range_m, self.centre_m = slope_deg, range_m, centre_m
        half, _ = _window(slope_deg)
        self.n_fine = int(round(2 * half / COARSE_BIN_M)) * FINE_PER_COARSE
        lo = centre_m - half
        self.lo = float(np.float32(lo)) if float32_start else lo
        self.edges = self.lo + COARSE_BIN_M * np.arange(self.n_fine // FINE_PER_COARSE + 1)

    def reference(self) -> np.ndarray:
        return reference(self.edges, slope_deg=self.slope_deg, altitude_m=self.range_m,
                         geometry=self.geometry)


class _Ours(_Tool):
    geometry = "parallel"

    def __init__(self, slope_deg: float, *, pulse: bool, z0_m: float = PLATE_Z0_M,
                 range_m: float = ORBIT_M):
        super().__init__(slope_deg, range_m=range_m, centre_m=2.0 * range_m)
        self.scene = mi.load_dict({"type": "scene", "plate": _plate_mesh(slope_deg, z0_m)})
        self.integ = mi.load_dict({"type": "pathlength", "altitude_m": z0_m + range_m,
                                   "footprint_sigma_m": FOOTPRINT_SIGMA_M,
                                   "pulse_sigma_ns": PULSE_SIGMA_NS if pulse else 0.0})
        self.pulse = pulse

    def run(self, n_paths: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        k = 256
        shots = max(1, n_paths // k)
        z = np.zeros(shots)
        r = self.integ.trace(self.scene, shot_x_m=z, shot_y_m=z, paths_per_shot=k, seed=seed)
        opl = r.time_ns * C_M_PER_NS
        w = r.weight.astype(np.float64)
        if self.pulse:     # the photons as the detector sees them: histogram directly
            h, _ = np.histogram(opl, bins=self.edges, weights=w)
            return h / max(h.sum(), 1e-300), None
        pos = (opl - self.lo) / FINE_BIN_M - 0.5          # cloud-in-cell onto bin centres
        i0 = np.floor(pos).astype(np.int64)
        ok = (i0 >= -1) & (i0 < self.n_fine)
        i0, f, w = i0[ok], pos[ok] - i0[ok], w[ok]
        n = self.n_fine + 2                               # one guard bin at either end
        fine = (np.bincount(i0 + 1, w * (1 - f), minlength=n)
                + np.bincount(i0 + 2, w * f, minlength=n))[1:-1]
        return _coarse(fine), fine


def mitransient_scene(shapes: dict, *, eye_z_m: float, target_z_m: float,
                      projector_fov_deg: float, camera_fov_deg: float, texels: int,
                      far_clip_m: float, temporal_bins: int, bin_width_opl: float,
                      start_opl: float) -> mi.Scene:
    """mitransient's lidar over ``shapes``: a co-located ``projector`` (its irradiance the
    Gaussian footprint, ``texels``^2 over +-WINDOW_SIGMAS) and one-pixel ``perspective``
    camera at ``eye_z_m`` looking down at ``target_z_m``, a ``transient_hdr_film`` binning the
    optical path length from ``start_opl`` [m] (the near clip subtracted)."""
    u = ((np.arange(texels) + 0.5) / texels * 2 - 1) * WINDOW_SIGMAS
    g = np.exp(-0.5 * (u[:, None] ** 2 + u[None, :] ** 2)).astype(np.float32)
    look = mi.ScalarTransform4f().look_at(origin=[0.0, 0.0, eye_z_m],
                                          target=[0.0, 0.0, target_z_m], up=[0.0, 1.0, 0.0])
    return mi.load_dict({
        "type": "scene", **shapes,
        "laser": {"type": "projector", "fov": projector_fov_deg, "to_world": look,
                  "irradiance": {"type": "bitmap", "bitmap": mi.Bitmap(g[:, :, None]),
                                 "raw": True}},
        "sensor": {"type": "perspective", "fov": camera_fov_deg, "to_world": look,
                   "near_clip": NEAR_CLIP_M, "far_clip": far_clip_m,
                   "film": {"type": "transient_hdr_film", "width": 1, "height": 1,
                            "temporal_bins": int(temporal_bins),
                            "bin_width_opl": bin_width_opl, "start_opl": start_opl,
                            "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 1}}})


class _Mitransient(_Tool):
    geometry = "projector"

    def __init__(self, slope_deg: float, *, altitude_m: float, z0_m: float = PLATE_Z0_M):
        _import_mitransient()
        # the film stores start_opl in float32
        super().__init__(slope_deg, range_m=altitude_m, centre_m=2.0 * altitude_m - NEAR_CLIP_M,
                         float32_start=True)
        fov = 2.0 * math.degrees(math.atan(WINDOW_SIGMAS * FOOTPRINT_SIGMA_M / altitude_m))
        self.scene = mitransient_scene(
            {"plate": _plate_mesh(slope_deg, z0_m)}, eye_z_m=z0_m + altitude_m,
            target_z_m=z0_m, projector_fov_deg=fov, camera_fov_deg=fov, texels=1024,
            far_clip_m=4.0 * altitude_m, temporal_bins=self.n_fine, bin_width_opl=FINE_BIN_M,
            start_opl=self.lo)
        self.integ = mi.load_dict({"type": "transient_path", "max_depth": 2})

    def run(self, n_paths: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        _, transient = self.integ.render(self.scene, spp=int(n_paths), seed=seed)
        fine = np.asarray(transient, dtype=np.float64).reshape(-1)[:self.n_fine]
        return _coarse(fine), fine


# --------------------------------------------------------------------------- study
def _error(h: np.ndarray, ref: np.ndarray, edges: np.ndarray) -> tuple[float, float]:
    """Relative L2 error and centroid error [m of range] of a unit-mass histogram."""
    mid = 0.5 * (edges[1:] + edges[:-1]) - edges[0]
    l2 = float(np.linalg.norm(h - ref) / np.linalg.norm(ref))
    return l2, float((h @ mid - ref @ mid) / 2.0)


def run(*, quick: bool = False, smoke: bool = False, progress=None) -> dict:
    """Both tools, both plates, a ladder of photon counts. Returns a JSON-ready dict:
    ``rows`` (tool, plate, paths, seconds (median), error (RMS relative L2 over seeds),
    range_bias_m (mean centroid error [m])) and ``ratios`` (mitransient time / our time at
    equal error, by log-log interpolation). ``smoke`` (the tests' size; implies ``quick``):
    one seed a count and two ranges in the float32 sweep (every row and field; its numbers
    only show that it runs)."""
    if not available():
        return {"skipped": "mitransient is not installed: pip install 'lidar_mitsuba[bench]'"}
    quick = quick or smoke
    exps = (12, 14, 16) if quick else (12, 14, 16, 18, 20, 22)
    seeds = (1,) if smoke else (1, 2) if quick else (1, 2, 3)
    tools = {
        "lidar_mitsuba (impulse + pulse)": lambda s: _Ours(s, pulse=False),
        "lidar_mitsuba (photons, pulse sampled)": lambda s: _Ours(s, pulse=True),
        "mitransient, camera 1 km above": lambda s: _Mitransient(s, altitude_m=NEAR_M),
        "mitransient, camera at 496 km": lambda s: _Mitransient(s, altitude_m=ORBIT_M),
    }
    rows, waveforms = [], {}
    for slope in (0.0, 5.0):
        plate = f"{slope:g} deg plate"
        for name, make in tools.items():
            tool = make(slope)
            ref = tool.reference()
            tool.run(2 ** exps[0], 0)                      # compile
            for e in exps:
                n = 2 ** e
                times, errs, bias = [], [], []
                for seed in seeds:
                    t = time.perf_counter()
                    h, fine = tool.run(n, seed)
                    dr.sync_thread()
                    times.append(time.perf_counter() - t)
                    l2, b = _error(h, ref, tool.edges)
                    errs.append(l2)
                    bias.append(b)
                rows.append({"tool": name, "plate": plate, "paths": n,
                             "seconds": statistics.median(times),
                             "error": float(np.sqrt(np.mean(np.square(errs)))),
                             "range_bias_m": float(np.mean(bias))})
                if progress:
                    progress(rows[-1])
            if slope > 0 and fine is not None:
                waveforms[name] = {"lo_m": tool.lo, "bin_m": FINE_BIN_M,
                                   "center_m": tool.centre_m, "fine": fine.tolist()}
    return {"rows": rows, "ratios": speed_ratios(rows), "waveforms": waveforms,
            "float32_sweep": float32_sweep(n_ranges=2 if smoke else 4 if quick else 12),
            "fine_bin_m": FINE_BIN_M, "coarse_bin_m": COARSE_BIN_M,
            "float32_opl_spacing_m": float(np.spacing(np.float32(2 * ORBIT_M)))}


def float32_sweep(*, n_ranges: int = 12, paths: int = 2 ** 16) -> list[dict]:
    """Range bias [m] of the flat plate's waveform centroid for ranges drawn uniformly in
    496-497 km (orbits are not integer metres), ours and mitransient (camera at that range).
    The flat plate's return has no Monte Carlo spread in OPL, so what is left is precision."""
    rng = np.random.default_rng(7)
    out = []
    for range_m in np.round(ORBIT_M + rng.uniform(0.0, 1000.0, n_ranges), 4):
        row = {"range_m": float(range_m)}
        for key, tool in (("ours_bias_m", _Ours(0.0, pulse=False, range_m=range_m)),
                          ("mitransient_bias_m", _Mitransient(0.0, altitude_m=range_m))):
            h, _ = tool.run(paths, 1)
            row[key] = _error(h, tool.reference(), tool.edges)[1]
        out.append(row)
    return out


def _noise_limited(rows: list[dict]) -> bool:
    """Whether a curve still falls like 1/sqrt(paths): 16x the paths at least halve the error
    (a precision or discretisation floor does not)."""
    by_n = {r["paths"]: r["error"] for r in rows}
    n = max(by_n)
    return n // 16 in by_n and by_n[n] < 0.5 * by_n[n // 16]


def speed_ratios(rows: list[dict], *, top: int = 3) -> list[dict]:
    """How many times longer mitransient takes than we do to reach the same waveform error,
    per plate: in the Monte Carlo regime (error^2 x time constant), the ratio of
    error^2 x time, median over the ``top`` largest path counts. Ours is the impulse + pulse
    curve (the same post-processing as mitransient's). ``None`` where a curve has stopped
    falling (a precision floor: no amount of time reaches the other's error)."""
    out = []
    for plate in sorted({r["plate"] for r in rows}):
        ours = [r for r in rows if r["plate"] == plate and r["tool"].endswith("(impulse + pulse)")]
        for peer in ("mitransient, camera 1 km above", "mitransient, camera at 496 km"):
            theirs = {r["paths"]: r for r in rows if r["plate"] == plate and r["tool"] == peer}
            mine = {r["paths"]: r for r in ours}
            common = sorted(set(theirs) & set(mine))[-top:]
            row = {"plate": plate, "peer": peer, "paths": common,
                   "ours_noise_limited": _noise_limited(ours),
                   "peer_noise_limited": _noise_limited(list(theirs.values()))}
            if common and row["ours_noise_limited"] and row["peer_noise_limited"]:
                ratios = [theirs[n]["error"] ** 2 * theirs[n]["seconds"]
                          / (mine[n]["error"] ** 2 * mine[n]["seconds"]) for n in common]
                row["ratio"] = float(statistics.median(ratios))
                row["error_ratio_at_equal_paths"] = float(statistics.median(
                    theirs[n]["error"] / mine[n]["error"] for n in common))
            else:
                row["ratio"] = None
            out.append(row)
    return out


def chart(doc: dict, path):
    """Error against wall time for both plates, and the impulse responses at orbital range.
    Saved to ``path``; returns the (closed) matplotlib Figure, or ``None`` (nothing drawn)
    when the comparison was skipped."""
    from ..plotting import plt
    if "rows" not in doc:
        return None
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.3), dpi=110)
    styles = {"lidar_mitsuba (impulse + pulse)": ("tab:orange", "o-"),
              "lidar_mitsuba (photons, pulse sampled)": ("tab:red", "s--"),
              "mitransient, camera 1 km above": ("tab:blue", "^-"),
              "mitransient, camera at 496 km": ("tab:purple", "v:")}
    for ax, plate in zip(axes, ("0 deg plate", "5 deg plate")):
        for name, (col, st) in styles.items():
            rr = [r for r in doc["rows"] if r["plate"] == plate and r["tool"] == name]
            if rr:
                rr = sorted(rr, key=lambda r: r["paths"])
                ax.loglog([r["seconds"] for r in rr], [max(r["error"], 1e-6) for r in rr],
                          st, color=col, label=name, ms=4)
        ax.set_xlabel("wall time [s] (median)")
        ax.set_ylabel("relative L2 error of the 0.1 ns waveform")
        ax.set_title(plate)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    ax = axes[2]
    for name, (col, _) in styles.items():
        wf = doc.get("waveforms", {}).get(name)
        if not wf:
            continue
        fine = np.asarray(wf["fine"])
        x = wf["lo_m"] + (np.arange(fine.size) + 0.5) * wf["bin_m"] - wf["center_m"]
        per = 20                                        # 1 cm OPL bins for display
        n = fine.size // per
        y = fine[:n * per].reshape(n, per).sum(1)
        ax.step(x[:n * per].reshape(n, per).mean(1) / 2, y / y.sum(), where="mid",
                color=col, lw=2.2 if name.startswith("lidar") else 0.8,
                ls="--" if name.startswith("lidar") else "-", label=name, zorder=3)
    ax.set_xlim(-0.8, 0.8)
    ax.set_xlabel("range from the plate centre [m] (impulse response, 5 mm range bins)")
    ax.set_ylabel("fraction of the return")
    ax.set_title("5 deg plate: float32 path lengths at 496 km quantise by "
                 f"{doc.get('float32_opl_spacing_m', 0.0625) * 100:.2f} cm of OPL", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return fig


def format_summary(doc: dict) -> str:
    if "rows" not in doc:
        return f"peer comparison: {doc.get('skipped', 'not run')}"
    lines = ["peer comparison (mitransient), relative L2 error of the 0.1 ns waveform:"]
    for plate in ("0 deg plate", "5 deg plate"):
        for name in dict.fromkeys(r["tool"] for r in doc["rows"]):
            rr = [r for r in doc["rows"] if r["plate"] == plate and r["tool"] == name]
            last = rr[-1]
            lines.append(f"  {plate}, {name}: {last['error']:.2e} at {last['paths']} paths in "
                         f"{last['seconds']:.3f} s; range bias {100 * last['range_bias_m']:+.2f} cm")
    for r in doc["ratios"]:
        if r["ratio"] is not None:
            lines.append(f"  {r['plate']}: at equal error {r['peer']} takes {r['ratio']:.1f}x "
                         f"our time (its error {r['error_ratio_at_equal_paths']:.1f}x ours at "
                         f"equal paths)")
        else:
            why = {(False, False): "both curves sit on a floor (no Monte Carlo error left)",
                   (True, False): "its error has a floor",
                   (False, True): "our impulse response is exact (no Monte Carlo error left)",
                   }.get((r["ours_noise_limited"], r["peer_noise_limited"]), "too few points")
            lines.append(f"  {r['plate']}: {r['peer']}: no speed ratio, {why}")
    sw = doc.get("float32_sweep") or []
    if sw:
        ours = max(abs(r["ours_bias_m"]) for r in sw)
        theirs = [abs(r["mitransient_bias_m"]) for r in sw]
        lines.append(f"  flat plate, {len(sw)} ranges in 496-497 km: range bias ours <= "
                     f"{ours * 1e3:.3f} mm, mitransient {min(theirs) * 100:.2f}-"
                     f"{max(theirs) * 100:.2f} cm (float32 OPL spacing "
                     f"{doc['float32_opl_spacing_m'] * 100:.2f} cm)")
    return "\n".join(lines)
