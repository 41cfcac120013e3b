"""Memory and time against track length over a DEM (issue 13): one strong beam along a
meridian of a long synthetic ice-sheet DEM, streamed into ATL03 and ATL06 files
(:func:`lidar_mitsuba.granule.stream_granule`), each length in a fresh process so its peak
RSS is its own.

Reported per length: shots, sections, corridor tiles, wall time, shots/s, the process's
peak RSS and its RSS before the run (the process started as ``simulate --dem`` starts:
imports, the writer process forked, numba's kernels loaded, the renderer set up; the DEM
opened), ``working_mb`` = peak - before,
the size of the files written, and ``kernels``, the distinct Dr.Jit kernels the run
launched (up to 100 km): it must not grow with the tiles (each new kernel is an LLVM or CUDA
compile, ~0.2 s, that the disk cache hides only on a repeat of the same terrain).

The six-beam granule row runs the granule twice in its process, as a campaign's long-lived
worker does: ``seconds`` is the second (warm: renderer, kernels, writer process and DEM
already loaded), ``of_cast`` its ratio to casting the same rays alone (:func:`cast_time`:
the granule's ray count cast into its own corridor tiles in launches of >= 1 M lanes, with
``cast_cv`` the spread of its passes), ``end_to_end_s`` the first granule's end counted from
the interpreter's start (what a cold ``lidar-mitsuba simulate --dem`` pays: the process starts
as that command's does, through :func:`lidar_mitsuba.startup.granule_process`, with the
collector set as the command launcher sets it, :func:`lidar_mitsuba.startup.own_process`) and
``end_to_end_over_warm`` the ratio of the two.
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import resource
import subprocess
import sys
import time

import numpy as np

#: the long test DEM: 10 km wide along the -45 meridian (a straight line x = 0 in EPSG:3413)
DEM_WIDTH_M = 10_000.0
DEM_POSTING_M = 100.0
START_LAT = 65.0
KERNELS_UP_TO_KM = 100.0


def make_dem(path: pathlib.Path, length_km: float) -> pathlib.Path:
    """A DEM long enough for a ``length_km`` track north from 65 N along -45 E."""
    from ..ground import dem
    from pyproj import Geod, Transformer
    lon1, lat1, _ = Geod(ellps="WGS84").fwd(-45.0, START_LAT, 0.0, length_km * 1e3)
    to = Transformer.from_crs("EPSG:4326", "EPSG:3413", always_xy=True)
    _, y0 = to.transform(-45.0, START_LAT)
    _, y1 = to.transform(-45.0, lat1)
    pad = 5_000.0
    length = abs(y1 - y0) + 2 * pad
    mid_lon, mid_lat = Transformer.from_crs("EPSG:3413", "EPSG:4326", always_xy=True).transform(
        0.0, 0.5 * (y0 + y1))
    return dem.synthetic_ice_sheet(path, lat_deg=mid_lat, lon_deg=mid_lon, width_m=DEM_WIDTH_M,
                                   length_m=length, posting_m=DEM_POSTING_M, hole=False)


def ice_sheet_track() -> object:
    """The track north along the -45 meridian from :data:`START_LAT` (a
    :class:`~lidar_mitsuba.geotrack.GeoTrack`): :func:`make_dem`'s DEM lies under it."""
    from .. import geotrack
    return geotrack.GeoTrack(start_lat_deg=START_LAT, start_lon_deg=-45.0, azimuth_deg=0.0)


def ice_sheet(folder: pathlib.Path, length_km: float) -> tuple:
    """``(surface, track)``: the DEM of :func:`make_dem` for ``length_km``, written to
    ``folder``/dem.tif, as a :class:`~lidar_mitsuba.ground.dem.DEMSurface`, and
    :func:`ice_sheet_track` (the cloud and forest rows' ground)."""
    from ..ground import dem
    surface = dem.DEMSurface(dem.DEM.open(make_dem(pathlib.Path(folder) / "dem.tif",
                                                   length_km)))
    return surface, ice_sheet_track()


def granule_rays(summaries) -> int:
    """The rays a streamed granule cast (its beams' summaries): shots x paths per shot x
    bounces, summed over its beams (what :func:`cast_time` casts)."""
    return int(sum(o.shots * o.config["paths_per_shot"] * o.config["max_depth"]
                   for o in summaries))


