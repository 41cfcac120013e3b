"""Peer comparison with mitransient through water and cloud: a lake and a cloud layer.

The companion of :mod:`.peer` (flat and sloped plates) for the ``mediapathlength`` integrator:
mitransient renders the same two scenes with its transient path tracers and both tools'
impulse responses, binned in optical path length (OPL), are compared within their Monte Carlo
errors (``lake()``, ``cloud()``, ``plot()``).

The set-up, the same for both tools where the tools allow it (helpers from :mod:`.peer`):

- **Lake**: a 120 m square rough water surface through ``(0, 0, z0)`` (``z0 = 123.45 m``),
  Mitsuba's own ``roughdielectric`` (Beckmann, ``alpha = 0.1``, ``int_ior = 1.333``,
  ``ext_ior = 1``), so both tools see the same BSDF, over a Lambertian bottom (albedo 0.5) 1 m
  below. mitransient's OPL is the sum of n x length with n = 1.333 under water; ours takes the
  group index of a ``roughdielectric`` to be its phase index, 1.333, so both model one index.
- **Cloud**: a Lambertian 0.9 plate (120 m square, :func:`.peer._plate_mesh`) under a
  homogeneous layer 10 m to 30 m above it (a ``cube`` with a ``null`` BSDF, as wide as the
  plate; ``sigma_t`` = 0.025 / m: vertical optical depth 0.5; albedo 0.9; Henyey-Greenstein
  g = 0.7). Light in air and in the layer travels at c in both tools.
- A nadir lidar **1 km above** the water surface / plate (:data:`.peer.NEAR_M`, where
  float32 OPLs are fine) with a Gaussian footprint and no pulse (impulse responses), for both
  tools: the same placement, so the slant legs to points off nadir (r^2 / R: 12 mm at
  r = 2.5 m) are the same in both. Footprint sigma 2.5 m for the cloud; 0.5 m for the lake
  (see mitransient's index bug below, whose correction leaves (n-1) r^2 / 2R of spread).
- **Ours**: ``mediapathlength`` (photons from the footprint straight down, next-event returns
  toward the receiver; ``max_depth`` vertices: 2 in the lake, surface and bottom; 6 in the
  cloud), receiver FOV 20.65 m (lake) or unbounded (cloud: the forward-scattered halo is
  tens of metres wide). The OPL is measured from 2 x 1 km.
- **mitransient** (1.3.1): a one-pixel ``perspective`` camera and a co-located ``projector``
  with the footprint texture (+-4 sigma), ``transient_hdr_film`` in OPL, the near clip
  (1 m) subtracted as in :mod:`.peer`. Lake: ``transient_path``, ``max_depth = 4`` (camera,
  surface, bottom, underside of the surface, projector: its camera-driven path needs the
  extra underside vertex to reach the point emitter through the rough surface), camera window
  +-4 sigma. Cloud: ``transient_prbvolpath`` (mitransient's tracer for participating media:
  ``transient_path`` ignores media), ``max_depth = 7`` (vertices + 1, as ours' 6), Russian
  roulette off, camera window the whole plate (+-62 m) so that nothing the plate returns is
  clipped in either tool.

What each tool models differently:

- mitransient's next-event estimate adds the emitter leg times the index of the region the
  path arrived from, not the one the leg crosses. From the underside of the water surface
  the leg to the projector is in air but is counted at n = 1.333: every bottom return comes
  (n - 1) x ``|surface - projector|`` = 333 m (+ (n-1) r^2 / 2R) late. The comparison moves that
  window of mitransient's histogram back by (n - 1) x 1 km (an exact number of 2 cm bins) and
  reports the mass found anywhere else (none). Ours counts that leg in air.
- Rays: ours start vertically from the footprint; mitransient's fan out from the projector
  (<= 0.01 rad here; the irradiance's r^-2 and cos falls are 1e-4 effects).
- Ours is light-driven (importance transport), mitransient camera-driven (radiance): the
  1 / n^2 of the radiance leaving water enters in different places.
- Absolute scale: ours weighs 1 for a Lambertian 0.9 plate in clear air; mitransient's unit
  is the projector's. Each tool's returns are divided by its own render of that plate in
  clear air (same camera and projector), which makes them comparable.

Open point (run(), 33.5M mitransient samples): the cloud's layer returns are 3-5 % higher
in mitransient than ours (layer / clear plate z = -4.1, chi^2 p = 2e-3); at the test's size
(8.4M) they agree (p = 0.48). Not yet explained (both use Mitsuba's HG and medium).

Statistics: histograms in 2 cm (lake) or 0.5 m (cloud) OPL bins, each normalised to unit mass
over the window. Sampling errors from independent batches: ours from groups of shots (iid),
mitransient's from independent renders (seeds); the error of a normalised bin or of a ratio
of sums by the delta method over the batches. chi^2 = sum over bins holding >= 1e-4 of the
mass of (difference / combined standard error)^2, leaving out the largest bin (the unit-mass
constraint fixes it), dof = bins used. Scale-free ratios (bottom / surface, layer / ground,
late / direct ground) and the plate-calibrated ones, with their closed forms where one
exists.
"""
from __future__ import annotations

