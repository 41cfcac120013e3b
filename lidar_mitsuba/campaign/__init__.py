"""Ice-sheet campaigns on Dask: ``lidar-mitsuba campaign SPEC.toml --out DIR`` and :func:`run`.

A campaign is many granules (six beams along a ground track over a GeoTIFF DEM, streamed to
ATL03 and ATL06 files by :func:`lidar_mitsuba.granule.stream_granule`), one Dask task each, on
the engine of the parameter sweeps (:func:`lidar_mitsuba.sweep.execute`): a ``LocalCluster``
here, any running scheduler (``client=``, ``--scheduler tcp://...``; its workers need
lidar_mitsuba and the spec's files at the same paths, and ``DIR`` on a shared file system), or
``workers=0``: one granule after another in this process.

**Spec** (TOML; paths relative to the file)::

    [campaign]
    name = "demo"             # default: the file's name
    seed = 0                  # every granule's seeds derive from it
    format = "parquet"        # tables: "parquet" or "csv"
    version = 1               # vvv and rr of the file names
    revision = 1
    map_bin_m = 1000          # along-track bins of the map [m]
    atl08 = false             # our ATL08 of every granule too (default: with a [forest])
    kernel_cache = "cache"    # snow kernel tables' root (default $LIDAR_MITSUBA_CACHE)

    [dem]
    path = "demo_dem.tif"     # or paths = [...]: the orbit's tracks are found over each

    [instrument]
    preset = "atlas"          # or "paper"
    beams = "all"             # strong, weak, or names: gt1l,gt2l
    sc_orient = 0
    options = { dead_time_ns = 3.2 }   # Instrument fields shared by the beams

    [run]
    shots = 2000              # per beam and granule (at most a crossing), or "all"
    max_depth = 1             # or "auto"; paths_per_shot ("auto"), section_shots (65536)

    [epochs]
    cycles = [3, 4]           # ICESat-2 cycles (the orbit's times) and/or
    dates = ["2019-06-01T00:00:00Z"]   # dates (a spec track flies at each)

    [orbit]                   # the repeat-orbit tracks crossing each DEM
    passes = "both"           # ascending, descending
    # inclination_deg = 92, rgts = 1387, days = 91, node_lon_deg = -0.129,
    # cycle1_utc = "2018-09-28T16:20:02Z", nodal_day_s = 86228.458 (ICESat-2's, as published:
    # campaign/tracks.py), min_length_km = 1

    [[tracks]]                # tracks of your own (any number), each one of:
    start = [69.97, -45.0]    #   a start [lat, lon] and azimuth_deg (a geodesic),
    azimuth_deg = 0.0         #   polyline = [[lat, lon], ...], or file = "rgt.csv"
    rgt = 123                 # optional: the names' RGT (0) and its node time in a cycle
    # epoch_utc = "..."       # optional: its own time instead of [epochs]

    [surface]
    roughness_relief_m = 0.5  # fractal roughness below the DEM posting: a number, or a
    roughness_p = 1.8         # raster with roughness_levels_m = [...]

    [snow]                    # a snow volume under the surface (off without this table)
    grain_um = "demo_grain_um.tif"       # a number, or a raster binned to the levels:
    grain_levels_um = [100, 200, 400, 700, 1000]
    density_kg_m3 = 350                  # likewise (density_levels_kg_m3)
    model = "auto"                       # kernel (auto) or walk

    [forest]                  # a stand over every granule's DEM (off without this table):
    species = "conifer"       #   lm.forest's keywords (height_m, cover, lai, leaf_angle,
    representation = "turbid" #   clumping, ...), size_m: the side of its periodic square
    height_m = 18             #   at the DEM's centre (2048); with it, [campaign] atl08
    cover = 0.6               #   defaults to true: our ATL08 of every granule, and the
    lai = 3                   #   task table's terrain error and canopy height
    size_m = 2048

**Tasks**: DEMs x tracks (the spec's, then the orbit's crossings: ascending, descending, by
RGT) x epochs (:func:`lidar_mitsuba.campaign.tasks.expand`). Each is one granule; its
``task_id`` hashes what defines it (track and time, DEM, shots, instrument, surface, campaign
seed), so a rerun finds what is done. Its photon seed comes from ``SeedSequence([campaign
seed, task_id])`` and its roughness tile's from a stream of its own: neither depends on where
or in what order granules run, so the tables are the same on 0, 1 or many workers, to the bit.

**Surface properties from rasters** (:mod:`.rasters`): a grain-size (density, roughness)
GeoTIFF is read by window along each granule's footprints (all its beams, every 20 m). Each is
resolved per beam and granule section (``Task.grain_sections``, ``density_sections``,
``roughness_sections``: the median over the beam's footprints in the section, snapped to the
nearest level of the spec); a section's snow is its (grain, density) pair's, its roughness the
granule's tile at its level's relief, and a section whose snow or roughness changes is planned
anew. A density or roughness raster with the granule's level in every section leaves the task
as that one number would (no sections; the same task id and seeds). One snow kernel table per
(grain, density) pair is built here before any task is sent, into the kernel cache the workers
read (``kernel_cache``), so a table is built once per campaign pair, not per granule. The
section bounds go to the worker with the task (``Task.section_bounds``), which labels each
segment with its section's levels. *Resolution*: a 40 m ATL06 segment sees its beam's levels
over its section (``[run] section_shots`` shots along track), whatever the raster's pixels; the
segment table keeps the raster's own value at each segment (``*_raster``) beside the one
simulated, so the difference is visible. Shorter sections, or a finer grain of levels, resolve
the field better.

**Outputs** (``out``): ``granules/ATL03/ATL03_[yyyymmdd][hhmmss]_[ttttccss]_[vvv]_[rr].h5``
and ``granules/ATL06/ATL06_...`` (with ``atl08``: ``granules/ATL08/ATL08_...``, our land
and canopy product, its numbers in the task table: :data:`.land.LAND_COLUMNS`), as ICESat-2
names them (:func:`.tracks.product_name`;
``orbit_info/rgt`` and ``cycle_number`` filled in, ``METADATA`` with the name's release), a
folder per product so that ``icepyx.Read("out/granules/ATL06")`` reads a product's granules,
read by the same tools as any granule of ours;
``segments.parquet``: every ATL06 segment with its latitude, longitude, ``h_li``, truth and
error (:data:`.granules.SEGMENT_COLUMNS`); ``tasks.parquet``: a row per granule, its bias and
precision (:data:`.granules.ROW_COLUMNS`); ``map.png``: bias and precision per along-track bin
over the DEM's hillshade (:func:`.maps.plot_map`); ``spec.json``. Each granule's row
(``rows/``) and segments (``segments/``) are written as it finishes, atomically: a rerun skips
the granules with a row (failed ones too, unless ``retry_failed``), so a killed campaign
resumes where it stopped. A granule whose run raises is recorded ``failed`` with its one-line
error, and no files; the others go on.

**Modules**: :mod:`.spec` (the TOML), :mod:`.tracks` (the repeat orbit, names, crossings),
:mod:`.rasters` (property rasters), :mod:`.tasks` (expansion), :mod:`.granules` (what a worker
runs), :mod:`.land` (a forest and ATL08), :mod:`.maps` (the figure); this file drives them.
"""
from __future__ import annotations