def _peak_rss_mb() -> float:
    """This process's peak resident memory [MB]: Linux's ``VmHWM``, which starts afresh at
    ``exec``; ``ru_maxrss`` keeps the peak of the process that forked it (the bench, ~1.5 GB
    by the time it gets here), so it is only the fallback."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


#: the cast yardstick (:func:`cast_time`): the most of the granule's corridor tiles it casts
#: into, the fewest lanes a launch (ESTIMATE, from one trial: passes of 1.3 M-lane launches
#: moved by 3-17 % (median 6 %) under a load of 13-17, where the 65 k-lane launches of the
#: yardstick before it moved by 37-53 % between calls), and its passes after one warm-up (each
#: pass casts the granule's rays once; docs/guide/campaigns.md has the measurements)
CAST_TILES = 8
CAST_LANES = 1_000_000
CAST_PASSES = 5


def cast_time(surface, track, *, rays: int, paths_per_shot: int, shots: int,
              beams: str = "all", passes: int = CAST_PASSES, seed: int = 0) -> dict:
    """The time [s] to cast a granule's own rays alone: the yardstick a granule's pipeline
    is held against (``of_cast``).

    What is cast: ``rays`` rays (the granule's shots x paths per shot x bounces; at
    ``max_depth=1`` every one a primary ray, as the integrator's ``_first_surface`` casts
    them), as vertical rays from above the scene to their first hit (``ray_intersect``,
    the hit distance evaluated: no sampling, weights or detection), into ``tiles`` of the
    granule's own corridor tiles (``rays //`` :data:`CAST_LANES`, at least 1 and at most
    :data:`CAST_TILES`; :meth:`granule._Context.plan` of ``tiles`` stretches of
    :data:`~lidar_mitsuba.ground.dem.TILE_SHOTS` shots, evenly spread along the
    ``shots``-shot track and taken from each of the granule's ``beams`` (as
    :func:`~lidar_mitsuba.geotrack.select_beams` names them) in turn: the same DEM, the
    same corridor meshed ``5 sigma + 1 m`` about the footprints, built as the granule
    builds them),
    ``rays / tiles`` lanes a launch (~1.3 M for a six-beam 100 km granule, where the
    granule's own launches are a tile's 65 k: large launches, so the launch overheads and
    the other agents' load move the yardstick less), the footprints of the tile's shots
    repeated with Gaussian offsets of the footprint's sigma. The scene builds are not timed
    (the granule's cost, as the tiles' layout is); Dr.Jit's whole pool casts (the machine's
    every core: a bound).

    One tile's scene is alive at a time (as in the granule); each is cast ``passes + 1``
    times and the first dropped (its kernel from the cache, first touches). A pass is the
    ``k``-th launch of every tile: its seconds summed over the tiles, each launch timed
    between two ``dr.sync_thread()``. Returns ``cast_s`` (the median pass [s]),
    ``cast_rays_per_s``, ``cast_cv`` (the passes' coefficient of variation: standard
    deviation over mean), ``cast_cpu_s`` (the median pass's CPU seconds, every thread of the
    process: what other agents' load moves least), ``cast_tiles`` and ``cast_lanes`` (per
    launch)."""
    import drjit as dr
    from .. import geotrack, granule
    from ..ground.dem import TILE_SHOTS
    from ..trace.scene import scene_bounds
    from ..trace.variant import ensure_renderer
    mi = ensure_renderer()
    ctx = granule._Context(surface, track, None)
    beams = geotrack.select_beams(beams, 0)
    tiles = max(1, min(CAST_TILES, int(rays) // CAST_LANES))
    lanes = max(1, int(rays) // tiles)
    tile_shots = min(TILE_SHOTS, int(shots))
    rng = np.random.default_rng(seed)
    seconds, cpu_s = np.zeros((tiles, int(passes))), np.zeros((tiles, int(passes)))
    for k in range(tiles):
        first = int((k + 0.5) / tiles * (shots - tile_shots))
        p = ctx.plan(beams[k % len(beams)], tile_shots, first=first, seed=seed, max_depth=1,
                     paths_per_shot=paths_per_shot, progress=False)
        pick = np.arange(lanes) % p.x_local_m.size
        sigma = p.instrument.footprint_sigma_m
        x = mi.Float(p.x_local_m[pick] + rng.normal(0.0, sigma, lanes))
        y = mi.Float(p.y_local_m[pick] + rng.normal(0.0, sigma, lanes))
        z = dr.full(mi.Float, float(scene_bounds(p.scene)[1][2]) + 1.0, lanes)
        dr.eval(x, y, z)
        for j in range(int(passes) + 1):
            dr.sync_thread()
            t0, c0 = time.perf_counter(), time.process_time()
            si = p.scene.ray_intersect(mi.Ray3f(mi.Point3f(x, y, z),
                                                mi.Vector3f(0.0, 0.0, -1.0)))
            dr.eval(si.t)
            dr.sync_thread()
            if j:
                seconds[k, j - 1] = time.perf_counter() - t0
                cpu_s[k, j - 1] = time.process_time() - c0
            del si
        del p, x, y, z                              # one tile's scene alive at a time
    scale = int(rays) / (lanes * tiles)                     # the granule's rays, to the ray
    per_pass, cpu_pass = seconds.sum(axis=0) * scale, cpu_s.sum(axis=0) * scale
    cast_s = float(np.median(per_pass))
    return {"cast_s": cast_s, "cast_rays_per_s": int(rays) / cast_s,
            "cast_cv": float(per_pass.std() / per_pass.mean()),
            "cast_cpu_s": float(np.median(cpu_pass)), "cast_tiles": int(tiles),
            "cast_lanes": lanes}


def _process_age_s() -> float:
    """Seconds since this process started (Linux's ``/proc``: the interpreter's start
    included), or NaN where that is not known."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = float(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            uptime_s = float(f.read().split()[0])
        return uptime_s - start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return float("nan")


