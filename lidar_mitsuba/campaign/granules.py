"""One campaign task on a worker: a granule streamed to its ATL03 and ATL06 files
(:func:`lidar_mitsuba.granule.stream_granule`), its ATL06 segments read back with their truth
and error, and its row of statistics (:func:`run_task`)."""
from __future__ import annotations

import contextlib
import json
import math
import os
import pathlib
import socket
import time
import warnings
from datetime import datetime, timezone

import numpy as np

from ..sweep.task import _one_line, _set_threads, _versions
from .land import LAND_COLUMNS, forest_over, land_statistics

#: the segment table's columns (:func:`read_segments` and the task's properties)
SEGMENT_COLUMNS: dict[str, str] = {
    "task_index": "the granule's task (the table's order: task, beam, segment)",
    "granule": "[yyyymmddhhmmss]_[ttttccss]_[vvv]_[rr] of its ATL03/ATL06 files",
    "rgt": "reference ground track (0: a spec track without one)",
    "cycle": "cycle", "region": "granule region (1-14)",
    "beam": "gt1l .. gt3r", "strength": "strong or weak",
    "segment_id": "ATL06 segment_id (the segment spans 20 m segments id and id + 1)",
    "delta_time": "time of the segment centre [s since 2018-01-01]",
    "latitude": "segment centre [deg]", "longitude": "segment centre [deg]",
    "x_atc": "along-track distance of the segment centre from the first shot [m]",
    "h_li": "ATL06 land-ice height [m] (NaN: not fitted)",
    "h_li_sigma": "its formal error [m]",
    "h_truth": "truth [m]: the least-squares line of the shots' reference elevation (the "
               "Gaussian-footprint mean of the surface) at the segment centre (ATL06 dem/h_ref_m)",
    "error": "h_li - h_truth [m]",
    "atl06_quality_summary": "0: good, 1: flagged",
    "n_fit_photons": "photons in the final fit",
    "grain_um": "snow grain radius simulated at the segment: its beam's level in its "
                "section [um] (NaN: no snow)",
    "grain_um_raster": "the grain-size raster at the segment centre [um] (NaN: no raster)",
    "density_kg_m3": "snow density simulated at the segment: its beam's level in its section "
                     "with a raster [kg/m^3] (NaN: snow_from_grains' default, or no snow)",
    "density_kg_m3_raster": "the density raster at the segment centre",
    "roughness_relief_m": "roughness relief simulated at the segment: its beam's level in its "
                          "section with a raster [m] (NaN: none)",
    "roughness_relief_m_raster": "the roughness raster at the segment centre [m]",
}
#: task rows' columns
ROW_COLUMNS: dict[str, str] = {
    "task_id": "16 hex digits identifying the granule (resume key)",
    "task_index": "position in the spec's expansion", "granule": "file names' common part",
    "rgt": "reference ground track (0: a spec track without one)", "cycle": "cycle",
    "region": "granule region (1-14)", "ascending": "the pass: northward at the first shot",
    "dem": "DEM file", "shots": "shots per beam", "seed": "photon seed",
    "grain_um": "the granule's snow grain radius level, its median over every beam [um] "
                "(None: no snow; each beam's section has its own: the segments' grain_um)",
    "density_kg_m3": "the granule's snow density level, its median over every beam [kg/m^3] "
                     "(None: snow_from_grains' default; with a raster each beam's section may "
                     "have its own: the segments' density_kg_m3)",
    "roughness_relief_m": "the granule's roughness relief level, its median over every beam "
                          "[m] (None or 0: none; likewise per section: the segments')",
    "medians_json": "raster medians along the granule before binning (JSON)",
    "status": "'ok' or 'failed'", "error": "one-line error of a failed task",
    "photons": "signal photons, all beams", "n_segments": "ATL06 segments, all beams",
    "n_good": "unflagged segments with a truth",
    "bias_m": "mean error of the good segments [m]",
    "bias_se_m": "its standard error from every other good segment (independent) [m]",
    "std_m": "standard deviation of the good segments' error [m] (precision)",
    "atl03": "ATL03 file, relative to granules/ (ATL03/ATL03_...h5)",
    "atl06": "ATL06 file, relative to granules/ (ATL06/ATL06_...h5)",
    "task_s": "wall time on the worker [s]", "started_at": "UTC (ISO 8601)",
    "finished_at": "UTC (ISO 8601)", "worker": "host:pid",
    "lidar_mitsuba_version": "versions of the worker's packages", "mitsuba_version": "",
    "drjit_version": "", "track_json": "the track (GeoTrack fields, JSON)",
    **LAND_COLUMNS,
}
#: the properties a raster resolves per beam and granule section, and the task's field of
#: their levels (``{beam: [level per section]}``, :class:`.tasks.Task`)
SECTIONED = {"grain_um": "grain_sections", "density_kg_m3": "density_sections",
             "roughness_relief_m": "roughness_sections"}
