"""Where a warm granule's wall time goes (issue 43): the timeline of bench's granule row's
second granule, on both of its processes.

``python -m lidar_mitsuba.studies.granule_timeline DEM KM`` runs the six-beam granule of
:mod:`lidar_mitsuba.studies.track_length` twice in one process, as a campaign's worker does,
and prints one JSON line of the second (warm) granule's :func:`summary`: the head (the
granule's start to its first trace on the launcher thread), the launcher's busy and idle
time and its idle gap at each section boundary, the simulating thread's CPU, the writer
process's waits, work and close, and the tail (the last section handed to the writer to both
files closed). ``--events PATH`` also writes every event (JSON).

Each event is ``(label, "b" or "e", time [s], thread CPU [s], process id, thread name)``:
``time.perf_counter`` (``CLOCK_MONOTONIC`` on Linux, one clock for both processes) and
``time.thread_time`` at the begin and end of the functions :func:`install` wraps: a beam's
section on the simulating thread (``section``, with the section and beam), each trace
launched and fetched on the launcher thread (``trace``), a section handed to the writer
(``handed``) and the close waited for (``close_wait``); in the writer process its waits for
the pipe (``receive``), each section written (``written``) and the files' close (``close``).
The writer's events come back through a file it writes at the close (a forked writer only:
one started afresh has none). The wrappers cost a few microseconds an event (~500 events a
granule), nothing against the granule's seconds.
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import pathlib
import tempfile
import threading
import time

_EVENTS: list = []
_WRITER_FILE: list = [None]


def _mark(label: str, what: str) -> None:
    _EVENTS.append((label, what, time.perf_counter(), time.thread_time(), os.getpid(),
                    threading.current_thread().name))


def _wrap(owner, name: str, label, *, after=None) -> None:
    """``owner.name`` marked at its begin and end as ``label`` (a string, or a function of
    the call's arguments giving it); ``after``: called after the end's mark."""
    real = getattr(owner, name)

    @functools.wraps(real)
    def marked(*args, **kw):
        lab = label if isinstance(label, str) else label(*args, **kw)
        _mark(lab, "b")
        try:
            return real(*args, **kw)
        finally:
            _mark(lab, "e")
            if after is not None:
                after()
    setattr(owner, name, marked)


def _dump_writer() -> None:
    """In the writer process, after a granule's close: its events, for the parent."""
    if _WRITER_FILE[0] is not None and os.getpid() != _WRITER_FILE[0][1]:
        pathlib.Path(_WRITER_FILE[0][0]).write_text(json.dumps(_EVENTS))
        _EVENTS.clear()


def install(writer_file: str | os.PathLike) -> None:
    """Wrap the granule's functions (call before the writer process is forked, so that it
    inherits the wrappers: before :func:`lidar_mitsuba.startup.granule_process`); the writer
    writes its events to ``writer_file`` at each close."""
    from .. import granule, granule_writer
    _WRITER_FILE[0] = (str(writer_file), os.getpid())
    _wrap(granule._BeamStream, "section",
          lambda self, k, *a, **kw: f"section:{k}:{self.beam.name}")
    _wrap(granule_writer.WriterProcess, "section", "handed")
    _wrap(granule_writer.WriterProcess, "close", "close_wait")
    _wrap(granule_writer, "_receive", "receive")
    _wrap(granule_writer.GranuleFiles, "section",
          lambda self, run, **kw: f"written:{run.beam.name}")
    _wrap(granule_writer.GranuleFiles, "close", "close", after=_dump_writer)


def install_launcher() -> None:
    """Wrap each trace's task on the launcher thread (after the renderer's set-up: the
    trace's modules load Dr.Jit)."""
    from ..trace import stream

    def on(launcher, launch):            # (as stream._on, the task marked)
        def marked(a: int, b: int, seed: int):
            def task():
                _mark("trace", "b")
                try:
                    return launch(a, b, seed).result()
                finally:
                    _mark("trace", "e")
            return launcher.submit(task)
        return marked
    stream._on = on


def _spans(events: list) -> dict:
    """``{label: [(begin, end, cpu), ...]}`` from begin/end events (per process and thread),
    in order of their begin."""
    open_, out = {}, {}
    for label, what, t, cpu, pid, thread in sorted(events, key=lambda e: e[2]):
        key = (label, pid, thread)
        if what == "b":
            open_[key] = (t, cpu)
        elif key in open_:
            t0, c0 = open_.pop(key)
            out.setdefault(label, []).append((t0, t, cpu - c0))
    return out


def summary(events: list, *, t0: float, t1: float) -> dict:
    """The timeline of one granule that ran from ``t0`` to ``t1`` [s, ``perf_counter``] from
    its ``events`` (both processes'; see the module docstring); times [s] from ``t0``."""
    spans = _spans(events)
    traces = spans.get("trace", [])
    sections = sorted((s, label) for label, v in spans.items() if label.startswith("section:")
                      for s in v)
    busy = sum(e - b for b, e, _ in traces)
    gaps = []
    for (b, _, _), _label in sections[1:]:     # the launcher idle across each boundary
        before = [e for _, e, _ in traces if e <= b]
        after = [s for s, _, _ in traces if s >= b]
        if before and after:
            gaps.append(round(after[0] - before[-1], 4))
    handed = spans.get("handed", [])
    closed = spans.get("close_wait", [])
    writer = {k: spans.get(k, []) for k in ("receive", "close")}
    written = sorted(s for label, v in spans.items() if label.startswith("written:")
                     for s in v)
    out = {
        "seconds": t1 - t0,
        "head_s": traces[0][0] - t0 if traces else None,
        "launcher_busy_s": busy, "launcher_cpu_s": sum(c for *_, c in traces),
        "launcher_idle_s": (traces[-1][1] - traces[0][0] - busy) if traces else None,
        "boundary_gaps_s": gaps,
        "simulating_cpu_s": sum(s[2] for s, _ in sections),
        "last_trace_end_s": traces[-1][1] - t0 if traces else None,
        "tail_s": closed[-1][1] - handed[-1][1] if handed and closed else None,
        "writer_wait_s": sum(e - b for b, e, _ in writer["receive"]) if written else None,
        "writer_busy_s": sum(e - b for b, e, _ in written) if written else None,
        "writer_cpu_s": sum(c for *_, c in written) if written else None,
        "writer_first_section_s": written[0][0] - t0 if written else None,
        "writer_close_s": writer["close"][-1][1] - writer["close"][-1][0]
        if writer["close"] else None,
        "sections": [{"section": label.split(":", 1)[1], "start_s": round(b - t0, 4),
                      "end_s": round(e - t0, 4), "cpu_s": round(c, 4)}
                     for (b, e, c), label in sections]}
    return out


def measure(dem_path: str, length_km: float) -> tuple[dict, list]:
    """The second of two six-beam granules in this process (call in a fresh one) over
    ``dem_path`` for ``length_km``: ``(summary, events)``."""
    from . import track_length as tl
    writer_file = pathlib.Path(tempfile.gettempdir()) / f"granule_timeline_{os.getpid()}.json"
    install(writer_file)
    from ..startup import granule_process
    granule_process()
    install_launcher()
    from ..ground import dem
    surf = dem.DEMSurface(dem.DEM.open(dem_path))
    shots = int(round(length_km * 1e3 / 0.7))
    for _ in range(2):                 # a worker's first granule, then the one reported
        _EVENTS.clear()
        writer_file.unlink(missing_ok=True)
        t0 = time.perf_counter()
        tl._granule(surf, tl.ice_sheet_track(), shots, "all", count_kernels=False)
        t1 = time.perf_counter()
    events = list(_EVENTS)
    if writer_file.exists():
        events += json.loads(writer_file.read_text())
        writer_file.unlink()
    return summary(events, t0=t0, t1=t1), events


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("dem")
    ap.add_argument("km", type=float)
    ap.add_argument("--events", type=pathlib.Path, default=None)
    a = ap.parse_args()
    from ..startup import own_process
    own_process()
    row, evs = measure(a.dem, a.km)
    if a.events is not None:
        a.events.write_text(json.dumps(evs))
    print(json.dumps(row))
