"""Parameter sweeps on Dask: ``lidar-mitsuba sweep SPEC.toml --out DIR`` and :func:`run`.

A sweep is a grid (or list) of parameters times a number of replicates; each task is one
:func:`~lidar_mitsuba.run.simulate` run reduced to one row of statistics. Tasks run on
Dask distributed: a ``LocalCluster`` on this machine by default, or any running scheduler
(``client=`` / ``--scheduler tcp://...``: a workstation, an HPC cluster through dask-jobqueue,
Kubernetes through dask-kubernetes; its workers need lidar_mitsuba installed and the spec's
scene files at the same paths). ``workers=0`` runs the tasks one after another in this process.

**Spec** (TOML; every section optional but one of ``[fixed]``, ``[grid]``, ``[[list]]``)::

    [sweep]
    name = "roughness"        # default: the file's name
    replicates = 3            # realisations per point: each its own terrain and photons (1)
    seed = 0                  # the sweep's seed: every task's seeds derive from it (0)
    format = "parquet"        # or "csv"

    [fixed]                   # parameters of every task
    beam = "weak"
    shots = 2000

    [grid]                    # the cartesian product of these lists
    p = [1.5, 1.8, 2.0]
    background_mhz = [0.0, 5.0]

    [[list]]                  # explicit points, each crossed with the grid
    surface = "fractal"
    [[list]]
    scene = "../scenes/slope.xml"       # relative to the spec's folder
    params = { slope_deg = 8 }          # the XML's <default> parameters (-D slope_deg=8)

Parameters are the API's names (the CLI's options without ``--``): the fields of
:class:`~lidar_mitsuba.instrument.Instrument` (``beam``, ``background_mhz``, ``dead_time_ns``,
...), of :class:`~lidar_mitsuba.ground.surface.SurfaceSpec` (``surface`` for its kind, ``p``,
``relief_m``, ``size_m``, ``grid_m``, ``terrain_seed``, ``rho_d``, ...), of
:class:`~lidar_mitsuba.track.Track` and :func:`~lidar_mitsuba.run.simulate`'s ``shots``,
``seed``, ``paths_per_shot``, ``max_depth``, ``chunk_shots``, ``crop_to_track``, ``variant``;
``scene`` (an XML file) and ``params.NAME`` (``[grid] params.slope_deg = [0, 4, 8]`` sweeps an
XML parameter). A key belongs to one section; ``slope_deg`` without ``surface`` means the
slope surface, as on the CLI.

**Tasks**: each ``[[list]]`` entry (one empty entry without a list) x each grid point x each
replicate, in that order (``task_index``). ``task_id`` is the first 16 hex digits of the
SHA-256 of the task's parameters, replicate and sweep seed (JSON, sorted keys): the same task
has the same id in any run, which is how a rerun finds what is done.

**Seeds**: a task's photon seed is drawn from ``SeedSequence([sweep seed, task_id])`` and its
``terrain_seed`` from ``SeedSequence([sweep seed, TERRAIN, replicate])``: replicate ``r`` is the
same terrain at every point of the grid (a paired design: differences between points are not
blurred by terrain-to-terrain variation), with its own photons. Neither depends on the order
or the place tasks run in, so a sweep gives the same table on any number of workers. Giving
``seed`` or ``terrain_seed`` as a parameter overrides the derived one.

**Rows**: :data:`COLUMNS` (bias, precision, robust spread, photons per shot, ATL06 ``h_li``
statistics, their standard errors, timings, versions and the exact configuration), plus one
column per parameter of the spec. **Storage** (``out``): ``rows/<task_id>.parquet`` (or
``.csv``), one file per task, written atomically as each task finishes; ``results.parquet``
(or ``.csv``), every task's row in task order, written at the end (and when interrupted);
``spec.json``. A rerun skips the tasks that have a row (failed ones too, unless
``retry_failed``), so an interrupted sweep resumes where it stopped.

**Failures**: a task whose parameters are invalid (checked here before anything runs) or whose
run raises is recorded with ``status`` ``"failed"`` and its one-line ``error``; the others go
on. A spec in which every task is invalid is refused (:class:`SpecError`).

**Threads**: Dr.Jit and numba use every core of a process by default. On a ``LocalCluster``
each task runs with ``cores // workers`` threads (Dr.Jit's ``set_thread_count``, numba's
``set_num_threads``); on another scheduler with the workers' defaults unless ``threads`` is
given. Results do not depend on the thread count.

**Modules**: :mod:`.spec` (loading and expanding specs), :mod:`.task` (one task: its
simulate() keywords, the run, its row; what a worker executes), :mod:`.plot` (the chart);
this file stores rows and drives Dask. Dask, pandas and pyarrow are imported by this package
only, so ``import lidar_mitsuba`` and the other commands do not load them.
"""
from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import pathlib
import sys
import time
from datetime import datetime, timezone

