"""A campaign's tasks: one granule each (a track over a DEM at an epoch), with its file name,
seeds and surface properties, expanded from a spec in a fixed order (:func:`expand`)."""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from dataclasses import dataclass

import numpy as np

from ..sweep.spec import SpecError
from . import rasters as rs, tracks as tk
from .granules import SECTIONED
from .spec import CampaignSpec, Property, load_spec

_TERRAIN_STREAM = 0x54455252        # 'TERR': roughness seeds apart from photon seeds


@dataclass(frozen=True)
class Task:
    """One granule of a campaign (what a worker runs, as a dict with the run's settings).

    Attributes:
        task_id: 16 hex digits of the SHA-256 of what defines the granule (its track and
            epoch, DEM, shots, instrument, surface, campaign seed): the same in every run.
        task_index: its place in the spec's expansion (the tables' order).
        granule: the file names' common part, ``[yyyymmddhhmmss]_[ttttccss]_[vvv]_[rr]``.
        rgt, cycle, region: the reference ground track (0: a track of the spec's own without
            one), the cycle (0: before cycle 1), the granule region (1-14).
        ascending: the pass (northward at the first shot).
        dem: the DEM file (absolute); track: :class:`~lidar_mitsuba.geotrack.GeoTrack` fields.
        shots: shots per beam; seed: the photon seed; roughness_seed: the roughness tile's.
        grain_um, density_kg_m3, roughness_relief_m: the granule's values (None: none).
        grain_sections: with a grain-size raster, each beam's level per granule section
            (``{beam: [level, ...]}``: what its photons see; ``grain_um`` is the granule's).
        density_sections, roughness_sections: likewise with a density (roughness) raster,
            where some beam's section has a level other than the granule's (None where every
            one has the granule's: the granule is then run, and named, as with one value).
        section_bounds: the granule sections' ``[(first, stop), ...]`` shots (every beam's:
            :func:`lidar_mitsuba.granule.section_bounds`, as the granule streams them);
            shot_spacing_m: the shots' spacing along track [m]. A segment at ``x_atc`` is in
            the section holding shot ``floor(x_atc / shot_spacing_m)``.
        medians: each raster property's median along the granule before binning.
        invalid: why the task cannot run ('' when it can): recorded, not run.
    """
    task_id: str
    task_index: int
    granule: str
    rgt: int
    cycle: int
    region: int
    ascending: bool
    dem: str
    track: dict
    shots: int
    seed: int
    roughness_seed: int
    grain_um: float | None
    density_kg_m3: float | None
    roughness_relief_m: float | None
    medians: dict
    invalid: str = ""
    grain_sections: dict | None = None
    density_sections: dict | None = None
    roughness_sections: dict | None = None
    section_bounds: tuple = ()
    shot_spacing_m: float = 0.7


def _instrument(spec: CampaignSpec):
    """The campaign's instrument (a strong beam: what every beam shares)."""
    from ..instrument import Instrument
    opts = spec.instrument_options
    inst = Instrument.atlas("strong", **opts) if spec.instrument == "atlas" else \
        Instrument(**opts)
    return inst


def _margin_m(inst) -> float:
    """How far from every beam's footprint the DEM must be valid [m]: the corridor a run
    meshes (the field of view when paths may bounce on), plus two DEM pixels and a probe step."""
    return max(5.0 * inst.footprint_sigma_m + 1.0, inst.fov_diameter_m / 2.0 + 5.0) + 100.0