import json
import pathlib
import sys
from dataclasses import dataclass

from ..sweep import SpecError, _Store, execute
from .granules import ROW_COLUMNS, SEGMENT_COLUMNS, run_task, snow_volume
from .spec import CampaignSpec, load_spec
from .tasks import Task, check_tasks, expand, payload

__all__ = ["run", "load", "load_spec", "expand", "check_tasks", "build_kernels", "CampaignSpec",
           "CampaignResult", "SpecError", "Task", "SEGMENT_COLUMNS", "ROW_COLUMNS"]


@dataclass
class CampaignResult:
    """What :func:`run` returns.

    Attributes:
        segments: every ATL06 segment of the finished granules (pandas DataFrame,
            :data:`SEGMENT_COLUMNS`, in task, beam, segment order).
        tasks: a row per granule (:data:`ROW_COLUMNS`, in task order).
        out: the output folder; map: ``map.png`` (None when not drawn).
        ran, skipped, failed: granules run now, found done, failed (of all).
    """
    segments: object
    tasks: object
    out: pathlib.Path
    map: pathlib.Path | None
    ran: int
    skipped: int
    failed: int


def _tables(store: _Store, tasks: list[Task]):
    """``(segments, task rows)`` of ``tasks`` found in ``store``, in task order."""
    import pandas as pd
    rows = store.read()
    found = [rows[t.task_id] for t in tasks if t.task_id in rows]
    trows = pd.DataFrame.from_records(found, columns=list(ROW_COLUMNS)) if found else \
        pd.DataFrame(columns=list(ROW_COLUMNS))
    parts = []
    for r in found:
        if r.get("status") != "ok":
            continue
        f = _segments_file(store, r["task_id"])
        if not f.is_file():          # (lost: the granule runs again on the next call)
            continue
        parts.append(pd.read_parquet(f) if store.fmt == "parquet" else
                     pd.read_csv(f, keep_default_na=True))
    seg = pd.concat(parts, ignore_index=True) if parts else \
        pd.DataFrame(columns=list(SEGMENT_COLUMNS))
    return seg[list(SEGMENT_COLUMNS)], trows