from ..constants import ParameterError
from .spec import Spec, SpecError, Task, expand, load_spec, parameter_names, task_id  # noqa: F401
from .task import COLUMNS, RUN_DEPENDENT, _HEAD, _one_line, _row, _set_threads, build, run_task  # noqa: F401


# --------------------------------------------------------------------------- storage
def _tidy(rows: list[dict], parameters: list[str]):
    """The table: rows in task order, columns head, parameters, then :data:`COLUMNS`; a
    parameter column mixing text and numbers becomes text."""
    import pandas as pd
    cols = list(_HEAD) + [p for p in parameters if p not in COLUMNS] + \
        [c for c in COLUMNS if c not in _HEAD]
    df = pd.DataFrame.from_records(rows, columns=cols)
    df = df.sort_values("task_index", kind="stable").reset_index(drop=True)
    for p in parameters:
        kinds = {type(v) for v in df[p] if v is not None and not (isinstance(v, float)
                                                                  and math.isnan(v))}
        if str in kinds and len(kinds) > 1:
            df[p] = [None if v is None else str(v) for v in df[p]]
    return df


class _Store:
    """``out/rows/<task_id>.<format>``, one file per finished task, and the results table."""

    def __init__(self, out, fmt: str):
        self.out = pathlib.Path(out)
        self.rows = self.out / "rows"
        self.fmt = fmt

    def read(self) -> dict[str, dict]:
        """``{task_id: row}`` of every readable row file (either format)."""
        import pandas as pd
        found = {}
        for f in sorted(self.rows.glob("*.parquet")) + sorted(self.rows.glob("*.csv")):
            try:
                df = pd.read_parquet(f) if f.suffix == ".parquet" else pd.read_csv(f)
                found.setdefault(f.stem, {k: (None if v is pd.NA else v)
                                          for k, v in df.iloc[0].to_dict().items()})
            except Exception:                    # unreadable: the task runs again
                continue
        return found

    def _write(self, df, path: pathlib.Path) -> None:
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        try:
            if self.fmt == "parquet":
                df.to_parquet(tmp, index=False)
            else:
                df.to_csv(tmp, index=False)
            os.replace(tmp, path)
        finally:
            if tmp.exists():
                tmp.unlink()

    def add(self, row: dict) -> None:
        import pandas as pd
        self.put(pd.DataFrame([row]), "rows", row["task_id"])

    def put(self, df, folder: str, key: str) -> pathlib.Path:
        """Write ``df`` to ``out/<folder>/<key>.<format>``, atomically."""
        path = self.out / folder / f"{key}.{self.fmt}"
        path.parent.mkdir(parents=True, exist_ok=True)
        self._write(df, path)
        return path

    def results(self, df, name: str = "results") -> pathlib.Path:
        path = self.out / f"{name}.{self.fmt}"
        self._write(df, path)
        return path


def load(out, spec=None):
    """The table of the rows in folder ``out`` so far (of ``spec``'s tasks, in order, when
    given; else every row there), e.g. to look at a sweep that is still running."""
    if spec is None:
        doc = json.loads((pathlib.Path(out) / "spec.json").read_text())
        spec = load_spec(doc)
    spec = load_spec(spec)
    rows = _Store(out, spec.format).read()
    ids = {t.task_id for t in expand(spec)}
    return _tidy([r for k, r in rows.items() if k in ids], spec.parameters)


# --------------------------------------------------------------------------- the engine
def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


