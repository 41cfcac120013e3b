"""Speed of the sweep engine on this machine: ``python scripts/bench_sweep.py [--out FILE.json]``.

* Scheduling overhead per task: no-op tasks on a 2-worker LocalCluster, (a) one at a time
  (submit, wait, result: the round trip) and (b) 200 at once (wall / 200), against calling the
  function here; and the cost of writing one row's part file (Parquet).
* Speed-up: a sweep of 8 tasks of ~3 s (weak beam, 40 000 shots over the 1024 m p-fractal,
  4 values of p x 2 replicates) with no Dask (in this process), 1 worker (2 threads) and
  2 workers (1 thread each: the default; and 2 threads each, oversubscribed, for comparison).
  Wall time of ``sweep.run`` including the cluster's start, and the span of the tasks
  (first start to last end, from the rows).

Medians of ``--repeats`` runs (3). Every configuration gives the same table (checked).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from datetime import datetime

from lidar_mitsuba import sweep

SPEC = {"sweep": {"name": "bench", "replicates": 2},
        "fixed": {"beam": "weak", "shots": 40000},
        "grid": {"p": [1.6, 1.8, 2.0, 2.2]}}


def noop(i):
    return i


def overhead(n: int = 200, repeats: int = 3) -> dict:
    from dask.distributed import Client, LocalCluster, as_completed
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        client.submit(noop, -1, pure=False).result()                      # warm
        t = time.perf_counter()
        for i in range(n):
            noop(i)
        local = (time.perf_counter() - t) / n
        trips, batch = [], []
        for _ in range(repeats):
            t = time.perf_counter()
            for i in range(50):
                client.submit(noop, i, pure=False).result()
            trips.append((time.perf_counter() - t) / 50)
            t = time.perf_counter()
            for f in as_completed([client.submit(noop, i, pure=False) for i in range(n)]):
                f.result()
            batch.append((time.perf_counter() - t) / n)
    row = sweep.run_task(sweep.expand({"fixed": {"surface": "flat", "shots": 10}})[0].__dict__)
    with tempfile.TemporaryDirectory() as d:
        store = sweep._Store(d, "parquet")
        store.add(row)
        t = time.perf_counter()
        for i in range(20):
            store.add(dict(row, task_id=f"{i:016x}"))
        write = (time.perf_counter() - t) / 20
    return {"local_call_s": local, "round_trip_s": statistics.median(trips),
            "batch_per_task_s": statistics.median(batch), "row_write_s": write}


def speedup(repeats: int = 3) -> dict:
    """Each repeat runs every configuration once (interleaved, so that the load of a shared
    machine drifts over all of them alike)."""
    configs = {"no Dask (this process)": dict(workers=0), "1 worker x 2 threads": dict(
        workers=1, threads=2), "2 workers x 1 thread": dict(workers=2),
        "2 workers x 2 threads": dict(workers=2, threads=2)}
    walls = {k: [] for k in configs}
    spans = {k: [] for k in configs}
    tasks = {k: [] for k in configs}
    reference = None
    for _ in range(repeats):
        for name, kw in configs.items():
            t = time.perf_counter()
            df = sweep.run(SPEC, **kw)
            walls[name].append(time.perf_counter() - t)
            start = min(map(datetime.fromisoformat, df["started_at"]))
            end = max(map(datetime.fromisoformat, df["finished_at"]))
            spans[name].append((end - start).total_seconds())
            tasks[name].append(float(df["task_s"].median()))
            cols = [c for c in df.columns if c not in sweep.RUN_DEPENDENT]
            if reference is None:
                reference = df[cols]
            assert df[cols].equals(reference), name
            print(name, round(walls[name][-1], 2), round(spans[name][-1], 2), flush=True)
    return {k: {"wall_s": statistics.median(walls[k]), "tasks_span_s": statistics.median(
        spans[k]), "task_s_median": statistics.median(tasks[k]), "walls_s": walls[k]}
        for k in configs}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="JSON file for the numbers")
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    doc = {"cores": len(os.sched_getaffinity(0)), "load_before": os.getloadavg()}
    doc["overhead"] = overhead(repeats=a.repeats)
    print("overhead", doc["overhead"], flush=True)
    doc["speedup"] = speedup(repeats=a.repeats)
    doc["load_after"] = os.getloadavg()
    s = doc["speedup"]
    one, two = s["1 worker x 2 threads"], s["2 workers x 1 thread"]
    doc["speedup_2_vs_1_worker"] = {"wall": one["wall_s"] / two["wall_s"],
                                    "tasks_span": one["tasks_span_s"] / two["tasks_span_s"]}
    print(json.dumps(doc["speedup_2_vs_1_worker"]))
    if a.out:
        with open(a.out, "w") as fh:
            json.dump(doc, fh, indent=1)


if __name__ == "__main__":
    main()
