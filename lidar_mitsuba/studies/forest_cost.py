"""The cost of a forest in a granule (``bench``'s ``forest`` rows; issue 42: "the turbid canopy
traces a 100 km forested granule at most 2x a bare one").

Six beams along the long synthetic ice sheet of :mod:`.track_length` (10 km wide, 100 m
posting), streamed to ATL03 and ATL06, bare and under a conifer stand of the species preset
(18 m, 60 % cover, LAI 3; the default periodic 2 km stand at the DEM's centre, which every
corridor tile sees through its images) in the ``gap`` and ``turbid`` representations over
100 km, and in ``explicit`` leaves over 0.35 km of one strong beam (one corridor tile:
~3.5 million triangles; six beams' tiles held ~7 GB here), each paired with the bare granule
of its length and beams. The runs of one length
alternate (bare, gap, turbid, bare, ...) in one warm process, after a short warm-up of each
(kernels compiled), and each row is the median of ``repeats``; a row's ``over_bare`` is its
median over the bare median, ``over_bare_paired`` the median of each round's ratio to the
bare run of its round, ``of_cast`` its median over the time its rays take to cast
alone into the bare DEM's corridor (:func:`.track_length.cast_time`: the row's own ray count,
as the ``granule`` row's ``of_cast``). The forest's ATL08 (our classifier over the ATL03,
:mod:`lidar_mitsuba.products.atl08.granule`) is timed apart (``atl08_s``): the product, not
the trace. All runs: ``max_depth=1``, paths per shot by the scout, the range gate 60 m (the
canopy inside it, bare and forest alike). ``quick`` (the bench's test): one beam over
0.15 km, bare and turbid (a 256 m stand), once each.

``python -m lidar_mitsuba.studies.forest_cost [KM] [REPEATS] [canopy,explicit]`` runs the
full study (or one part) in a process of its own and prints its JSON.
"""
from __future__ import annotations

import json
import pathlib
import statistics
import sys
import tempfile
import time

from . import track_length

#: the range gate of every run [m]: the paper's 30 m would cut the 18 m canopy's top
RANGE_GATE_M = 60.0
#: explicit leaves' length [km]: 500 shots, one corridor tile per beam (forest.TILE_SHOTS)
EXPLICIT_KM = 0.35


def _forest(surf, representation: str, *, stand_m: float | None = None):
    """The conifer preset over ``surf`` (a periodic square of ``stand_m`` [m] at its centre;
    None: the default, :data:`~lidar_mitsuba.vegetation.stand.DEM_STAND_M`)."""
    from ..vegetation.forest import forest
    bounds = None
    if stand_m is not None:
        (cx, cy), h = surf.centre_xy_m(), stand_m / 2
        bounds = ((cx - h, cy - h), (cx + h, cy + h))
    return forest(species="conifer", ground=surf, representation=representation, seed=1,
                  bounds_m=bounds)


def _granule(surface, track, *, shots: int, beams: str, tmp: pathlib.Path) -> tuple:
    """One streamed granule (ATL03 and ATL06): ``(seconds, summaries)``."""
    from .. import granule
    t0 = time.perf_counter()
    out = granule.stream_granule(surface=surface, track=track, shots=shots, beams=beams,
                                 max_depth=1, progress=False, paths_per_shot="auto",
                                 instrument_options={"range_gate_m": RANGE_GATE_M},
                                 atl03_path=tmp / "a3.h5", atl06_path=tmp / "a6.h5")
    return time.perf_counter() - t0, out


def _atl08_s(tmp: pathlib.Path) -> float:
    """Seconds our ATL08 takes from the last granule's ATL03."""
    from ..instrument import Instrument
    from ..products.atl08 import granule as atl08_granule
    t0 = time.perf_counter()
    atl08_granule.write_from_atl03(tmp / "a3.h5", tmp / "a8.h5",
                                   instrument=Instrument(range_gate_m=RANGE_GATE_M))
    return time.perf_counter() - t0