def run(spec, client=None, *, out=None, workers: int | None = None, threads: int | None = None,
        retry_failed: bool = False, progress: bool = False, log=None, _stop_after=None):
    """Run a sweep and return its table (a pandas DataFrame, one row per task, in task order).

    Args:
        spec: a TOML file, a dict of its tables, or a :class:`Spec`.
        client: a ``dask.distributed.Client`` to run on; ``None``: a ``LocalCluster`` of
            ``workers`` processes (one thread each) for the duration of the call.
        out: folder for the rows, ``results.parquet`` and ``spec.json`` (created; reusing it
            resumes: tasks with a row there are not run again). ``None``: nothing written.
        workers: processes of the ``LocalCluster`` (default: the cores); 0: no Dask, the tasks
            run in this process one after another.
        threads: Dr.Jit / numba threads per task (default: cores // workers on a
            ``LocalCluster``, the workers' own setting otherwise).
        retry_failed: run the tasks recorded as failed in ``out`` again.
        progress: a progress bar (stderr).
        log: ``log(message)`` for what happens (the CLI prints it).

    The DataFrame's ``attrs`` hold ``tasks``, ``ran``, ``skipped``, ``failed`` and
    ``results`` (the table's path, or None). Raises :class:`SpecError` for a bad spec.
    """
    spec = load_spec(spec)
    log = log or (lambda msg: None)
    tasks = expand(spec)
    invalid = _invalid_tasks(spec, tasks)
    store = _Store(out, spec.format) if out is not None else None
    ids = {t.task_id for t in tasks}
    rows = _resumed_rows(store, spec, ids, retry_failed=retry_failed)
    todo = [t for t in tasks if t.task_id not in rows]
    ran: list[dict] = []
    if rows:
        log(f"{len(rows)} of {len(tasks)} tasks already done in {out}")

    def record(row):
        if store is not None:
            store.add(row)
        rows[row["task_id"]] = row
        ran.append(row)
        bar.update(1)
        if _stop_after is not None and len(ran) >= _stop_after:
            raise KeyboardInterrupt

    from tqdm.auto import tqdm
    bar = tqdm(total=len(tasks), initial=len(rows), desc=spec.name, unit="task",
               disable=not progress, file=sys.stderr)
    path = None
    try:
        for t in todo:
            if t.task_id in invalid:             # recorded without running
                now = datetime.now(timezone.utc).isoformat()
                record(_row(dataclasses.asdict(t), status="failed",
                            error=_one_line(invalid[t.task_id]), started_at=now,
                            finished_at=now, worker="(not run: invalid parameters)"))
        todo = [t for t in todo if t.task_id not in invalid]
        if todo:
            _execute(todo, client=client, workers=workers, threads=threads, record=record,
                     log=log)
    finally:
        bar.close()
        if store is not None:                    # the table as stored (also when interrupted)
            rows = {k: r for k, r in store.read().items() if k in ids}
        df = _tidy(list(rows.values()), spec.parameters)
        if store is not None:
            path = store.results(df)
    df.attrs.update(tasks=len(tasks), ran=len(ran), skipped=len(tasks) - len(ran),
                    failed=int((df["status"] == "failed").sum()),
                    results=None if path is None else str(path))
    return df


def _invalid_tasks(spec: Spec, tasks: list[Task]) -> dict[str, Exception]:
    """The tasks whose parameters :func:`build` refuses, by task id, with the error each is
    recorded with. When every task is refused nothing would run: raises :class:`SpecError`
    naming the spec's key."""
    invalid: dict[str, Exception] = {}
    for t in tasks:
        try:
            build(t)
        except Exception as e:                   # recorded as the task's error
            invalid[t.task_id] = e
    if len(invalid) == len(tasks):               # nothing would run: refuse, naming the key
        e = next(iter(invalid.values()))
        if not isinstance(e, ParameterError):
            raise SpecError("spec", f"{_one_line(e)} (in every task)")
        given = [k for k in spec.where if k == e.name or k.startswith(e.name + ".")]
        key = f"{spec.where[given[0]]} {given[0]}" if given else e.name
        raise SpecError(key, f"{e.message} (in every task)")
    return invalid