def _geotracks(spec: CampaignSpec, dem_index: int, dem, inst, beams, orbit):
    """``[(track dict without epoch, rgt, ascending, shots, epochs [(t_s, cycle)])]`` of one
    DEM: the spec's own tracks over it, then the repeat orbit's crossings."""
    from ..geotrack import GeoTrack
    out = []
    spacing = inst.shot_spacing_m
    for t in spec.tracks:
        if t["dem"] != dem_index:
            continue
        g = GeoTrack(**{**t["track"], "polyline": _tuple(t["track"]["polyline"])})
        shots = _explicit_shots(spec, g, spacing)
        _, _, az, _ = g.shots(1, spacing_m=spacing)
        out.append((g.to_dict(), t["rgt"], bool(math.cos(math.radians(az[0])) > 0), shots,
                    _explicit_epochs(spec, t, orbit)))
    if spec.orbit is None:
        return out
    cycles = sorted(set(spec.cycles) | {orbit.cycle_of(_t_s(d)) for d in spec.dates})
    for c in tk.crossings(dem, spec.orbit, beams=beams, margin_m=_margin_m(inst),
                          passes=spec.passes, min_length_m=spec.min_length_m):
        fit = int(c.length_m // spacing)
        shots = fit if spec.run["shots"] == "all" else min(int(spec.run["shots"]), fit)
        poly, u0 = tk.crossing_polyline(c, start_m=(c.length_m - shots * spacing) / 2,
                                        length_m=shots * spacing)
        g = GeoTrack(polyline=poly)
        out.append((g.to_dict(), c.rgt, c.ascending, shots,
                    [(orbit.time_s(c.rgt, k, u0), k) for k in cycles]))
    return out


def _tuple(poly):
    return None if poly is None else tuple(map(tuple, poly))


def _t_s(text: str) -> float:
    from ..geotrack import SDP_EPOCH_UTC, parse_utc
    return (parse_utc(text) - SDP_EPOCH_UTC).total_seconds()


def _explicit_shots(spec: CampaignSpec, g, spacing: float) -> int:
    if spec.run["shots"] != "all":
        return int(spec.run["shots"])
    if g.polyline is None:
        raise SpecError("[run] shots", "'all' needs tracks of a known length (polylines, "
                        "files or the [orbit]'s)")
    from pyproj import Geod
    pts = np.asarray(g.polyline)
    _, _, d = Geod(ellps="WGS84").inv(pts[:-1, 1], pts[:-1, 0], pts[1:, 1], pts[1:, 0])
    return max(1, int(np.sum(d) // spacing))


def _explicit_epochs(spec: CampaignSpec, t: dict, orbit) -> list[tuple[float, int]]:
    """A spec track's ``[(t_s, cycle)]``: its own epoch, else each date, then each cycle (at
    its RGT's node time when it names an RGT, else at the cycle's start)."""
    if t.get("epoch_utc") is not None:
        ts = _t_s(t["epoch_utc"])
        return [(ts, orbit.cycle_of(ts))]
    out = [(_t_s(d), orbit.cycle_of(_t_s(d))) for d in spec.dates]
    for c in spec.cycles:
        out.append((orbit.time_s(t["rgt"], c, 0.0) if t["rgt"] else orbit.cycle_start_s(c), c))
    return out


def _value(prop: Property | None, values) -> tuple[float | None, float | None]:
    """``(value used, raster median)`` of a property from the raster's ``values`` along a
    granule's points (None without a raster)."""
    if prop is None:
        return None, None
    if prop.raster is None:
        return prop.value, None
    m = rs.finite_median(values)
    return (rs.snap(m, prop.levels) if math.isfinite(m) else math.nan), m


def _properties(spec: CampaignSpec, g, beams, shots, inst, opened: dict) -> tuple[dict, str]:
    """The granule's ``{grain_um, density_kg_m3, roughness_relief_m}`` used, their raster
    medians, each beam's level of each raster property per section (``*_sections``; density
    and roughness only where some section's level is not the granule's), the sections' shots
    (``section_bounds``), and why the task cannot run ('' if it can)."""
    props = {"grain_um": spec.grain, "density_kg_m3": spec.density,
             "roughness_relief_m": spec.roughness}
    need = {k: p for k, p in props.items() if p is not None and p.raster is not None}
    if need:
        lat, lon, shot = rs.track_points(g, beams, n_shots=shots,
                                         spacing_m=inst.shot_spacing_m)
    used, medians, values, why = {}, {}, {}, ""
    for k, p in props.items():
        if k in need:              # the raster at every beam's points, read once
            raster = opened.get(p.raster) or opened.setdefault(p.raster,
                                                               rs.PropertyRaster(p.raster))
            values[k] = raster.at(lat, lon)
        used[k], m = _value(p, values.get(k))
        if m is not None:
            medians[k] = m
        if used[k] is not None and not math.isfinite(used[k]) and not why:
            why = f"the {k} raster has no value along the track ({p.raster})"
    from ..granule import section_bounds
    bounds = section_bounds(shots, spacing_m=inst.shot_spacing_m,
                            section_shots=spec.run["section_shots"])
    sections = dict.fromkeys(SECTIONED.values())
    for k, p in need.items():       # what each beam's photons see, section by section
        if why:
            break
        levels = rs.section_levels(values[k], shot, beams=beams, levels=p.levels,
                                   bounds=bounds, fallback=used[k])
        if k == "grain_um" or any(v != used[k] for row in levels.values() for v in row):
            sections[SECTIONED[k]] = levels
    return {**used, "medians": medians, **sections,
            "section_bounds": tuple(map(tuple, bounds)),
            "shot_spacing_m": float(inst.shot_spacing_m)}, why


def task_id(doc: dict) -> str:
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _seeds(campaign_seed: int, tid: str) -> tuple[int, int]:
    seed = int(np.random.SeedSequence([campaign_seed, int(tid, 16)]).generate_state(1)[0])
    rough = int(np.random.SeedSequence([campaign_seed, _TERRAIN_STREAM, int(tid, 16)])
                .generate_state(1)[0])
    return seed, rough


def expand(spec) -> list[Task]:
    """The tasks of a spec, in order: DEMs x (the spec's tracks, then the orbit's crossings,
    ascending before descending, by RGT) x epochs. Reads each DEM and raster window along the
    tracks (cheap: no simulation). Raises :class:`~lidar_mitsuba.sweep.SpecError` when two
    granules would have one file name."""
    from ..geotrack import GeoTrack, select_beams
    from ..ground.dem import DEM
    spec = load_spec(spec)
    inst = _instrument(spec)
    beams = select_beams(spec.beams, spec.sc_orient)
    orbit = spec.orbit or tk.RepeatOrbit()
    tasks, opened, names = [], {}, {}
    for i, dem_path in enumerate(spec.dems):
        dem = DEM.open(dem_path)
        for track, rgt, asc, shots, epochs in _geotracks(spec, i, dem, inst, beams, orbit):
            g = GeoTrack(**{**track, "polyline": _tuple(track["polyline"])})
            props, why = _properties(spec, g, beams, shots, inst, opened)
            lat0 = g.start_lat_lon(spacing_m=inst.shot_spacing_m)[0]
            region = tk.granule_region(lat0, ascending=asc)
            for t_s, cycle in epochs:
                tasks.append(_task(spec, len(tasks), dem_path, spec.base_dir, track, rgt, asc,
                                   shots, t_s, cycle, region, props, why))
                _unique(names, tasks[-1])
    return tasks


def _task(spec, index, dem_path, base, track, rgt, asc, shots, t_s, cycle, region, props,
          why) -> Task:
    track = {**track, "epoch_utc": tk.utc_text(t_s)}
    name = tk.product_name("ATLxx", t_s=t_s, rgt=rgt, cycle=cycle, region=region,
                           version=spec.version, revision=spec.revision)[6:-3]
    used = {k: props[k] for k in SECTIONED}
    sections = {f: props[f] for f in SECTIONED.values()}
    # (density's and roughness's sections name the task only where they vary: a campaign of
    # one value per granule keeps its task ids, and so its seeds)
    doc = {"seed": spec.seed, "dem": os.path.relpath(dem_path, base), "track": track,
           "rgt": rgt, "cycle": cycle, "shots": shots, "beams": spec.beams,
           "sc_orient": spec.sc_orient, "instrument": spec.instrument,
           "options": spec.instrument_options, "run": spec.run, "snow_model": spec.snow_model,
           "roughness_p": spec.roughness_p, "name": name, **used,
           **{f: v for f, v in sections.items() if v is not None or f == "grain_sections"},
           **({} if spec.cloud is None else {"cloud": spec.cloud}),   # (clear: ids kept)
           **({} if spec.forest is None else {"forest": spec.forest}),   # (likewise bare)
           **({"atl08": True} if spec.atl08 else {})}
    tid = task_id(doc)
    seed, rough = _seeds(spec.seed, tid)
    return Task(task_id=tid, task_index=index, granule=name, rgt=int(rgt), cycle=int(cycle),
                region=int(region), ascending=bool(asc), dem=dem_path, track=track,
                shots=int(shots), seed=seed, roughness_seed=rough, medians=props["medians"],
                invalid=why, section_bounds=props["section_bounds"],
                shot_spacing_m=props["shot_spacing_m"], **sections, **used)


def _unique(names: dict, t: Task) -> None:
    if t.granule in names:
        raise SpecError("[[tracks]]", f"tasks {names[t.granule] + 1} and {t.task_index + 1} "
                        f"would both be granule {t.granule}: give the spec's tracks distinct "
                        "rgt or epochs")
    names[t.granule] = t.task_index


def payload(task: Task, spec: CampaignSpec, *, out: str, kernel_cache: str,
            variant: str | None) -> dict:
    """What a worker runs (:func:`lidar_mitsuba.campaign.granules.run_task`): the task and
    the campaign's settings, all plain values."""
    rasters = {k: p.raster for k, p in (("grain_um", spec.grain),
                                        ("density_kg_m3", spec.density),
                                        ("roughness_relief_m", spec.roughness))
               if p is not None and p.raster is not None}
    return {**dataclasses.asdict(task), "beams": spec.beams, "sc_orient": spec.sc_orient,
            "instrument": spec.instrument, "instrument_options": spec.instrument_options,
            "run": spec.run, "snow_model": spec.snow_model, "roughness_p": spec.roughness_p,
            "rasters": rasters, "out": str(out), "kernel_cache": kernel_cache,
            "variant": variant, "cloud": spec.cloud, "forest": spec.forest,
            "atl08": spec.atl08}


def check_tasks(tasks: list[Task]) -> None:
    """Refuse a campaign none of whose tasks can run (:class:`SpecError`)."""
    if not tasks:
        raise SpecError("spec", "no granules: no track crosses the DEM (every beam over valid "
                        "pixels) and the spec gives none of its own")
    if all(t.invalid for t in tasks):
        raise SpecError("spec", f"{tasks[0].invalid} (in every task)")