import math
import time

import numpy as np
from scipy import stats

from ..constants import C_M_PER_NS
from ..trace import lazy
from ..trace.lazy import mi

scn = lazy.module("lidar_mitsuba.trace.scene")
from .peer import (NEAR_CLIP_M, NEAR_M, PLATE_HALF_M, PLATE_Z0_M, WINDOW_SIGMAS,
                   mitransient_scene,
                   _import_mitransient, _plate_mesh, available)

RANGE_M = NEAR_M                   # lidar above the water surface / plate [m]
# lake
WATER_IOR = 1.333
WATER_ALPHA = 0.1
LAKE_DEPTH_M = 1.0
BOTTOM_ALBEDO = 0.5
LAKE_SIGMA_M = 0.5
LAKE_BIN_M = 0.02
LAKE_WINDOW_M = (-0.1065, 2.9935)  # OPL - 2R [m]: both peaks >= 3.5 mm from an edge
# cloud
CLOUD_BASE_M, CLOUD_TOP_M = 10.0, 30.0
CLOUD_TAU, CLOUD_ALBEDO, CLOUD_G = 0.5, 0.9, 0.7
CLOUD_SIGMA_M = 2.5
CLOUD_DEPTH = 6                    # vertices (ours); mitransient's max_depth is one more
CLOUD_BIN_M = 0.5
CLOUD_WINDOW_M = (-64.25, 60.25)
CLOUD_CAMERA_HALF_M = PLATE_HALF_M + 2.0
MIN_MASS = 1e-4                    # bins used in chi^2


# --------------------------------------------------------------------------- scenes
def _square(z_m: float, bsdf: dict) -> mi.Mesh:
    h = PLATE_HALF_M
    v = np.array([[-h, -h, z_m], [h, -h, z_m], [h, h, z_m], [-h, h, z_m]])
    return scn.mitsuba_mesh(v, [[0, 1, 2], [0, 2, 3]], bsdf=bsdf)


def _lake_shapes() -> dict:
    water = {"type": "roughdielectric", "distribution": "beckmann", "alpha": WATER_ALPHA,
             "int_ior": WATER_IOR, "ext_ior": 1.0}
    bottom = {"type": "diffuse", "reflectance": {"type": "spectrum", "value": BOTTOM_ALBEDO}}
    return {"surface": _square(PLATE_Z0_M, water),
            "bottom": _square(PLATE_Z0_M - LAKE_DEPTH_M, bottom)}


def _cloud_shapes() -> dict:
    h = CLOUD_TOP_M - CLOUD_BASE_M
    return {"plate": _plate_mesh(0.0),
            "layer": {"type": "cube", "bsdf": {"type": "null"},
                      "to_world": mi.ScalarTransform4f().translate([0, 0, PLATE_Z0_M + CLOUD_BASE_M + h / 2])
                      .scale([PLATE_HALF_M, PLATE_HALF_M, h / 2]),
                      "interior": {"type": "homogeneous", "sigma_t": CLOUD_TAU / h,
                                   "albedo": CLOUD_ALBEDO,
                                   "phase": {"type": "hg", "g": CLOUD_G}}}}