def _resumed_rows(store: _Store | None, spec: Spec, ids: set[str], *, retry_failed: bool
                  ) -> dict[str, dict]:
    """The rows of ``spec``'s tasks (ids ``ids``) already in the store, by task id (the failed
    ones left out with ``retry_failed``), after writing the store's folder and ``spec.json``;
    none without a store."""
    if store is None:
        return {}
    store.out.mkdir(exist_ok=True)
    (store.out / "spec.json").write_text(json.dumps(spec.to_dict(), indent=1) + "\n")
    return {k: r for k, r in store.read().items() if k in ids
            and not (retry_failed and r.get("status") == "failed")}


@contextlib.contextmanager
def local_client(workers: int | None = None, *, log=None):
    """A ``dask.distributed.Client`` on a ``LocalCluster`` of ``workers`` processes (default:
    the cores), one Dask thread each, closed on exit. Yields ``(client, threads)``: the
    Dr.Jit / numba threads each task should use, ``cores // workers``."""
    from dask.distributed import Client, LocalCluster
    n = workers or _cores()
    (log or (lambda msg: None))(f"starting a LocalCluster of {n} worker process{'es' * (n > 1)}")
    with LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        yield client, max(1, _cores() // n)


def compute_all(calls: dict, *, workers: int | None = None, log=None) -> dict:
    """``{key: (result, seconds)}`` of ``{key: fn}`` (functions of no arguments): one after
    another in this process with ``workers`` None or 0, else as tasks on a
    :func:`local_client` of ``workers`` processes. The results do not depend on where they
    ran: the studies that use this (``reproduce --workers``, ``brdf_variants.sweep(workers=)``)
    seed every computation themselves."""
    if not workers:
        return {key: _timed(fn) for key, fn in calls.items()}
    from ..trace.variant import ensure_renderer
    variant = ensure_renderer().variant()
    with local_client(workers, log=log) as (client, threads):
        futures = {key: client.submit(_timed, fn, threads, variant, pure=False)
                   for key, fn in calls.items()}
        return {key: fut.result() for key, fut in futures.items()}


def _timed(fn, threads: int | None = None, variant: str | None = None):
    """``(fn(), seconds)``, with ``threads`` Dr.Jit / numba threads in ``variant``."""
    if variant is not None:
        from ..trace.variant import set_variant
        set_variant(variant)
    _set_threads(threads)
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def _execute(todo: list[Task], *, client, workers, threads, record, log) -> None:
    """Run ``todo`` and ``record`` each row as it finishes (in this process with
    ``workers=0``, else on Dask)."""
    execute([dataclasses.asdict(t) for t in todo], fn=run_task, failed=_failed_row,
            client=client, workers=workers, threads=threads, record=record, log=log)


def _failed_row(payload: dict, error: BaseException) -> dict:
    now = datetime.now(timezone.utc).isoformat()
    return _row(payload, status="failed", error=_one_line(error), started_at=now,
                finished_at=now, worker="?")


def execute(payloads: list[dict], *, fn, failed, client=None, workers: int | None = None,
            threads: int | None = None, record, log=None) -> None:
    """Run ``fn({**payload, "threads": threads})`` for every payload (dicts of plain values)
    and ``record`` each result as it finishes: one after another in this process with
    ``client`` None and ``workers=0``; else as Dask tasks on ``client``, or on a
    :func:`local_client` of ``workers`` processes for the duration of the call (``threads``
    defaulting to cores // workers there). A task whose worker died or that could not be sent
    is recorded as ``failed(payload, exception)``. The engine of sweeps and campaigns
    (:mod:`lidar_mitsuba.campaign`)."""
    if client is None and workers == 0:
        for p in payloads:
            record(fn({**p, "threads": threads}))
        return
    with contextlib.ExitStack() as stack:
        if client is None:
            client, default_threads = stack.enter_context(local_client(workers, log=log))
            threads = threads or default_threads
        _submit(todo=payloads, fn=fn, failed=failed, client=client, threads=threads,
                record=record)


def _submit(*, todo: list[dict], fn, failed, client, threads, record) -> None:
    from dask.distributed import as_completed
    futures = {client.submit(fn, {**p, "threads": threads}, pure=False): p for p in todo}
    try:
        for fut in as_completed(futures):
            try:
                result = fut.result()
            except Exception as e:             # the worker died, or the task could not be sent
                result = failed(futures[fut], e)
            record(result)
    finally:
        client.cancel(list(futures))
