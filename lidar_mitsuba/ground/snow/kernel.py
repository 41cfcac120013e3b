"""Snow as a tabulated subsurface kernel: the full random walk (``volpathlength``) run once per
snowpack on tilted planes, reduced to what a lidar return needs, and cached on disk.

At nadir, light enters a facet of a homogeneous (or layered) snowpack at an incidence angle
equal to the facet's tilt and comes back along the way it came; the walk runs in the entry
facet's plane. So for a given snowpack its result depends on that one angle: per incident
photon, the mean return weight ``W(theta)`` and the weighted distribution of the extra optical
path ``L`` (the group index included) that the returned light spends inside. :func:`build`
traces the walk at nodes every 5 deg of incidence (a point footprint, a zero-width pulse, on a
plane through the origin tilted by the node's angle), and stores ``W`` and the quantile
function of ``L`` (:mod:`lidar_mitsuba_plugins.kernel_table`); the ``snowkernel`` integrator
then draws each photon's weight and delay from it at the cost of a surface hit.

Tables are cached under ``$LIDAR_MITSUBA_CACHE`` (default ``~/.cache/lidar_mitsuba``)
``/snow_kernel/<key>.npz``, the key a hash of everything the walk depends on (the snowpack's
coefficients, phase function, group index, layer, base, interaction cap, the table's
photons and seed, and :data:`VERSION`).

How many photons (:data:`PHOTONS`): the table's own Monte Carlo error must be far below a run's.
Its mean extra path has a standard error ``sd(L) / sqrt(N_eff)`` with ``N_eff`` the walk's
effective number of weighted returns; :func:`build` records it (``mean_path_se_m``), and the
tests hold it below a tenth of the elevation error of the runs that use it.
"""
from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import math
import os
import pathlib
import time

import numpy as np

from lidar_mitsuba_plugins import kernel_table

from ...constants import C_M_PER_NS

VERSION = 3
"""Bumped when the walk or the table's layout changes: old cache files are then ignored."""
N_NODES = 18
"""Nodes at 0, 5, ..., 85 deg of incidence (steeper facets use the last)."""
N_QUANTILES = 1024


def _photons_from_env(default: int = 1 << 17) -> int:
    raw = os.environ.get("LIDAR_MITSUBA_KERNEL_PHOTONS", "").strip()
    if not raw:
        return default
    if not raw.isdigit() or int(raw) < 1024:
        from ...constants import ParameterError
        raise ParameterError("LIDAR_MITSUBA_KERNEL_PHOTONS",
                             f"must be a whole number of walk photons >= 1024 (got {raw!r})")
    return int(raw)


PHOTONS = _photons_from_env()
"""Walk photons per node up to :data:`STEEP_DEG` (the facets a terrain mostly has); a
quarter of that beyond. ``$LIDAR_MITSUBA_KERNEL_PHOTONS`` sets it for a process and the
processes it starts (a campaign's workers): fewer photons build a table faster, with a larger
``mean_path_se_m``, under another key."""
STEEP_DEG = 30.0
ALTITUDE_M = 1000.0
"""Height of the tabulating trace's receiver above the plane [m] (any: only the extra path
is kept)."""


@contextlib.contextmanager
def photons_per_node(n: int | None):
    """Build tables with ``n`` walk photons per node inside the block (None: :data:`PHOTONS`
    unchanged). The photon count is part of a table's key, so a smaller table never stands in
    for a full one; quick studies use it where their numbers are a smoke run."""
    global PHOTONS
    old = PHOTONS
    if n is not None:
        PHOTONS = int(n)
    try:
        yield
    finally:
        PHOTONS = old


def cache_dir() -> pathlib.Path:
    """Where tables are kept: ``$LIDAR_MITSUBA_CACHE/snow_kernel`` (default
    ``~/.cache/lidar_mitsuba/snow_kernel``)."""
    root = os.environ.get("LIDAR_MITSUBA_CACHE") or os.path.join(
        os.path.expanduser("~"), ".cache", "lidar_mitsuba")
    return pathlib.Path(root) / "snow_kernel"


def key(vol, *, photons: int | None = None, seed: int = 0) -> str:
    """The cache key of ``vol``'s table: a hash of the walk's inputs."""
    doc = {"version": VERSION, "walk": vol.walk_inputs(),
           "photons": int(PHOTONS if photons is None else photons),
           "seed": int(seed), "nodes": N_NODES, "quantiles": N_QUANTILES}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:24]