def _segments_file(store: _Store, task_id: str) -> pathlib.Path:
    return store.out / "segments" / f"{task_id}.{store.fmt}"


def load(out, spec=None):
    """``(segments, tasks)`` DataFrames of the campaign in folder ``out`` so far (e.g. while
    it runs); ``spec`` default: the folder's ``spec.json``."""
    out = pathlib.Path(out)
    if spec is None:
        doc = json.loads((out / "spec.json").read_text())
        spec = load_spec(doc["spec"], base_dir=doc["base_dir"])
    spec = load_spec(spec)
    return _tables(_Store(out, spec.format), expand(spec))


def _kernel_root(spec: CampaignSpec) -> str:
    from ..ground.snow import kernel
    return spec.kernel_cache or str(kernel.cache_dir().parent)


def build_kernels(tasks: list[Task], spec: CampaignSpec, *, progress: bool = False,
                  log=None) -> int:
    """Build (or find) the snow kernel table of every (grain, density) pair the tasks'
    sections use, in the kernel cache the workers read; returns how many pairs."""
    if spec.snow_model == "walk":
        return 0
    from ..ground.snow import kernel
    from .granules import _kernel_cache, snow_pairs
    levels = set()
    for t in tasks:
        if t.invalid or t.grain_um is None:
            continue
        pairs = snow_pairs(t.grain_um, t.density_kg_m3, t.grain_sections, t.density_sections)
        levels |= set(pairs.values()) if pairs else {(t.grain_um, t.density_kg_m3)}
    levels = sorted(levels, key=lambda gd: (gd[0], -1.0 if gd[1] is None else gd[1]))
    with _kernel_cache(_kernel_root(spec)):
        for g, d in levels:
            (log or (lambda m: None))(f"snow kernel table: grains {g:g} um"
                                      + (f", {d:g} kg/m^3" if d is not None else ""))
            kernel.table(snow_volume(g, d), progress=progress)
    return len(levels)


def _prepare(spec, out, retry_failed, log):
    """Expand and check the spec, then write the folder, ``spec.json`` and ``granules/``;
    ``(tasks, store, rows already done)``."""
    tasks = expand(spec)
    check_tasks(tasks)
    store = _Store(out, spec.format)
    store.out.mkdir(exist_ok=True)
    (store.out / "granules").mkdir(exist_ok=True)
    doc = {"spec": spec.to_dict(), "base_dir": spec.base_dir, "tasks": len(tasks)}
    (store.out / "spec.json").write_text(json.dumps(doc, indent=1, default=str) + "\n")
    ids = {t.task_id for t in tasks}
    rows = {k: r for k, r in store.read().items() if k in ids
            and not (retry_failed and r.get("status") == "failed")
            and (r.get("status") != "ok" or _segments_file(store, k).is_file())}
    if rows:
        log(f"{len(rows)} of {len(tasks)} granules already done in {out}")
    return tasks, store, rows


