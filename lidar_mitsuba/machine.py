"""What the machine offers a run: the memory it can give (and refusals that name the option
before a run would exhaust it: a one-line error instead of a MemoryError or the kernel's OOM
killer), and the versions of the packages that run it."""
from __future__ import annotations

import contextlib
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor

from .constants import ParameterError

#: fraction of the available memory a run may plan to use
MEMORY_FRACTION = 0.8


#: seconds a reading of /proc/meminfo is reused (a DEM granule checks ~1 000 windows and
#: tiles: 0.15 ms a reading, ~0.15 s a granule). ESTIMATE: what runs here allocates far less
#: than a machine's memory in a quarter of a second.
MEMINFO_MAX_AGE_S = 0.25
_meminfo: list = [-1.0, 0]          # (monotonic time, bytes) of the last reading


def available_memory_bytes() -> int:
    """Memory available to new allocations [bytes]: ``MemAvailable`` of /proc/meminfo (read
    at most every :data:`MEMINFO_MAX_AGE_S`), or the free physical pages where that file does
    not exist."""
    now = time.monotonic()
    if now - _meminfo[0] < MEMINFO_MAX_AGE_S:
        return _meminfo[1]
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    _meminfo[:] = [now, int(line.split()[1]) * 1024]
                    return _meminfo[1]
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 2 ** 62          # unknown: do not refuse


_pool: tuple[tuple[int, int], ThreadPoolExecutor] | None = None
_CORES = max(1, os.cpu_count() or 1)     # (asked once: a writer process asks per chunk)


def host_threads() -> int:
    """Threads the host may use: as many as Dr.Jit's own pool (``dr.thread_count()``: the
    cores, or what a sweep task was given) once the renderer is loaded, the pool's count
    before :func:`trace_threads` narrowed it; before that (a pure stage, e.g. reading a file
    and fitting ATL06 segments) the cores."""
    if _granted[0] is not None:
        return _granted[0]
    if "drjit" not in sys.modules:
        return _CORES
    import drjit as dr
    return max(1, int(dr.thread_count()))


#: cores a streamed granule keeps from Dr.Jit's pool for its host work (:func:`trace_threads`).
#: ESTIMATE from the per-thread accounting of issue 43 (docs/guide/campaigns.md): beside the
#: trace, a granule keeps the simulating thread and its writer process busy; nanothread's
#: idle workers spin for work between kernels (~2 s of CPU a six-beam 100 km granule on 2
#: cores with 2 workers, ~0.1 s with 1), CPU those two threads need.
HOST_CORES_KEPT = 1
_granted: list = [None]     # Dr.Jit's thread count before trace_threads() narrowed it


@contextlib.contextmanager
def trace_threads(keep: int | None = None):
    """Dr.Jit's pool narrowed by ``keep`` threads (default :data:`HOST_CORES_KEPT`; at least
    one left) for the block, then restored; :func:`host_pool` keeps the count it had. Nested:
    the outer scope's count. (With one thread, Dr.Jit's LLVM backend runs each kernel in the
    thread that launches it.)"""
    from .trace.variant import ensure_renderer
    ensure_renderer()
    import drjit as dr
    before = int(dr.thread_count())
    n = max(1, before - int(HOST_CORES_KEPT if keep is None else keep))
    if _granted[0] is not None or n == before:
        yield
        return
    _granted[0] = before
    dr.set_thread_count(n)
    try:
        yield
    finally:
        dr.set_thread_count(before)
        _granted[0] = None


_launcher: list = [None]    # the thread trace_launcher() gives


def trace_launcher() -> ThreadPoolExecutor | None:
    """Within :func:`trace_threads` narrowed to one thread (Dr.Jit's LLVM backend then runs
    each kernel in the thread that launches it), a thread of its own for launching and
    fetching traces, so that they overlap the host's detection as the pool's workers would
    (Dr.Jit releases the GIL while a kernel runs); else ``None``. One per process."""
    if _granted[0] is None or "drjit" not in sys.modules:
        return None
    import drjit as dr
    if int(dr.thread_count()) != 1:
        return None
    if _launcher[0] is None or _launcher[0][0] != os.getpid():
        _launcher[0] = (os.getpid(), ThreadPoolExecutor(1, thread_name_prefix="lidar-trace"))
    return _launcher[0][1]


def host_pool() -> ThreadPoolExecutor:
    """A pool of :func:`host_threads` threads for host work that runs without the GIL (zlib,
    ``nogil`` numba kernels), made anew when that number changes or in a forked child."""
    global _pool
    key = (os.getpid(), host_threads())
    if _pool is None or _pool[0] != key:
        if _pool is not None and _pool[0][0] == key[0]:
            _pool[1].shutdown(wait=False)
        _pool = (key, ThreadPoolExecutor(max_workers=key[1], thread_name_prefix="lidar-host"))
    return _pool[1]


def check_memory(name: str, need_bytes: float, what: str, hint: str) -> None:
    """Raise :class:`ParameterError` naming ``name`` when ``need_bytes`` exceeds
    ``MEMORY_FRACTION`` of the available memory. ``what`` says what needs it, ``hint`` what
    to do instead."""
    have = available_memory_bytes()
    if need_bytes > MEMORY_FRACTION * have:
        raise ParameterError(name, f"{what} needs about {_gb(need_bytes)} of memory and "
                             f"{_gb(have)} is available; {hint}")


def _gb(n: float) -> str:
    return f"{n / 2 ** 30:.1f} GB" if n >= 2 ** 28 else f"{n / 2 ** 20:.0f} MB"


def versions() -> dict[str, str]:
    """``{"lidar_mitsuba": ..., "mitsuba": ..., "drjit": ...}`` as installed ("?" if absent)."""
    from importlib import metadata

    from . import __version__
    out = {"lidar_mitsuba": __version__}
    for pkg in ("mitsuba", "drjit"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "?"
    return out