def _writer_peak_rss_mb() -> float | None:
    """The writer process's peak resident memory [MB] (``VmHWM``), if one is running."""
    from .. import granule_writer
    w = granule_writer._WRITER[0]
    try:
        with open(f"/proc/{w.proc.pid}/status") as f:
            return next(float(ln.split()[1]) / 1024.0 for ln in f if ln.startswith("VmHWM:"))
    except (AttributeError, OSError, StopIteration):
        return None


def _cpu_s() -> float:
    """CPU seconds [s] this process (every thread, ended ones too) and its writer process
    have used since they started: what other agents' load on the machine moves far less
    than wall time."""
    t = os.times()
    from .. import granule_writer
    w = granule_writer._WRITER[0]
    try:
        with open(f"/proc/{w.proc.pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        writer = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (AttributeError, OSError, ValueError, IndexError):
        writer = 0.0
    return t.user + t.system + writer


def measure(dem_path: str, length_km: float, beams: str = "gt2l") -> dict:
    """Run one length of ``beams`` in this process (call in a fresh one); with every beam,
    the granule twice, as a long-lived worker runs granule after granule: the first (cold:
    ``end_to_end_s`` counts from the interpreter's start, imports and the renderer's set-up
    included) and the second (``seconds``: warm), against the time its rays alone take to
    cast (:func:`cast_time`); the same in CPU seconds of both processes (``cpu_s``,
    ``end_to_end_cpu_s``: from both processes' start)."""
    from ..startup import granule_process
    granule_process()                  # as simulate --dem starts (its imports first)
    from .. import granule
    from ..ground import dem
    surf = dem.DEMSurface(dem.DEM.open(dem_path))
    shots = int(round(length_km * 1e3 / 0.7))
    before = _peak_rss_mb()
    track = ice_sheet_track()
    first = None
    if beams == "all":                 # a worker's first granule, then the one reported
        first = _granule(surf, track, shots, beams, count_kernels=False)
        first.update(end_to_end_s=_process_age_s(), peak_rss_first_mb=_peak_rss_mb(),
                     end_to_end_cpu_s=_cpu_s())
    res = _granule(surf, track, shots, beams,
                   count_kernels=length_km <= KERNELS_UP_TO_KM and first is None)
    seconds, out = res["seconds"], res["out"]
    peak = _peak_rss_mb()
    sections = len(granule.section_bounds(shots, spacing_m=0.7,
                                          section_shots=granule.SECTION_SHOTS))
    row = {}
    if first is not None:        # the same rays, cast alone: the pipeline's cost over them
        rays = granule_rays(out)
        cast = cast_time(surf, track, rays=rays, shots=shots,
                         paths_per_shot=out[0].config["paths_per_shot"])
        row = {"beams": len(out), "rays": rays, **cast,
               "of_cast": seconds / cast["cast_s"],
               "first_s": first["seconds"], "end_to_end_s": first["end_to_end_s"],
               "end_to_end_over_warm": first["end_to_end_s"] / seconds,
               "cpu_s": res["cpu_s"], "end_to_end_cpu_s": first["end_to_end_cpu_s"],
               "end_to_end_over_warm_cpu": first["end_to_end_cpu_s"] / res["cpu_s"],
               "peak_rss_first_mb": first["peak_rss_first_mb"],
               "writer_peak_rss_mb": _writer_peak_rss_mb()}
    return {**row, "length_km": float(length_km), "shots": shots, "seconds": seconds,
            "shots_per_s": shots / seconds, "peak_rss_mb": peak, "rss_before_mb": before,
            "working_mb": peak - before, "files_mb": res["files_mb"], "sections": sections,
            "tiles": -(-shots // surf.tile_shots), "kernels": res["kernels"],
            "photons": out[0].photons, "bias_m": out[0].bias_m, "std_m": out[0].std_m}


def _granule(surf, track, shots: int, beams: str, *, count_kernels: bool) -> dict:
    """One streamed granule into a temporary folder: its wall time [s] (Dr.Jit's queue
    synced), CPU [s] (both processes, :func:`_cpu_s`), summaries, files' size [MB] and
    distinct kernels (when counted)."""
    import tempfile
    import drjit as dr
    from .. import granule
    with tempfile.TemporaryDirectory() as tmp:
        a3, a6 = pathlib.Path(tmp) / "ATL03.h5", pathlib.Path(tmp) / "ATL06.h5"
        t0, cpu0 = time.perf_counter(), _cpu_s()
        # the history keeps every launch's code (~14 KB each: ~50 MB over 1000 km), which
        # the memory figures would count: kernels are counted up to KERNELS_UP_TO_KM only
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory, count_kernels):
            out = granule.stream_granule(
                surface=surf, track=track, shots=shots, beams=beams, max_depth=1,
                progress=False, paths_per_shot="auto", atl03_path=a3, atl06_path=a6)
            dr.sync_thread()
            kernels = (len({k["hash"] for k in dr.kernel_history([dr.KernelType.JIT])})
                       if count_kernels else None)
        seconds, cpu_s = time.perf_counter() - t0, _cpu_s() - cpu0
        files_mb = (a3.stat().st_size + a6.stat().st_size) / 2 ** 20
    return {"seconds": seconds, "cpu_s": cpu_s, "out": out, "files_mb": files_mb,
            "kernels": kernels}


def run(*, out: pathlib.Path, quick: bool) -> list[dict]:
    """Every length of one strong beam in its own process, then a six-beam granule (4 km
    quick, else 100 km: a campaign's unit) against its ray casting; the DEM is made once for
    the longest."""
    lengths = (1.0, 4.0) if quick else (10.0, 100.0, 1000.0)
    runs = [(km, "gt2l") for km in lengths] + [(4.0 if quick else 100.0, "all")]
    out.mkdir(parents=True, exist_ok=True)
    path = make_dem(out / "long_dem.tif", max(lengths))
    rows = []
    for km, beams in runs:
        p = subprocess.run([sys.executable, "-m", "lidar_mitsuba.studies.track_length",
                            str(path), str(km), beams], check=True, capture_output=True,
                           text=True)
        rows.append(json.loads(p.stdout.strip().splitlines()[-1]))
    path.unlink()
    return rows


def chart(rows: list[dict], path: pathlib.Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = [r for r in rows if "beams" not in r]          # the one-beam lengths
    km = [r["length_km"] for r in rows]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8), dpi=110)
    a.plot(km, [r["peak_rss_mb"] for r in rows], "o-", label="peak RSS")
    a.plot(km, [r["rss_before_mb"] for r in rows], ":", color="0.5", label="before the run")
    a.set_xscale("log")
    a.set_xlabel("track length [km]")
    a.set_ylabel("memory [MB]")
    a.set_title("memory vs track length (one strong beam, streamed)")
    a.legend(fontsize=8)
    a.grid(alpha=0.3)
    b.plot(km, [r["shots_per_s"] for r in rows], "o-")
    b.set_xscale("log")
    b.set_xlabel("track length [km]")
    b.set_ylabel("shots / s (whole run)")
    b.set_title("throughput vs track length")
    b.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("dem")
    ap.add_argument("km", type=float)
    ap.add_argument("beams", nargs="?", default="gt2l")
    a = ap.parse_args()
    from ..startup import own_process
    own_process()                      # the collector as the command launcher sets it
    print(json.dumps(measure(a.dem, a.km, a.beams)))