RUN_DEPENDENT = ("task_s", "started_at", "finished_at", "worker")
_FLOAT32_FILL = float(np.finfo(np.float32).max)


def _nan(a) -> np.ndarray:
    a = np.asarray(a, np.float64)
    return np.where(a >= _FLOAT32_FILL, np.nan, a)


def read_segments(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every beam's ATL06 segments of one of our ATL06 files (beams in file order): columns
    ``beam``, ``strength``, ``segment_id``, ``delta_time``, ``latitude``, ``longitude``,
    ``x_atc``, ``h_li``, ``h_li_sigma``, ``h_truth``, ``error``, ``atl06_quality_summary``,
    ``n_fit_photons`` (each (n,); fill values as NaN)."""
    import h5py
    cols: dict[str, list] = {k: [] for k in (
        "beam", "strength", "segment_id", "delta_time", "latitude", "longitude", "x_atc",
        "h_li", "h_li_sigma", "h_truth", "atl06_quality_summary", "n_fit_photons")}
    with h5py.File(path, "r") as f:
        for name in sorted(k for k in f if k.startswith("gt")):
            li = f[name]["land_ice_segments"]
            n = li["h_li"].shape[0]
            cols["beam"].append(np.full(n, name, object))
            cols["strength"].append(np.full(n, str(f[name].attrs["atlas_beam_type"]), object))
            cols["segment_id"].append(li["segment_id"][()].astype(np.int64))
            for key, src in (("delta_time", "delta_time"), ("latitude", "latitude"),
                             ("longitude", "longitude")):
                cols[key].append(np.asarray(li[src][()], np.float64))
            cols["x_atc"].append(_nan(li["ground_track/x_atc"][()]))
            cols["h_li"].append(_nan(li["h_li"][()]))
            cols["h_li_sigma"].append(_nan(li["h_li_sigma"][()]))
            cols["h_truth"].append(_nan(li["dem/h_ref_m"][()]))
            cols["atl06_quality_summary"].append(
                li["atl06_quality_summary"][()].astype(np.int64))
            cols["n_fit_photons"].append(li["fit_statistics/n_fit_photons"][()].astype(np.int64))
    out = {k: (np.concatenate(v) if v else np.zeros(0)) for k, v in cols.items()}
    out["error"] = out["h_li"] - out["h_truth"]
    return out


def statistics(seg: dict) -> dict:
    """A granule's bias and precision over its good segments (flag 0, finite error)."""
    e = seg["error"]
    good = (seg["atl06_quality_summary"] == 0) & np.isfinite(e)
    d = e[good]
    alt = e[good & (seg["segment_id"] % 2 == 0)]
    return {"n_segments": int(e.size), "n_good": int(d.size),
            "bias_m": float(d.mean()) if d.size else math.nan,
            "std_m": float(d.std(ddof=1)) if d.size > 1 else math.nan,
            "bias_se_m": float(alt.std(ddof=1) / math.sqrt(alt.size)) if alt.size > 1
            else math.nan}


@contextlib.contextmanager
def _kernel_cache(root: str | None):
    """``$LIDAR_MITSUBA_CACHE`` set to ``root`` (where the parent built the snow kernel
    tables) for the block."""
    old = os.environ.get("LIDAR_MITSUBA_CACHE")
    if root is None or root == old:
        yield
        return
    os.environ["LIDAR_MITSUBA_CACHE"] = root
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("LIDAR_MITSUBA_CACHE", None)
        else:
            os.environ["LIDAR_MITSUBA_CACHE"] = old


def snow_volume(grain_um, density_kg_m3):
    """The snow of a granule (``None`` without grains)."""
    if grain_um is None or not math.isfinite(grain_um):
        return None
    from ..ground.snow import snow_from_grains
    kw = {} if density_kg_m3 is None else {"density_kg_m3": float(density_kg_m3)}
    return snow_from_grains(grain_radius_um=float(grain_um), **kw)


def _roughness_tile(p: dict, dem, relief):
    """The granule's roughness heightfield of ``relief`` [m] (None or 0: none), from the
    task's roughness seed: each relief the same tile, scaled."""
    from ..ground.dem import roughness
    if not relief:
        return None
    return roughness(p=p["roughness_p"], relief_m=float(relief), posting_m=dem.posting_m,
                     seed=p["roughness_seed"])


def _surface(p: dict) -> tuple[object, dict]:
    """The granule's :class:`~lidar_mitsuba.ground.dem.DEMSurface` and ``stream_granule``'s
    roughness option: none (the granule's roughness on the surface), or with
    ``roughness_sections`` the DEM alone and ``roughness(beam, k)`` giving each beam's
    section its level's heightfield (one per level)."""
    from ..ground.dem import DEM, DEMSurface
    dem = DEM.open(p["dem"])
    levels = p.get("roughness_sections")
    if not levels:
        surface = DEMSurface(dem, roughness=_roughness_tile(p, dem, p.get("roughness_relief_m")))
        if p.get("forest"):                  # the spec's stand over it
            surface = forest_over(surface, p["forest"])
        return surface, {}
    tiles = {r: _roughness_tile(p, dem, r) for row in levels.values() for r in row}
    return DEMSurface(dem), {"roughness": lambda beam, k: tiles[levels[beam.name][k]]}


def simulate(p: dict) -> tuple[dict, int, pathlib.Path, pathlib.Path]:
    """Stream the granule of task ``p`` to ``out/granules/ATL03/ATL03_*.h5`` and
    ``out/granules/ATL06/ATL06_*.h5`` (and with ``p["atl08"]`` our ATL08 to
    ``out/granules/ATL08/ATL08_*.h5``; a folder per product, as ``icepyx.Read(folder)`` reads
    one product's granules; each written under a temporary name beginning with a dot, which
    such a reader's glob skips, then renamed) and read its segments back: ``(segments, signal
    photons, atl03, atl06)``."""
    from ..geotrack import GeoTrack
    from ..granule import stream_granule
    folder = pathlib.Path(p["out"]) / "granules"
    final = [folder / f"ATL0{k}" / f"ATL0{k}_{p['granule']}.h5"
             for k in ((3, 6, 8) if p.get("atl08") else (3, 6))]
    for f in final:
        f.parent.mkdir(exist_ok=True)
    tmp = [f.with_name(f".{f.name}.part.h5") for f in final]
    track = dict(p["track"])
    if track.get("polyline") is not None:
        track["polyline"] = tuple(map(tuple, track["polyline"]))
    surface, kw = _surface(p)
    kw.update(_snow(p), **_cloud(p))
    run = p["run"]
    try:
        summaries = stream_granule(
            surface=surface, track=GeoTrack(**track), shots=p["shots"],
            atl03_path=tmp[0], atl06_path=tmp[1], beams=p["beams"], sc_orient=p["sc_orient"],
            instrument_options=p["instrument_options"], instrument=p["instrument"],
            seed=p["seed"], paths_per_shot=run["paths_per_shot"], max_depth=run["max_depth"],
            progress=False, section_shots=run["section_shots"], variant=p.get("variant"),
            orbit_info={"cycle_number": p["cycle"], **({"rgt": p["rgt"]} if p["rgt"] else {})},
            atl08_path=tmp[2] if len(tmp) > 2 else None, **kw)
    except BaseException:
        for t in tmp:
            t.unlink(missing_ok=True)
        raise
    for t, f in zip(tmp, final):
        os.replace(t, f)
    return read_segments(final[1]), sum(s.photons for s in summaries), final[0], final[1]


def _granule_file(path: pathlib.Path) -> str:
    """A granule file's path relative to ``granules/``: ``ATL03/ATL03_...h5``."""
    return f"{path.parent.name}/{path.name}"


def _with_properties(seg: dict, p: dict) -> dict:
    """The segments with the task's columns and the rasters sampled at the segment centres
    (the task's window only)."""
    from .rasters import PropertyRaster
    n = seg["h_li"].size
    out = {"task_index": np.full(n, p["task_index"], np.int64),
           "granule": np.full(n, p["granule"], object)}
    for k in ("rgt", "cycle", "region"):
        out[k] = np.full(n, p[k], np.int64)
    out.update(seg)
    for k in ("grain_um", "density_kg_m3", "roughness_relief_m"):
        v = p.get(k)
        out[k] = np.full(n, math.nan if v is None else float(v))
        levels = p.get(SECTIONED[k])
        if levels and n:                   # each segment's: its beam's level in its section
            out[k] = _section_values(seg, p, levels)
        raster = p["rasters"].get(k)
        out[f"{k}_raster"] = (PropertyRaster(raster).at(seg["latitude"], seg["longitude"])
                              if raster and n else np.full(n, math.nan))
    return out


def _section_values(seg: dict, p: dict, levels: dict) -> np.ndarray:
    """(n,) a property's value each segment's photons were simulated with: its beam's level
    (``levels``: ``{beam: [level per section]}``) in the section holding the segment's
    centre (the task's ``section_bounds``, shots ``shot_spacing_m`` apart: those the granule
    streamed)."""
    firsts = [a for a, _ in p["section_bounds"]]
    shot = np.nan_to_num(seg["x_atc"] / p["shot_spacing_m"]).astype(np.int64)
    k = np.clip(np.searchsorted(firsts, shot, side="right") - 1, 0, len(firsts) - 1)
    return np.array([levels[b][j] for b, j in zip(seg["beam"], k)], np.float64)


def snow_pairs(grain_um, density_kg_m3, grain_sections=None,
               density_sections=None) -> dict[tuple[str, int], tuple]:
    """``{(beam, section): (grain level, density level)}`` of a task with per-section levels
    (the granule's value where a property has none), ``{}`` without: each distinct pair is one
    :class:`~lidar_mitsuba.ground.snow.SnowVolume` and one kernel table."""
    if grain_um is None or not (grain_sections or density_sections):
        return {}
    rows = grain_sections or density_sections
    return {(b, j): (grain_sections[b][j] if grain_sections else grain_um,
                     density_sections[b][j] if density_sections else density_kg_m3)
            for b, row in rows.items() for j in range(len(row))}


def _snow(p: dict) -> dict:
    """``stream_granule``'s snow options: one snow for the granule, or each beam's per
    section (``grain_sections``, ``density_sections``), one :class:`SnowVolume` per
    (grain, density) pair."""
    pairs = snow_pairs(p.get("grain_um"), p.get("density_kg_m3"), p.get("grain_sections"),
                       p.get("density_sections"))
    if pairs:
        volumes = {gd: snow_volume(*gd) for gd in set(pairs.values())}
        return {"snow": lambda beam, k: volumes[pairs[beam.name, k]],
                "snow_model": p["snow_model"]}
    snow = snow_volume(p.get("grain_um"), p.get("density_kg_m3"))
    return {} if snow is None else {"snow": snow, "snow_model": p["snow_model"]}


def granule_cloud(p: dict):
    """The granule's cloud (:class:`~lidar_mitsuba.atmosphere.cloud_layer.Cloud`, or None: clear)
    from the spec's ``[cloud]``: the one cloud, or a draw from its climatology seeded by the
    granule's photon seed (the same task, the same cloud)."""
    from ..atmosphere.cloud_layer import Cloud, CloudClimatology
    t = p.get("cloud")
    if not t:
        return None
    if "optical_depth" in t:
        make = Cloud.ice if t.get("phase") == "ice" else Cloud.water
        return make(t["optical_depth"], t.get("base_m", 1000.0), t.get("top_m", 1500.0))
    clim = CloudClimatology(**{("cloud_fraction" if k == "fraction" else k): v
                               for k, v in t.items()})
    return clim.draw(np.random.default_rng([int(p["seed"]), 0x434C4F]))


def _cloud(p: dict) -> dict:
    cloud = granule_cloud(p)
    return {} if cloud is None else {"cloud": cloud}


def run_task(p: dict) -> dict:
    """Run one task (:func:`lidar_mitsuba.campaign.tasks.payload`, plus ``threads``):
    ``{"row": ..., "segments": {column: (n,) array} or None}``. Never raises for a failing
    granule: its row says ``failed`` and why, and no files are left for it."""
    started, t0 = datetime.now(timezone.utc), time.perf_counter()
    values: dict = {}
    segments = None
    try:
        if p.get("invalid"):
            raise _Invalid(p["invalid"])
        _set_threads(p.get("threads"))
        with _kernel_cache(p.get("kernel_cache")), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            seg, photons, a3, a6 = simulate(p)
            segments = _with_properties(seg, p)
        values.update(statistics(seg), photons=int(photons), atl03=_granule_file(a3),
                      atl06=_granule_file(a6))
        if p.get("atl08"):                  # its land segments' numbers
            a8 = a6.parent.parent / "ATL08" / a6.name.replace("ATL06", "ATL08", 1)
            values.update(land_statistics(a8), atl08=_granule_file(a8))
    except Exception as e:                    # recorded, not raised: the campaign goes on
        values = {"status": "failed", "error": str(e) if isinstance(e, _Invalid)
                  else _one_line(e)}
    return {"row": row(p, **values, task_s=time.perf_counter() - t0,
                       started_at=started.isoformat(),
                       worker=f"{socket.gethostname()}:{os.getpid()}",
                       finished_at=datetime.now(timezone.utc).isoformat()),
            "segments": segments}


class _Invalid(Exception):
    """A task the spec's expansion found cannot run."""


def row(p: dict, **values) -> dict:
    """A task row with every column of :data:`ROW_COLUMNS`."""
    out = {k: p.get(k) for k in ("task_id", "task_index", "granule", "rgt", "cycle", "region",
                                 "ascending", "dem", "shots", "seed", "grain_um",
                                 "density_kg_m3", "roughness_relief_m")}
    out.update(medians_json=json.dumps(p.get("medians", {}), sort_keys=True),
               track_json=json.dumps(p.get("track"), sort_keys=True), status="ok", error="",
               photons=0, n_segments=0, n_good=0, atl03="", atl06="", atl08="")
    for k in ROW_COLUMNS:
        out.setdefault(k, math.nan)
    out.update(_versions())
    out.update(values)
    return out