def run(spec, client=None, *, out, workers: int | None = None, threads: int | None = None,
        retry_failed: bool = False, progress: bool = False, plot: bool = True, log=None,
        _stop_after: int | None = None) -> CampaignResult:
    """Run a campaign (see the module docstring) and return its tables.

    Args:
        spec: a TOML file, a dict of its tables, or a :class:`CampaignSpec`.
        client: a ``dask.distributed.Client``; ``None``: a ``LocalCluster`` of ``workers``.
        out: the output folder (created; reusing it resumes).
        workers: LocalCluster processes (default: the cores); 0: no Dask, in this process.
        threads: Dr.Jit / numba threads per granule (default: cores // workers on a
            LocalCluster, the workers' own otherwise).
        retry_failed: run the granules recorded as failed again.
        progress: a progress bar (stderr); plot: draw ``map.png``; log: ``log(message)``.

    Raises :class:`SpecError` for a bad spec, before anything is written.
    """
    spec = load_spec(spec)
    log = log or (lambda msg: None)
    tasks, store, rows = _prepare(spec, pathlib.Path(out), retry_failed, log)
    todo = [t for t in tasks if t.task_id not in rows]
    ran: list[dict] = []
    from tqdm.auto import tqdm
    bar = tqdm(total=len(tasks), initial=len(rows), desc=spec.name, unit="granule",
               disable=not progress, file=sys.stderr)

    def record(result):
        _record(store, result)
        ran.append(result["row"])
        bar.update(1)
        if _stop_after is not None and len(ran) >= _stop_after:
            raise KeyboardInterrupt

    try:
        build_kernels(todo, spec, progress=progress, log=log)
        variant = _variant()
        loads = [payload(t, spec, out=str(store.out.resolve()), variant=variant,
                         kernel_cache=_kernel_root(spec)) for t in todo]
        for p in [p for p in loads if p["invalid"]]:      # recorded without running
            record(run_task(p))
        execute([p for p in loads if not p["invalid"]], fn=run_task, failed=_failed,
                client=client, workers=workers, threads=threads, record=record, log=log)
    finally:
        bar.close()
        seg, trows = _tables(store, tasks)
        store.results(seg, "segments")
        store.results(trows, "tasks")
    return _finish(spec, store, seg, trows, ran=len(ran), plot=plot)


def _finish(spec, store, seg, trows, *, ran: int, plot: bool) -> CampaignResult:
    path = None
    if plot and len(seg):
        from .maps import plot_map
        path = store.out / "map.png"
        grain = spec.grain.raster if spec.grain is not None else None
        n_ok = int((trows["status"] == "ok").sum())
        plot_map(seg, dems=list(spec.dems), bin_m=spec.map_bin_m, path=path,
                 grain_raster=grain, title=f"{spec.name}: {n_ok} granules, {len(seg)} ATL06 "
                 f"segments ({int((seg['atl06_quality_summary'] == 0).sum())} good)")
    return CampaignResult(segments=seg, tasks=trows, out=store.out, map=path, ran=ran,
                          skipped=len(trows) - ran, failed=int((trows["status"] == "failed")
                                                               .sum()))


def _record(store: _Store, result: dict) -> None:
    """A finished granule: its segments, then its row (the row says it is done)."""
    import pandas as pd
    row = result["row"]
    if result.get("segments") is not None:
        store.put(pd.DataFrame(result["segments"])[list(SEGMENT_COLUMNS)], "segments",
                  row["task_id"])
    store.add(row)


def _failed(p: dict, error: BaseException) -> dict:
    from ..sweep.task import _one_line
    from .granules import row
    return {"row": row(p, status="failed", error=_one_line(error), worker="?"),
            "segments": None}


def _variant() -> str:
    from ..trace.variant import ensure_renderer
    return ensure_renderer().variant()
