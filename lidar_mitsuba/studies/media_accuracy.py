"""Water and air in the accuracy-against-time chart (``bench``): what each knob of a lake and a
fog run costs and buys.

Two scenes of ``scenes/``, run as a user would (default flags but the knob varied), strong beam:

- **a melt pond 2 m deep** (``melt_pond.xml``): the reference is closed form, the bottom's
  apparent depth n_g x 2 m; a run's error is the distance of its bottom photons' median height
  from it, combined with its surface photons' median (which should sit at 0);
- **fog of optical depth 0.5** 50-250 m above snow (``fog.xml``): the reference is the run with
  the most vertices and paths; a run's error combines the differences of the signal photons'
  mean (bias) and standard deviation, as the other panels do.

Knobs: ``max_depth`` (the fog at one vertex is the attenuation-only model; the pond at two
sees the bottom once, without the light its surface reflects back down), ``paths_per_shot``
and the shot count. Each setting's time is the median of three seeds after a warm-up run.
"""
from __future__ import annotations

import math
import pathlib
import time

import numpy as np

from ..ground import water
from ..instrument import Instrument
from ..run import simulate

SCENES = pathlib.Path(__file__).resolve().parents[2] / "scenes"
SEEDS = (1, 2, 3)
POND_DEPTH_M = 2.0


def _pond(res) -> tuple[float, float]:
    """(surface median, bottom median) heights [m] of a pond run's signal photons."""
    h = res.h_m[res.detections.is_signal]
    target = -water.WATER_GROUP_INDEX_532 * POND_DEPTH_M
    surf, bot = h[np.abs(h) < 0.3], h[np.abs(h - target) < 0.5]
    return (float(np.median(surf)) if surf.size else np.nan,
            float(np.median(bot)) if bot.size else np.nan)


def _run(scene: str, params: dict, *, seed: int, **knobs):
    t0 = time.perf_counter()
    res = simulate(scene_file=str(SCENES / scene), params=params, seed=seed, progress=False,
                   instrument=Instrument(beam="strong"), keep_returns=False, **knobs)
    return res, time.perf_counter() - t0


def _setting(scene, params, error, *, smoke: bool = False, **knobs) -> dict:
    """One row: the median time and the RMS error over :data:`SEEDS` after a warm-up run;
    ``smoke``: the first seed alone, no warm-up (every row and field, its time meaningless)."""
    if not smoke:
        _run(scene, params, seed=0, **knobs)                   # warm-up: compile the kernels
    runs = [_run(scene, params, seed=s, **knobs) for s in (SEEDS[:1] if smoke else SEEDS)]
    errs = [error(r) for r, _ in runs]
    return {"seconds": float(np.median([t for _, t in runs])),
            "error_m": float(np.sqrt(np.nanmean(np.square(errs)))),
            "max_depth": int(runs[0][0].config["max_depth"]),
            "paths_per_shot": int(runs[0][0].config["paths_per_shot"])}


def _pond_error(res) -> float:
    surf, bot = _pond(res)
    return math.hypot(surf, bot + water.WATER_GROUP_INDEX_532 * POND_DEPTH_M)


def _fog_error(ref):
    def error(res) -> float:
        st = res.report().overall
        return math.hypot(st.bias_m - ref.bias_m, st.std_m - ref.std_m)
    return error


def run(*, quick: bool = False, smoke: bool = False) -> dict:
    """Both panels: ``{name: {"reference": {...}, "rows": [...]}}`` as
    :func:`lidar_mitsuba.studies.accuracy.run` gives them. ``smoke`` (the tests' size; implies
    ``quick``): each setting run once (:func:`_setting`; the reference run is the quick one)."""
    quick = quick or smoke
    shots = 300 if quick else 1500
    out = {}
    pond = {"depth_m": str(POND_DEPTH_M)}
    rows = []
    knobs = ({"max_depth": (2, 8)} if quick else
             {"max_depth": (2, 4, 8), "paths_per_shot": (8, 16, 64),
              "shots": (shots // 2, shots)})
    for knob, values in knobs.items():
        for v in values:
            cfg = {"shots": shots, knob: v}
            rows.append({"knob": knob, "value": v, **_setting("melt_pond.xml", pond,
                                                              _pond_error, smoke=smoke,
                                                              **cfg)})
    out[f"melt pond {POND_DEPTH_M:g} m"] = {
        "reference": {"source": f"closed form: bottom at n_g x {POND_DEPTH_M:g} m, "
                                f"n_g = {water.WATER_GROUP_INDEX_532:.4f}"}, "rows": rows}
    fog = {"tau": "0.5"}
    ref_shots, ref_depth = (2 * shots, 8) if quick else (4 * shots, 16)
    ref_res, ref_s = _run("fog.xml", fog, seed=999, shots=ref_shots, max_depth=ref_depth)
    ref = ref_res.report().overall
    rows = []
    knobs = ({"max_depth": (1, 8)} if quick else
             {"max_depth": (1, 2, 4, 8), "paths_per_shot": (64, 256, 1024),
              "shots": (shots // 2, shots)})
    for knob, values in knobs.items():
        for v in values:
            cfg = {"shots": shots, knob: v}
            rows.append({"knob": knob, "value": v,
                         **_setting("fog.xml", fog, _fog_error(ref), smoke=smoke, **cfg)})
    out["fog, optical depth 0.5"] = {
        "reference": {"source": f"{ref_shots} shots, max_depth {ref_depth} ({ref_s:.1f} s)",
                      "bias_m": ref.bias_m, "std_m": ref.std_m}, "rows": rows}
    return out


def format_summary(doc: dict) -> list[str]:
    """One line per panel: the cheapest and the most accurate setting, and shots per second."""
    lines = []
    for name, panel in doc.items():
        rows = panel["rows"]
        best = min(rows, key=lambda r: r["error_m"])
        fast = min(rows, key=lambda r: r["seconds"])
        lines.append(f"{name}: fastest {fast['knob']}={fast['value']} {fast['seconds']:.2f} s "
                     f"(error {100 * fast['error_m']:.1f} cm); most accurate "
                     f"{best['knob']}={best['value']} {best['seconds']:.2f} s "
                     f"(error {100 * best['error_m']:.1f} cm)")
    return lines
