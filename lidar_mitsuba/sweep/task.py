"""One sweep task: the simulate() keywords of its parameters, the run, and its row of
statistics (:data:`COLUMNS`). What a Dask worker executes (:func:`run_task`)."""
from __future__ import annotations

import dataclasses
import json
import math
import os
import pathlib
import socket
import time
import warnings
from datetime import datetime, timezone

import numpy as np

from ..products import atl06
from ..constants import ParameterError
from ..machine import versions
from ..instrument import Instrument
from ..run import check_run, simulate
from ..ground.surface import SurfaceSpec
from ..track import Track
from ..trace.variant import DEFAULT_VARIANT
from .spec import Task, _key, parameter_names

#: columns that differ between identical runs (when and where a task ran)
RUN_DEPENDENT = ("simulate_s", "atl06_s", "task_s", "started_at", "finished_at", "worker")

COLUMNS: dict[str, str] = {
    "task_id": "16 hex digits identifying the task (parameters, replicate, sweep seed)",
    "task_index": "position of the task in the spec's expansion (the table's order)",
    "replicate": "realisation 0 .. replicates - 1",
    # ... one column per parameter of the spec here ...
    "seed": "photon Monte Carlo seed of the run (derived from the task, or the parameter)",
    "terrain_seed": "fractal terrain seed (derived from the replicate, or the parameter; "
                    "planes and scenes do not use it)",
    "status": "'ok', or 'failed' (invalid parameters, or the run raised)",
    "error": "one-line error of a failed task ('' when ok)",
    "n_photons": "signal photons detected (0 when failed)",
    "photons_per_shot": "signal photons per shot",
    "bias_m": "mean of h - z_ref over the signal photons [m]",
    "bias_se_m": "standard error of bias_m, std / sqrt(n) [m]",
    "std_m": "precision: standard deviation of h - z_ref [m]",
    "std_se_m": "standard error of std_m, from the photons' kurtosis (std / sqrt(2 (n - 1)) "
                "for normal residuals) [m]",
    "robust_std_m": "robust spread: 1.4826 x median absolute deviation of h - z_ref [m] (the "
                    "precision without the late tail of multiply scattered photons)",
    "robust_std_se_m": "standard error of robust_std_m, 1.1664 robust_std_m / sqrt(n) (normal "
                       "approximation: the MAD's 37 % efficiency) [m]",
    "atl06_n_segments": "ATL06-style 40 m segments (lidar_mitsuba.products.atl06, all photons)",
    "atl06_n_good": "unflagged segments",
    "h_li_bias_m": "mean of h_li - h_ref over the good segments [m]",
    "h_li_bias_se_m": "its standard error, from every other good segment (independent) [m]",
    "h_li_std_m": "standard deviation of h_li - h_ref over the good segments [m]",
    "h_li_std_se_m": "its standard error, std / sqrt(2 (k - 1)), k every other good segment [m]",
    "max_depth_used": "bounces traced (max_depth 'auto' resolved)",
    "warnings": "the run's SimulationWarnings, joined by ' | '",
    "simulate_s": "wall time of simulate() [s]",
    "atl06_s": "wall time of the segment fit [s]",
    "task_s": "wall time of the whole task on its worker [s]",
    "started_at": "UTC start of the task (ISO 8601)",
    "finished_at": "UTC end of the task (ISO 8601)",
    "worker": "host:pid of the process that ran it",
    "lidar_mitsuba_version": "versions of the worker's packages",
    "mitsuba_version": "",
    "drjit_version": "",
    "parameters_json": "the task's parameters as given in the spec (JSON)",
    "config_json": "the run's full configuration, simulate()'s result.config (JSON; '' when "
                   "failed)",
}
_HEAD = ("task_id", "task_index", "replicate")


def build(task: Task | dict) -> dict:
    """The :func:`~lidar_mitsuba.run.simulate` keywords of a task (ParameterError, named,
    for a bad value: cheap, nothing is loaded)."""
    t = task if isinstance(task, dict) else dataclasses.asdict(task)
    groups = parameter_names()
    kw: dict[str, dict] = {"instrument": {}, "surface": {}, "track": {}, "run": {}, "xml": {}}
    for k, v in t["parameters"].items():
        if k.startswith("params."):
            kw["xml"][k[7:]] = v
        else:
            kw[groups[k]]["kind" if k == "surface" else k] = tuple(v) if isinstance(v, list) else v
    run = kw["run"]
    run["seed"] = t["seed"]
    scene = run.pop("scene", None)
    if scene is None and kw["xml"]:
        raise ParameterError("params", "only apply to a scene (give scene = \"FILE.xml\")")
    if scene is not None:
        if kw["surface"]:
            name = next(iter(kw["surface"]))
            raise ParameterError("surface" if name == "kind" else name,
                                 "does not apply to a scene (set it in the XML)")
        path = pathlib.Path(t["base_dir"]) / str(scene)
        if not path.is_file():
            raise ParameterError("scene", f"{str(path)!r} not found")
        surface = dict(scene_file=str(path), params=kw["xml"] or None)
    else:
        s = kw["surface"]
        if "kind" not in s and "slope_deg" in s:
            s["kind"] = "slope"
        s.setdefault("terrain_seed", t["terrain_seed"])
        surface = dict(surface=SurfaceSpec(**s))
    crop = run.pop("crop_to_track", True)
    run.setdefault("variant", DEFAULT_VARIANT)
    check_run(**{k: v for k, v in run.items()
                 if k in ("shots", "seed", "paths_per_shot", "max_depth", "chunk_shots")})
    return dict(instrument=Instrument(**kw["instrument"]), track=Track(**kw["track"]),
                crop_to_track=crop, **surface, **run)


