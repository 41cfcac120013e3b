"""``campaign`` (granules over DEMs on Dask, :mod:`lidar_mitsuba.campaign`) and
``make-raster`` (a property GeoTIFF with a gradient over a DEM, e.g. the demo's grain size)."""
from __future__ import annotations

import math
import os
import pathlib
import sys

from .args import (PROG, UsageError, connect_scheduler, nonnegative_int, out_dir, out_path,
                   positive_int, spec_error)


def add_parsers(sub) -> None:
    c = sub.add_parser("campaign", help="ice-sheet campaigns on Dask: granules along repeat-"
                       "orbit tracks over DEMs, a segment table and a bias map, resumable",
                       description="Simulate many granules (ATL03 + ATL06 files named as "
                       "ICESat-2 names them) along the spec's tracks and the repeat-orbit "
                       "tracks crossing its DEMs, one Dask task each (a LocalCluster here, or "
                       "a running scheduler), with snow and roughness from rasters; writes "
                       "every ATL06 segment with its truth and error to one table and maps "
                       "bias and precision over the DEM. Rerunning resumes. The spec format is "
                       "in docs/guide/campaigns.md and in `lidar_mitsuba.campaign`.")
    c.add_argument("spec", metavar="SPEC.toml", help="the campaign: [campaign], [dem], "
                   "[instrument], [run], [epochs], [orbit], [[tracks]], [surface], [snow]")
    c.add_argument("--out", required=True, metavar="DIR", help="folder for granules/, "
                   "segments.parquet, tasks.parquet and map.png (created if missing; reusing "
                   "it skips the granules already done)")
    c.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler, e.g. "
                   "tcp://host:8786 (its workers must see DIR and the spec's files at the same "
                   "paths; default: a LocalCluster here)")
    c.add_argument("--workers", type=nonnegative_int, metavar="N", help="LocalCluster "
                   "processes (default: the cores; 0: no Dask, one granule after another here)")
    c.add_argument("--threads", type=positive_int, metavar="N", help="Dr.Jit and numba "
                   "threads per granule (default: cores / workers on the LocalCluster)")
    c.add_argument("--retry-failed", action="store_true", help="run the granules recorded as "
                   "failed again")
    c.add_argument("--no-map", action="store_true", help="do not draw map.png")
    c.add_argument("--no-progress", action="store_true", help="no progress bar")

    r = sub.add_parser("make-raster", help="write a property GeoTIFF with a gradient over a "
                       "DEM (e.g. snow grain size for a campaign)",
                       description="Write a GeoTIFF on a DEM's CRS and extent whose value "
                       "rises linearly from --start on one edge to --stop on the opposite one "
                       "along --direction-deg (the campaign demo's grain size: 100 to 1000 um "
                       "from west to east).")
    r.add_argument("--like", required=True, metavar="DEM.tif", help="the DEM it covers")
    r.add_argument("--out", required=True, metavar="FILE.tif", help="GeoTIFF to write")
    r.add_argument("--start", type=float, required=True, help="value on the first edge")
    r.add_argument("--stop", type=float, required=True, help="value on the opposite edge")
    r.add_argument("--direction-deg", type=float, default=90.0, metavar="DEG",
                   help="direction it rises along [deg clockwise from the CRS's +y] (90: +x)")
    r.add_argument("--posting-m", type=float, metavar="M", help="pixel size (the DEM's)")
    r.add_argument("--log", action="store_true", help="rise geometrically, not linearly")


def cmd_campaign(a) -> int:
    """Checks the spec (its tracks and rasters too: :func:`lidar_mitsuba.campaign.run` expands
    it first) and the options before anything is written."""
    from .. import campaign
    if not pathlib.Path(a.spec).is_file():
        raise UsageError("SPEC", f"{a.spec!r} not found")
    if a.scheduler is not None and a.workers is not None:
        raise UsageError("--workers", "does not apply to --scheduler (its workers are started "
                         "there)")
    out = out_dir(a.out)
    try:
        spec = campaign.load_spec(a.spec)
    except campaign.SpecError as e:
        raise spec_error(a.spec, e) from None
    client = connect_scheduler(a.scheduler) if a.scheduler is not None else None
    try:
        res = campaign.run(spec, client, out=out, workers=a.workers, threads=a.threads,
                           retry_failed=a.retry_failed, progress=not a.no_progress,
                           plot=not a.no_map, log=lambda msg: print(msg, flush=True))
    except campaign.SpecError as e:
        raise spec_error(a.spec, e) from None
    except KeyboardInterrupt:
        sys.stderr.write(f"{PROG} campaign: the finished granules are in {out}; run the same "
                         "command again to resume\n")
        raise
    finally:
        if client is not None:
            client.close()
    _report(spec, res, out)
    return 0


def _report(spec, res, out) -> None:
    t = res.tasks
    print(f"{spec.name}: {len(t)} granules, {res.ran} run now, {res.skipped} already done, "
          f"{res.failed} failed; {len(res.segments)} ATL06 segments")
    seg = res.segments
    good = seg[(seg["atl06_quality_summary"] == 0)]
    e = good["error"].to_numpy(float)
    e = e[~(e != e)]
    if e.size > 1:
        print(f"  h_li - truth over {e.size} good segments: mean {100 * e.mean():+.2f} cm, "
              f"std {100 * e.std(ddof=1):.2f} cm")
    print(f"wrote {out / f'segments.{spec.format}'}, {out / f'tasks.{spec.format}'}"
          + (f", {res.map}" if res.map else "") + f" and {out / 'granules'}")
    for _, row in t[t["status"] == "failed"].head(5).iterrows():
        sys.stderr.write(f"{PROG} campaign: warning: granule {row['granule']} failed: "
                         f"{row['error']}\n")


def cmd_make_raster(a) -> int:
    out = out_path(a.out, (".tif", ".tiff"))
    if not pathlib.Path(a.like).is_file():
        raise UsageError("--like", f"{a.like!r} not found")
    for flag, v in (("--start", a.start), ("--stop", a.stop), ("--direction-deg",
                                                               a.direction_deg)):
        if not math.isfinite(v):
            raise UsageError(flag, f"must be a finite number (got {v})")
    if a.posting_m is not None and not (math.isfinite(a.posting_m) and a.posting_m > 0):
        raise UsageError("--posting-m", f"must be > 0 (got {a.posting_m})")
    if a.log and not (a.start > 0 and a.stop > 0):
        raise UsageError("--log", "needs --start and --stop > 0")
    from ..campaign.rasters import gradient_raster
    import tempfile
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:    # no partial file on failure
        t = pathlib.Path(tmp) / out.name
        gradient_raster(t, like=a.like, start=a.start, stop=a.stop,
                        direction_deg=a.direction_deg, posting_m=a.posting_m, log=a.log)
        os.replace(t, out)
    print(f"wrote {out}")
    return 0
