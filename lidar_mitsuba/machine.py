"""What the machine offers a run: the memory it can give (and refusals that name the option
before a run would exhaust it: a one-line error instead of a MemoryError or the kernel's OOM
killer), and the versions of the packages that run it."""
from __future__ import annotations

import os
import sys
from concurrent.futures import ThreadPoolExecutor

from .constants import ParameterError

#: fraction of the available memory a run may plan to use
MEMORY_FRACTION = 0.8


def available_memory_bytes() -> int:
    """Memory available to new allocations [bytes]: ``MemAvailable`` of /proc/meminfo, or the
    free physical pages where that file does not exist."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
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
    cores, or what a sweep task was given) once the renderer is loaded; before that (a pure
    stage, e.g. reading a file and fitting ATL06 segments) the cores."""
    if "drjit" not in sys.modules:
        return _CORES
    import drjit as dr
    return max(1, int(dr.thread_count()))


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