def _one_line(e: BaseException) -> str:
    text = (str(e).strip().splitlines() or [""])[0]
    return text if isinstance(e, ParameterError) else f"{type(e).__name__}: {text}"


def _versions() -> dict:
    return {f"{pkg}_version": v for pkg, v in versions().items()}


def _set_threads(n: int | None) -> None:
    if n is None:
        return
    from ..trace.variant import ensure_renderer
    ensure_renderer()                  # (libLLVM checked before Dr.Jit loads)
    import drjit as dr
    import numba
    dr.set_thread_count(int(n))
    numba.set_num_threads(max(1, min(int(n), numba.config.NUMBA_NUM_THREADS)))


def _nan(v) -> float:
    return math.nan if v is None else float(v)


def _statistics(res) -> dict:
    """The row's numbers of one SimulationResult."""
    o = res.report().overall
    dh = res.dh_m[res.detections.is_signal]
    n = dh.size
    mad = 1.4826 * float(np.median(np.abs(dh - np.median(dh)))) if n else math.nan
    t = time.perf_counter()
    table = atl06.segments_from_result(res)
    summary = atl06.summarize(table)
    d = table.h_li - table.h_ref_m
    k = int(np.count_nonzero(table.good & (np.arange(len(table)) % 2 == 0) & np.isfinite(d)))
    h_std = _nan(summary["h_li_minus_ref_std_m"])
    return {"n_photons": int(n), "photons_per_shot": float(o.photons_per_shot),
            "bias_m": o.bias_m, "bias_se_m": o.bias_se_m, "std_m": o.std_m,
            "std_se_m": o.std_se_m, "robust_std_m": mad,
            "robust_std_se_m": 1.1664 * mad / math.sqrt(n) if n > 1 else math.nan,
            "atl06_n_segments": int(summary["n_segments"]), "atl06_n_good": int(summary["n_good"]),
            "h_li_bias_m": _nan(summary["h_li_minus_ref_mean_m"]),
            "h_li_bias_se_m": _nan(summary["h_li_minus_ref_se_m"]),
            "h_li_std_m": h_std,
            "h_li_std_se_m": h_std / math.sqrt(2.0 * (k - 1)) if k > 1 else math.nan,
            "atl06_s": time.perf_counter() - t}


def _row(task: dict, **values) -> dict:
    """A row with every column of :data:`COLUMNS` (NaN / 0 / '' where there is no value)."""
    row = {"task_id": task["task_id"], "task_index": task["task_index"],
           "replicate": task["replicate"]}
    for k, v in task["parameters"].items():
        row[k] = json.dumps(v) if isinstance(v, list) else v
    row.update(seed=task["seed"], terrain_seed=task["terrain_seed"], status="ok", error="",
               n_photons=0, atl06_n_segments=0, atl06_n_good=0, max_depth_used=0,
               warnings="", parameters_json=_key(task["parameters"]), config_json="")
    for k in COLUMNS:
        row.setdefault(k, math.nan)
    row.update(_versions())
    row.update(values)
    return row


def run_task(task: dict) -> dict:
    """Run one task (a :class:`Task` as a dict, plus ``threads``) and return its row; never
    raises for a failing run: the row says ``failed`` and why."""
    started, t0 = datetime.now(timezone.utc), time.perf_counter()
    values: dict = {}
    try:
        _set_threads(task.get("threads"))
        kw = build(task)
        with warnings.catch_warnings():     # the SimulationWarnings are kept in the row; the
            warnings.simplefilter("ignore")  # rest (numpy on empty segments) is noise here
            res = simulate(progress=False, **kw)
            values.update(_statistics(res), simulate_s=res.timings_s["total_s"],
                          max_depth_used=int(res.config["max_depth"]),
                          warnings=" | ".join(res.config["warnings"]),
                          config_json=json.dumps(res.config, default=str))
    except Exception as e:                     # recorded, not raised: the sweep goes on
        values = {"status": "failed", "error": _one_line(e)}
    return _row(task, **values, task_s=time.perf_counter() - t0,
                started_at=started.isoformat(), worker=f"{socket.gethostname()}:{os.getpid()}",
                finished_at=datetime.now(timezone.utc).isoformat())
