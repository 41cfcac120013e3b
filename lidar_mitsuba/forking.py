"""A helper process forked from this one, where that is safe (issue 43's cold start).

A process started afresh (``python -m ...``) imports everything again: numpy, numba, h5py,
scipy.special, our package (~0.75 s of CPU) and numba's first dispatch (its target context
and the first kernel from the cache, ~0.3 s), all of which the process that starts it has
already paid. A child *forked* from it inherits them (copy-on-write pages: what neither
writes stays shared). :func:`fork` does that, when :func:`refusal` finds nothing that makes a
fork unsafe; the caller falls back to a fresh interpreter otherwise.

Why a fork is refused (POSIX's ``fork`` copies only the calling thread: a lock another thread
held, or a pool's state, is copied as it was and never released in the child):

- not Linux (macOS's system frameworks are not fork-safe; Windows has no fork);
- any other Python thread alive (a Dask worker's, a campaign's, our own feeder or loader
  threads), or the call not on the main thread;
- native threads beyond OpenBLAS's pools (counted in ``/proc/self/task``): OpenBLAS, which
  numpy and scipy each load, starts ``n - 1`` workers at import and stops them before a fork
  (its own ``pthread_atfork`` handler), so those are counted and allowed; any other native
  thread is unknown and refuses the fork;
- Dr.Jit imported (its thread pool, LLVM's state: the renderer is set up after the fork);
- numba's threading layer launched (its workers are native threads with shared queues);
- an HDF5 file open (the child would hold its handle and HDF5's state of it);
- pyproj imported (its import opens PROJ's database, SQLite, which must not be used from
  both sides of a fork: the writer child uses PROJ).
"""
from __future__ import annotations

import contextlib
import ctypes
import os
import subprocess
import sys
import threading
import time
import traceback

#: OpenBLAS's ``get_num_threads`` under the names numpy's and scipy's builds export
_OPENBLAS_THREADS = ("openblas_get_num_threads", "openblas_get_num_threads64_",
                     "scipy_openblas_get_num_threads", "scipy_openblas_get_num_threads64_")


def refusal() -> str | None:
    """Why forking this process now would not be safe (every reason found, ``"; "``-joined),
    or ``None`` when it is (the module docstring lists what is checked)."""
    if not sys.platform.startswith("linux") or not hasattr(os, "fork"):
        return "forks only on Linux"
    reasons = []
    if threading.current_thread() is not threading.main_thread():
        reasons.append("not on the main thread")
    others = [t.name for t in threading.enumerate() if t is not threading.current_thread()]
    if others:
        reasons.append(f"other threads are alive ({', '.join(others)})")
    if "drjit" in sys.modules:
        reasons.append("Dr.Jit is loaded (its thread pool and LLVM)")
    parallel = sys.modules.get("numba.np.ufunc.parallel")
    if parallel is not None and getattr(parallel, "_is_initialized", False):
        reasons.append("numba's threading layer is running")
    if "pyproj" in sys.modules:
        reasons.append("pyproj is loaded (PROJ's database, an SQLite file, is open: a "
                       "connection must not cross a fork)")
    h5py = sys.modules.get("h5py")
    if h5py is not None and h5py.h5f.get_obj_count(h5py.h5f.OBJ_ALL, h5py.h5f.OBJ_FILE):
        reasons.append("an HDF5 file is open")
    unknown = _native_threads() - len(threading.enumerate()) - _openblas_workers()
    if unknown > 0:
        reasons.append(f"{unknown} native thread(s) other than Python's and OpenBLAS's")
    return "; ".join(reasons) or None


def _native_threads() -> int:
    """This process's threads, as the kernel counts them (every native thread)."""
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:                     # (unknown: as many as refuse a fork)
        return 1 << 30


def _openblas_workers() -> int:
    """The worker threads of every OpenBLAS loaded in this process (``num_threads - 1``
    each); a loaded OpenBLAS whose thread count cannot be read counts as none (its workers
    then refuse the fork as unknown)."""
    with open("/proc/self/maps") as f:
        paths = {ln.split()[-1] for ln in f if "openblas" in ln.lower()}
    workers = 0
    for path in sorted(p for p in paths if p.startswith("/")):
        try:
            lib = ctypes.CDLL(path, mode=getattr(os, "RTLD_NOLOAD", 0))
        except OSError:
            continue
        for name in _OPENBLAS_THREADS:
            fn = getattr(lib, name, None)
            if fn is not None:
                workers += max(int(fn()) - 1, 0)
                break
    return workers


class Forked:
    """A forked child (:func:`fork`): the part of :class:`subprocess.Popen` that its parent
    uses (``pid``, ``returncode``, :meth:`poll`, :meth:`wait`)."""

    def __init__(self, pid: int):
        self.pid, self.returncode = pid, None

    def poll(self) -> int | None:
        """Its exit code when it has ended (reaped), else ``None``."""
        if self.returncode is None:
            self._reap(os.WNOHANG)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        """Wait for its end (at most ``timeout`` [s]: :class:`subprocess.TimeoutExpired`)."""
        if timeout is None:
            while self.returncode is None:
                self._reap(0)
            return self.returncode
        deadline = time.monotonic() + timeout
        while self.poll() is None:
            if time.monotonic() > deadline:
                raise subprocess.TimeoutExpired(f"forked child {self.pid}", timeout)
            time.sleep(0.005)
        return self.returncode

    def _reap(self, flags: int) -> None:
        try:
            pid, status = os.waitpid(self.pid, flags)
        except ChildProcessError:           # (reaped elsewhere: its code is unknown)
            self.returncode = -1
            return
        if pid:
            self.returncode = os.waitstatus_to_exitcode(status)


def fork(target, *args, close: tuple[int, ...] = ()) -> Forked:
    """Fork this process (call only when :func:`refusal` is ``None``); the child closes the
    file descriptors ``close`` (the parent's ends of its pipes), reads its standard input
    from ``/dev/null`` (as a ``Popen`` with ``stdin=DEVNULL``), runs ``target(*args)`` and
    ends with ``os._exit`` (0, or 1 after printing an exception's traceback): never returning
    to the caller's code, running no ``atexit`` handler and flushing none of the parent's
    buffers (flushed here before the fork)."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    pid = os.fork()
    if pid:
        return Forked(pid)
    code = 1
    try:                                    # the child
        for fd in close:
            os.close(fd)
        devnull = os.open(os.devnull, os.O_RDONLY)
        os.dup2(devnull, 0)
        os.close(devnull)
        target(*args)
        code = 0
    except KeyboardInterrupt:               # (the terminal's interrupt reaches both)
        pass
    except BaseException:                   # noqa: BLE001 (nothing may return from here)
        with contextlib.suppress(BaseException):
            traceback.print_exc()
    finally:
        with contextlib.suppress(BaseException):
            sys.stderr.flush()
        os._exit(code)