def _clear_shapes() -> dict:
    """The calibration plate: Lambertian 0.9 at z0 in clear air."""
    return {"plate": _plate_mesh(0.0)}


def _edges(window: tuple[float, float], bin_m: float) -> np.ndarray:
    n = int(round((window[1] - window[0]) / bin_m))
    return window[0] + bin_m * np.arange(n + 1)


# --------------------------------------------------------------------------- the two tools
def _ours(shapes: dict, edges: np.ndarray, *, sigma_m: float, max_depth: int, fov_m: float,
          shots: int, paths: int, batches: int, seed: int) -> tuple[np.ndarray, float]:
    """Our returns binned in OPL - 2R: (batches, bins) mean weight per path of each group of
    shots (iid), and the wall time [s] of the trace and histogram."""
    scene = mi.load_dict({"type": "scene", **shapes})
    integ = mi.load_dict({"type": "mediapathlength", "max_depth": max_depth,
                          "altitude_m": PLATE_Z0_M + RANGE_M, "footprint_sigma_m": sigma_m,
                          "pulse_sigma_ns": 0.0, "fov_radius_m": fov_m})
    z = np.zeros(shots)
    integ.trace(scene, shot_x_m=z[:8], shot_y_m=z[:8], paths_per_shot=paths, seed=seed + 99)
    t = time.perf_counter()
    r = integ.trace(scene, shot_x_m=z, shot_y_m=z, paths_per_shot=paths, seed=seed)
    rel = r.time_ns * C_M_PER_NS - 2.0 * RANGE_M
    k = np.searchsorted(edges, rel, side="right") - 1
    ok = (k >= 0) & (k < edges.size - 1)
    group = (r.shot.astype(np.int64) * batches) // shots
    nb = edges.size - 1
    h = np.bincount(group[ok] * nb + k[ok], weights=r.weight[ok].astype(np.float64),
                    minlength=batches * nb).reshape(batches, nb)
    h /= (shots // batches) * paths
    return h, time.perf_counter() - t


def _mit_scene(shapes: dict, edges: np.ndarray, *, sigma_m: float, camera_half_m: float,
               extra_bins: int = 0) -> mi.Scene:
    """mitransient's scene: camera and projector 1 km above z0; the film's window is
    ``edges`` (OPL - 2R + the near clip) plus ``extra_bins`` more after it."""
    return mitransient_scene(
        shapes, eye_z_m=PLATE_Z0_M + RANGE_M, target_z_m=PLATE_Z0_M,
        projector_fov_deg=2.0 * math.degrees(math.atan(WINDOW_SIGMAS * sigma_m / RANGE_M)),
        camera_fov_deg=2.0 * math.degrees(math.atan(camera_half_m / RANGE_M)), texels=512,
        far_clip_m=4.0 * RANGE_M, temporal_bins=edges.size - 1 + extra_bins,
        bin_width_opl=float(edges[1] - edges[0]),
        start_opl=2.0 * RANGE_M - NEAR_CLIP_M + float(edges[0]))


def _mit(scene: mi.Scene, integrator: dict, *, spp: int, seeds: int,
         seed: int) -> tuple[np.ndarray, float]:
    """mitransient's transient, one row per independent render (seed), and the wall time
    [s] of the renders (the kernel compiled beforehand)."""
    integ = mi.load_dict(integrator)
    integ.render(scene, spp=256, seed=10_000 + seed)
    t = time.perf_counter()
    rows = []
    for s in range(seeds):
        _, transient = integ.render(scene, spp=int(spp), seed=seed * 1000 + s)
        rows.append(np.asarray(transient, dtype=np.float64).reshape(-1))
    return np.array(rows), time.perf_counter() - t


# --------------------------------------------------------------------------- statistics
def _normalised(b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit-mass histogram of the batch mean and its standard error (delta method over the
    ``b.shape[0]`` iid batches)."""
    tot = b.sum(axis=1)
    mean_h, mean_t = b.mean(axis=0), tot.mean()
    h = mean_h / mean_t
    infl = (b - h[None, :] * tot[:, None]) / mean_t
    return h, infl.std(axis=0, ddof=1) / math.sqrt(b.shape[0])


def _ratio(num: np.ndarray, den: np.ndarray) -> tuple[float, float]:
    """Ratio of batch means and its delta-method standard error."""
    r = num.mean() / den.mean()
    return float(r), float((num - r * den).std(ddof=1) / den.mean() / math.sqrt(num.size))


def _agreement(ho: np.ndarray, so: np.ndarray, hm: np.ndarray, sm: np.ndarray) -> dict:
    """chi^2 of the unit-mass histograms over the bins holding >= MIN_MASS (both tools'
    errors > 0), the largest bin left out (the unit-mass constraint fixes it)."""
    se = np.hypot(so, sm)
    use = (0.5 * (ho + hm) >= MIN_MASS) & (so > 0) & (sm > 0)
    use[np.argmax(ho + hm)] = False
    z = np.where(use, (ho - hm) / np.where(se > 0, se, 1.0), 0.0)
    chi2 = float(np.sum(z[use] ** 2))
    dof = int(use.sum())
    return {"chi2": chi2, "dof": dof, "p_value": float(stats.chi2.sf(chi2, dof)),
            "z": z.tolist(), "used": use.tolist(), "max_abs_z": float(np.max(np.abs(z)))}


def _compare(ours: np.ndarray, mit: np.ndarray) -> dict:
    ho, so = _normalised(ours)
    hm, sm = _normalised(mit)
    return {"ours": ho.tolist(), "ours_se": so.tolist(), "mitransient": hm.tolist(),
            "mitransient_se": sm.tolist(), **_agreement(ho, so, hm, sm)}


def _pair(name: str, ours: tuple[float, float], mit: tuple[float, float],
          closed: float | None = None) -> dict:
    se = math.hypot(ours[1], mit[1])
    return {"name": name, "ours": ours[0], "ours_se": ours[1], "mitransient": mit[0],
            "mitransient_se": mit[1], "z": (ours[0] - mit[0]) / se if se > 0 else 0.0,
            "closed_form": closed}


# --------------------------------------------------------------------------- studies
def _lake_shift_m() -> float:
    """How much later than its true OPL mitransient puts a bottom return: the projector leg
    counted at n (+(n-1) R), less the two under-water segments it shortens by Mitsuba's
    float32 spawn offset, (1 + max|p|) RayEpsilon along the normal, at the surface and the
    bottom (each times n)."""
    eps = float(mi.math.RayEpsilon)
    short = sum((1.0 + abs(z)) * eps for z in (PLATE_Z0_M, PLATE_Z0_M - LAKE_DEPTH_M))
    return (WATER_IOR - 1.0) * RANGE_M - WATER_IOR * short


def _lake_mit(edges: np.ndarray, spp: int, seeds: int, seed: int):
    """mitransient on the lake in 0.5 mm bins, its bottom window moved back by
    :func:`_lake_shift_m` (to 0.25 mm) and summed into ``edges``' bins; returns the
    (seeds, bins) histogram, the mass outside both windows (relative), the wall time and the
    (seeds,) calibration plate totals."""
    per = 40
    fine = edges[0] + (LAKE_BIN_M / per) * np.arange((edges.size - 1) * per + 1)
    shift = int(round(_lake_shift_m() / (LAKE_BIN_M / per)))
    integ = {"type": "transient_path", "max_depth": 4}
    scene = _mit_scene(_lake_shapes(), fine, sigma_m=LAKE_SIGMA_M,
                       camera_half_m=WINDOW_SIGMAS * LAKE_SIGMA_M, extra_bins=shift)
    raw, secs = _mit(scene, integ, spp=spp, seeds=seeds, seed=seed)
    nf = fine.size - 1
    hist = raw[:, :nf].copy()
    below = fine[:-1] < 1.0                       # the surface's window (bottom: from 2.6 m)
    hist[:, ~below] = raw[:, shift:shift + nf][:, ~below]
    lost = raw.sum() - hist.sum()
    hist = hist.reshape(seeds, -1, per).sum(axis=2)
    plate = _mit_scene(_clear_shapes(), edges, sigma_m=LAKE_SIGMA_M,
                       camera_half_m=WINDOW_SIGMAS * LAKE_SIGMA_M)
    cal, _ = _mit(plate, integ, spp=spp // 4, seeds=seeds, seed=seed + 1)
    return hist, float(lost / raw.sum()), secs, cal.sum(axis=1)


def lake(*, shots: int = 16384, paths: int = 64, batches: int = 64, spp: int = 2 ** 20,
         seeds: int = 16, seed: int = 1) -> dict:
    """The lake (module docstring): both tools' unit-mass impulse responses in 2 cm OPL bins,
    chi^2, and the bottom / surface and plate-calibrated ratios with their errors."""
    _import_mitransient()
    edges = _edges(LAKE_WINDOW_M, LAKE_BIN_M)
    ours, t_ours = _ours(_lake_shapes(), edges, sigma_m=LAKE_SIGMA_M, max_depth=2,
                         fov_m=20.65, shots=shots, paths=paths, batches=batches, seed=seed)
    mit, lost, t_mit, cal = _lake_mit(edges, spp, seeds, seed)
    surf = edges[:-1] < 1.0
    f = ((WATER_IOR - 1) / (WATER_IOR + 1)) ** 2
    glint = f / (4 * WATER_ALPHA ** 2 * 0.9)      # Beckmann at nadir, per 0.9 plate
    bottom = (1 - f) ** 2 * BOTTOM_ALBEDO / WATER_IOR ** 2 / 0.9
    ob, os_ = ours[:, ~surf].sum(1), ours[:, surf].sum(1)
    mb, ms = mit[:, ~surf].sum(1), mit[:, surf].sum(1)
    ratios = [_pair("bottom / surface", _ratio(ob, os_), _ratio(mb, ms), bottom / glint),
              _pair("surface / 0.9 plate", (float(os_.mean()), float(os_.std(ddof=1)
                                                                      / math.sqrt(batches))),
                    _ratio(ms, cal), glint),
              _pair("bottom / 0.9 plate", (float(ob.mean()), float(ob.std(ddof=1)
                                                                    / math.sqrt(batches))),
                    _ratio(mb, cal), bottom)]
    return {"scene": "lake", "edges_m": edges.tolist(), "bin_m": LAKE_BIN_M,
            **_compare(ours, mit), "ratios": ratios, "mitransient_mass_elsewhere": lost,
            "mitransient_bottom_shift_m": _lake_shift_m(),
            "ours_paths": shots * paths, "mitransient_samples": spp * seeds,
            "ours_seconds": t_ours, "mitransient_seconds": t_mit}


def cloud(*, shots: int = 8192, paths: int = 64, batches: int = 64, spp: int = 2 ** 21,
          seeds: int = 16, seed: int = 1) -> dict:
    """The cloud layer (module docstring): both tools' unit-mass impulse responses in 0.5 m
    OPL bins, chi^2, and the layer / ground, late / direct and plate-calibrated ratios."""
    _import_mitransient()
    edges = _edges(CLOUD_WINDOW_M, CLOUD_BIN_M)
    kw = dict(sigma_m=CLOUD_SIGMA_M, max_depth=CLOUD_DEPTH, fov_m=1e4, shots=shots,
              paths=paths, batches=batches, seed=seed)
    ours, t_ours = _ours(_cloud_shapes(), edges, **kw)
    o_cal, _ = _ours(_clear_shapes(), edges, **{**kw, "shots": shots // 4})
    integ = {"type": "transient_prbvolpath", "max_depth": CLOUD_DEPTH + 1, "rr_depth": 1000}
    scenes = [_mit_scene(s, edges, sigma_m=CLOUD_SIGMA_M, camera_half_m=CLOUD_CAMERA_HALF_M)
              for s in (_cloud_shapes(), _clear_shapes())]
    mit, t_mit = _mit(scenes[0], integ, spp=spp, seeds=seeds, seed=seed)
    m_cal, _ = _mit(scenes[1], integ, spp=spp // 4, seeds=seeds, seed=seed + 1)
    mid = 0.5 * (edges[1:] + edges[:-1])
    layer, peak, late = mid < -1.0, np.abs(mid) < 0.25, mid > 0.25

    def parts(b, cal):
        oc = cal.sum(1)
        return {"layer / direct ground": _ratio(b[:, layer].sum(1), b[:, peak].sum(1)),
                "late ground / direct ground": _ratio(b[:, late].sum(1), b[:, peak].sum(1)),
                "direct ground / clear plate": _ratio(b[:, peak].sum(1), oc),
                "layer / clear plate": _ratio(b[:, layer].sum(1), oc),
                "total / clear plate": _ratio(b.sum(1), oc)}
    po, pm = parts(ours, o_cal), parts(mit, m_cal)
    h = CLOUD_TOP_M - CLOUD_BASE_M
    st, p180 = CLOUD_TAU / h, (1 - CLOUD_G ** 2) / (4 * math.pi * (1 + CLOUD_G) ** 3)
    single = CLOUD_ALBEDO * st * p180 * (1 - math.exp(-2 * CLOUD_TAU)) / (2 * st) * math.pi / 0.9
    ratios = [_pair(k, po[k], pm[k]) for k in po]
    return {"scene": "cloud", "edges_m": edges.tolist(), "bin_m": CLOUD_BIN_M,
            **_compare(ours, mit), "ratios": ratios,
            "single_scattering_layer_over_plate": single,     # lower bounds of the
            "unscattered_ground_over_plate": math.exp(-2 * CLOUD_TAU),   # two ratios
            "ours_paths": shots * paths, "mitransient_samples": spp * seeds,
            "ours_seconds": t_ours, "mitransient_seconds": t_mit}


# --------------------------------------------------------------------------- figure
def plot(results: list[dict], path):
    """One column per scene: both unit-mass histograms (log scale) and the residuals in
    combined standard errors. Saved to ``path``; returns the closed Figure."""
    from ..plotting import plt
    fig, axes = plt.subplots(2, len(results), figsize=(6.5 * len(results), 6.5), dpi=110,
                             sharex="col", squeeze=False,
                             gridspec_kw={"height_ratios": [3, 1]})
    for j, res in enumerate(results):
        edges = np.asarray(res["edges_m"])
        mid = 0.5 * (edges[1:] + edges[:-1]) / 2.0        # range [m] = OPL / 2
        ax, rx = axes[0, j], axes[1, j]
        for key, col, ls in (("ours", "tab:orange", "-"), ("mitransient", "tab:blue", "--")):
            y = np.asarray(res[key])
            ax.step(mid, np.where(y > 0, y, np.nan), where="mid", color=col, ls=ls,
                    label=f"{'lidar_mitsuba' if key == 'ours' else 'mitransient'}")
        ax.set_yscale("log")
        ax.set_ylabel(f"fraction of the return per {res['bin_m'] * 100:g} cm OPL bin")
        ax.set_title(f"{res['scene']}: chi2/dof = {res['chi2']:.1f}/{res['dof']}, "
                     f"p = {res['p_value']:.2g}", fontsize=9)
        lines = [f"{r['name']}: {r['ours']:.4g}±{r['ours_se']:.2g} vs "
                 f"{r['mitransient']:.4g}±{r['mitransient_se']:.2g} ({r['z']:+.1f} SE)"
                 for r in res["ratios"]]
        ax.text(0.02, 0.02, "\n".join(lines), transform=ax.transAxes, fontsize=6.5,
                va="bottom")
        ax.legend(fontsize=8)
        z = np.where(res["used"], res["z"], np.nan)
        rx.axhspan(-2, 2, color="0.9")
        rx.plot(mid, z, "k.", ms=3)
        rx.set_ylabel("(ours - mitr.) / SE")
        rx.set_xlabel("range after the surface / plate (OPL - 2 x 1 km) / 2 [m]")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return fig


def run(*, quick: bool = False) -> dict:
    """Both scenes (smaller with ``quick``); JSON-ready ``{"lake": ..., "cloud": ...}``."""
    if not available():
        return {"skipped": "mitransient is not installed: pip install 'lidar_mitsuba[bench]'"}
    s = 4 if quick else 1
    return {"lake": lake(shots=16384 // s, spp=2 ** 20 // s),
            "cloud": cloud(shots=8192 // s, spp=2 ** 21 // s)}


__all__ = ["lake", "cloud", "plot", "run"]