def _alternated(cases: dict, track, *, km: float, beams: str, repeats: int, warm: bool,
                tmp: pathlib.Path, surf, log=None) -> list[dict]:
    """Rows of ``cases`` (name -> surface), run in turn ``repeats`` times (after a 0.3 km
    warm-up of each when ``warm``), each against the first (bare) and its rays cast."""
    shots = int(round(km * 1e3 / 0.7))
    if warm:
        for s in cases.values():
            _granule(s, track, shots=min(shots, 430), beams=beams, tmp=tmp)
    times = {name: [] for name in cases}
    outs, atl08 = {}, {}
    for _ in range(repeats):
        for name, s in cases.items():
            t, outs[name] = _granule(s, track, shots=shots, beams=beams, tmp=tmp)
            times[name].append(t)
            if log is not None:
                log(f"{name} {km:g} km: {t:.2f} s")
            if name != "bare" and name not in atl08:
                atl08[name] = _atl08_s(tmp)
    bare = statistics.median(times["bare"])
    rows, casts = [], {}
    for name, out in outs.items():
        rays = track_length.granule_rays(out)
        ppshot = out[0].config["paths_per_shot"]
        if (rays, ppshot) not in casts:           # (rows of the same rays: one yardstick)
            casts[rays, ppshot] = track_length.cast_time(surf, track, rays=rays, shots=shots,
                                                         beams=beams, paths_per_shot=ppshot)
        cast = casts[rays, ppshot]
        sec = statistics.median(times[name])
        rows.append({"representation": name, "length_km": km, "beams": len(out),
                     "shots": shots, "seconds": sec, "times_s": times[name],
                     "over_bare": sec / bare,
                     # each round's run over the bare one beside it, the median (the load of
                     # a shared machine drifts between rounds more than within one)
                     "over_bare_paired": statistics.median(
                         t / b for t, b in zip(times[name], times["bare"])),
                     "rays": rays, **cast, "of_cast": sec / cast["cast_s"],
                     "paths_per_shot": out[0].config["paths_per_shot"],
                     "atl08_s": atl08.get(name), "repeats": repeats,
                     "photons": out[0].photons})
    return rows


def run(*, quick: bool, km: float | None = None, repeats: int | None = None,
        parts: tuple[str, ...] = ("canopy", "explicit"), log=None) -> list[dict]:
    """The rows: bare, gap and turbid at ``km`` (default 100; quick: bare and turbid, one
    beam, 0.15 km), then bare and explicit at :data:`EXPLICIT_KM` (not quick). ``log``:
    called with a line after each granule."""
    km = (0.15 if quick else 100.0) if km is None else float(km)
    repeats = (1 if quick else 3) if repeats is None else int(repeats)
    beams = "gt2l" if quick else "all"
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        surf, track = track_length.ice_sheet(tmp, km)
        reps = ("turbid",) if quick else ("gap", "turbid")
        stand_m = 256.0 if quick else None            # (quick: its cover in 0.03 s)
        rows = []
        if "canopy" in parts:
            cases = {"bare": surf, **{r: _forest(surf, r, stand_m=stand_m) for r in reps}}
            rows += _alternated(cases, track, km=km, beams=beams, repeats=repeats,
                                warm=not quick, tmp=tmp, surf=surf, log=log)
            if log is not None:
                log(json.dumps(rows))
        if not quick and "explicit" in parts:       # one beam: ~3.5 M triangles a tile
            rows += _alternated({"bare": surf, "explicit": _forest(surf, "explicit")}, track,
                                km=min(km, EXPLICIT_KM), beams="gt2l", repeats=repeats,
                                warm=False, tmp=tmp, surf=surf, log=log)
    return rows


def format_rows(rows: list[dict]) -> list[str]:
    """The rows in words, one line per length."""
    lines = []
    for km in dict.fromkeys(r["length_km"] for r in rows):
        here = [r for r in rows if r["length_km"] == km]
        bare = next(r for r in here if r["representation"] == "bare")
        parts = [f"bare {bare['seconds']:.1f} s ({bare['of_cast']:.1f}x its rays cast alone)"]
        for r in here:
            if r["representation"] == "bare":
                continue
            atl08 = "" if r["atl08_s"] is None else f", its ATL08 {r['atl08_s']:.1f} s"
            parts.append(f"{r['representation']} {r['seconds']:.1f} s = {r['over_bare']:.2f}x "
                         f"bare (paired {r['over_bare_paired']:.2f}x; {r['of_cast']:.1f}x its "
                         f"rays cast alone, "
                         f"{r['paths_per_shot']} paths a shot{atl08})")
        lines.append(f"forest in a DEM granule ({bare['beams']} beams x {km:g} km, conifer "
                     f"18 m, 60 % cover, LAI 3; medians of {bare['repeats']}): "
                     + "; ".join(parts))
    return lines


if __name__ == "__main__":
    args = sys.argv[1:]
    print(json.dumps(run(quick=False, km=float(args[0]) if args else None,
                         repeats=int(args[1]) if len(args) > 1 else None,
                         parts=tuple(args[2].split(",")) if len(args) > 2
                         else ("canopy", "explicit"),
                         log=lambda line: print(line, file=sys.stderr, flush=True))))