def _tilted_plane(vol, theta_deg: float):
    """A 100 m plane through the origin tilted by ``theta_deg`` about the y axis, bounding
    the snowpack ``vol``: a vertical ray at (0, 0) enters it at the origin at that incidence
    (the walk runs in the entry facet's plane: its extent only has to hold the entry)."""
    from ...trace import scene as scn
    t = math.radians(theta_deg)
    corners = np.array([[-50.0, -50.0], [50.0, -50.0], [-50.0, 50.0], [50.0, 50.0]])
    # rotate (x, 0, 0) -> (x cos t, 0, -x sin t): the normal (0, 0, 1) -> (sin t, 0, cos t)
    v = np.column_stack([corners[:, 0] * math.cos(t), corners[:, 1],
                         -corners[:, 0] * math.sin(t)])
    return scn.scene_from_mesh(v, np.array([[0, 1, 3], [0, 3, 2]]), bsdf=vol), \
        np.array([math.sin(t), 0.0, math.cos(t)])


def build_node(vol, theta_deg: float, *, photons: int, seed: int) -> dict:
    """The walk at one incidence angle: ``weight`` (the mean return weight per incident
    photon) and its standard error ``weight_se``; ``extra_path_m`` (N_QUANTILES,) the
    quantiles of the weighted extra path [m], its weighted ``mean_path_m`` and that mean's
    standard error ``mean_path_se_m`` (from the weighted returns' effective count); and the
    returned light's sideways spread from the entry point along the facet (weighted
    ``lateral_rms_m`` and 99th percentile ``lateral_p99_m``) [m]."""
    from ...trace.variant import ensure_renderer
    mi = ensure_renderer()
    scene, normal = _tilted_plane(vol, theta_deg)
    params = {**vol.integrator_params(), "pulse_sigma_ns": 0.0, "footprint_sigma_m": 0.0,
              "altitude_m": ALTITUDE_M, "fov_radius_m": 1e5}
    integ = mi.load_dict(params)
    per_shot = 1024
    n_shots = max(1, photons // per_shot)
    r = integ.trace(scene, shot_x_m=np.zeros(n_shots), shot_y_m=np.zeros(n_shots),
                    paths_per_shot=per_shot, seed=seed)
    del scene, integ
    n = n_shots * per_shot
    w = np.asarray(r.weight, np.float64)
    L = np.asarray(r.time_ns, np.float64) * C_M_PER_NS - 2.0 * ALTITUDE_M
    q = np.column_stack([r.x_m, r.y_m, r.z_m]).astype(np.float64)
    lateral = np.linalg.norm(q - np.outer(q @ normal, normal), axis=1)
    total = float(w.sum())
    if total <= 0:
        return {"weight": 0.0, "weight_se": 0.0, "extra_path_m": np.zeros(N_QUANTILES),
                "mean_path_m": 0.0,
                "mean_path_se_m": 0.0, "lateral_rms_m": 0.0, "lateral_p99_m": 0.0}
    mean = float(np.sum(w * L) / total)
    n_eff = total ** 2 / float(np.sum(w * w))
    sd = math.sqrt(float(np.sum(w * (L - mean) ** 2) / total))
    w_mean = total / n            # per incident photon: the records' weights, zeros elsewhere
    w_sd = math.sqrt(max(float(np.sum(w * w)) / n - w_mean ** 2, 0.0))
    return {"weight": w_mean, "weight_se": w_sd / math.sqrt(n),
            "extra_path_m": weighted_quantiles(L, w, N_QUANTILES),
            "mean_path_m": mean, "mean_path_se_m": sd / math.sqrt(n_eff),
            "lateral_rms_m": math.sqrt(float(np.sum(w * lateral ** 2) / total)),
            "lateral_p99_m": float(weighted_quantile_at(lateral, w, [0.99])[0])}


def weighted_quantile_at(x: np.ndarray, w: np.ndarray, u) -> np.ndarray:
    """The quantiles of ``x`` weighted by ``w`` at levels ``u`` in [0, 1] (the weighted
    empirical distribution with each sample's mass centred on it, linear in between; level 0
    and 1 are the sample's minimum and maximum)."""
    order = np.argsort(x, kind="stable")
    xs, ws = x[order], w[order]
    cum = np.cumsum(ws)
    mid = (cum - 0.5 * ws) / cum[-1]
    u = np.asarray(u, np.float64)
    out = np.interp(u, mid, xs)
    return np.where(u <= 0, xs[0], np.where(u >= 1, xs[-1], out))


def weighted_quantiles(x: np.ndarray, w: np.ndarray, n_levels: int) -> np.ndarray:
    """The quantiles of ``x`` weighted by ``w`` at the table's levels
    :func:`~lidar_mitsuba_plugins.kernel_table.quantile_levels` (``n_levels``)."""
    return weighted_quantile_at(x, w, kernel_table.quantile_levels(n_levels))


def build(vol, *, photons: int | None = None, seed: int = 0, progress: bool = True) -> dict:
    """The table of ``vol`` (every node; :func:`build_node`): arrays ``weight`` (J,),
    ``extra_path_m`` (J, M), ``mean_path_m``, ``mean_path_se_m``, ``lateral_rms_m``,
    ``lateral_p99_m`` (J,), and ``photons`` (J,), ``seconds``."""
    photons = PHOTONS if photons is None else int(photons)
    angles = kernel_table.node_angles_deg(N_NODES)
    bar = None
    if progress:
        from tqdm.auto import tqdm
        bar = tqdm(total=N_NODES, desc="tabulating the snow's subsurface kernel (once per "
                   "snowpack, cached)", unit="angle", delay=1.0, leave=False)
    rows, counts = [], []
    t0 = time.perf_counter()
    try:
        for j, theta in enumerate(angles):
            n = photons if theta <= STEEP_DEG else max(1024, photons // 4)
            rows.append(build_node(vol, float(theta), photons=n, seed=seed * 7919 + j))
            counts.append(n)
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    out = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    out["photons"] = np.array(counts)
    out["seconds"] = np.array(time.perf_counter() - t0)
    return out


def table(vol, *, photons: int | None = None, seed: int = 0, progress: bool = True
          ) -> tuple[pathlib.Path, dict]:
    """``(path, table)`` of ``vol``'s kernel: read from the cache, or built
    (:func:`build`, ``photons`` per node, default :data:`PHOTONS`) and written there. A
    table that cannot be written (a read-only home) is kept in a temporary folder."""
    photons = PHOTONS if photons is None else int(photons)
    k = key(vol, photons=photons, seed=seed)
    path = cache_dir() / f"{k}.npz"
    with _building(path):           # processes sharing the cache build each table once
        return _read_or_build(vol, path, k, photons=photons, seed=seed, progress=progress)


@contextlib.contextmanager
def _building(path: pathlib.Path):
    """An exclusive lock on ``path``'s ``.lock`` file while a table is read or built: a second
    process (a campaign's or a test run's workers) waits for the first one's table instead of
    walking the same photons again. Without a writable cache folder, no lock."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path.with_name(f".{path.name}.lock"), os.O_CREAT | os.O_RDWR, 0o644)
    except OSError:
        yield
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)                # closing releases the lock


def _read_or_build(vol, path: pathlib.Path, k: str, *, photons: int, seed: int,
                   progress: bool) -> tuple[pathlib.Path, dict]:
    if path.is_file():
        try:
            return path, kernel_table.load(path)
        except (OSError, ValueError, KeyError):
            pass                       # a partial or foreign file: built again below
    t = build(vol, photons=photons, seed=seed, progress=progress)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError:
        import tempfile
        path = pathlib.Path(tempfile.gettempdir()) / f"lidar_mitsuba_snow_kernel_{k}.npz"
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
    kernel_table.save(tmp, **t)
    os.replace(tmp, path)
    return path, kernel_table.load(path)       # as stored (float32): what a later run reads


def summary(t: dict) -> dict:
    """A table's numbers for a run's config: its photons, build time, nadir weight and mean
    extra path, and the largest sideways spread of the returned light (99th percentile) [m]."""
    return {"nodes": int(np.size(t["weight"])), "photons_nadir": int(np.ravel(t["photons"])[0]),
            "build_s": float(t["seconds"]), "weight_nadir": float(t["weight"][0]),
            "weight_se_nadir": float(t["weight_se"][0]),
            "mean_extra_path_nadir_m": float(t["mean_path_m"][0]),
            "mean_extra_path_se_nadir_m": float(t["mean_path_se_m"][0]),
            "lateral_rms_max_m": float(np.max(t["lateral_rms_m"])),
            "lateral_p99_max_m": float(np.max(t["lateral_p99_m"]))}


def plane_warning(t: dict, *, facet_m: float | None) -> str | None:
    """A warning where the plane the walk (and so the kernel) assumes under each facet is
    doubtful: the returned light's sideways spread (the table's largest weighted rms) above a
    tenth of the facets' size ``facet_m`` [m] (the mesh spacing; ``None``: unknown, no
    warning)."""
    spread = float(np.max(t["lateral_rms_m"]))
    if facet_m is None or not np.isfinite(facet_m) or spread <= 0.1 * facet_m:
        return None
    return (f"the light returned from the snow spreads {100 * spread:.2g} cm sideways "
            f"(rms) on {facet_m:g} m facets: the walk and the kernel both treat "
            f"the facet a photon enters as a plane, which holds where the spread is well "
            f"under the facets (a tenth); a finer mesh or a smoother surface, or expect "
            f"errors of the order of the spread's share of a facet")
