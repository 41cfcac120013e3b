"""A streamed granule's ATL03 and ATL06 files, written beside the simulation (issue 43).

:class:`GranuleFiles` holds the two files of one granule open and appends each section as
it comes: its ATL03 rows (:func:`lidar_mitsuba.products.atl03.beam.write_beam`) and its ATL06
fit (:class:`lidar_mitsuba.granule_products._Fits`, on a thread of its own); both files are
written atomically (a failure leaves neither).

:class:`WriterProcess` runs a :class:`GranuleFiles` in a process of its own, so the
simulating thread never waits for HDF5 nor shares its interpreter lock with the writer (a
writer *thread* gained nothing: the layout and the tracer's host work hold the GIL that
HDF5's Python side needs). A section goes to it as a pickle (protocol 5: the arrays travel
out of band, each one copy through a pipe, ~30 MB a six-beam section of 65 536 shots) from a
feeder thread, at most :data:`MAX_QUEUED` sections waiting (memory stays a few sections);
errors come back with the next section or at the close. The process lives as long as the
process that started it (:func:`writer`: one per process, reused granule after granule, so
a campaign worker pays its start, ~1 s of imports, once); the files are the same to the bit
as those written in the simulating process (``tests/test_granule.py``).

The process is *forked* from the simulating one where that is safe
(:func:`lidar_mitsuba.forking.refusal`: Linux, no other thread, Dr.Jit and pyproj not
loaded, no HDF5 file open), as ``simulate --dem`` and bench's granule row start it, right
after their imports: the child inherits the imports and numba's start
(:func:`~lidar_mitsuba.precompile.start_numba`, run just before the fork) instead of paying
them again (~1.1 s of CPU).
Elsewhere (a Dask worker's threads, a process whose renderer is set up, not Linux) it is a
fresh interpreter, ``python -m lidar_mitsuba.granule_writer``. Both serve the same pipes.
"""
from __future__ import annotations

import contextlib
import gc
import os
import pathlib
import pickle
import queue
import subprocess
import sys
import threading
import traceback
from multiprocessing.connection import Connection

import numpy as np

from . import forking
from .startup import frozen_start

#: sections waiting for the writer process before the simulating thread waits
MAX_QUEUED = 2
#: ``"process"``, ``"inline"`` (in the simulating thread) or ``"auto"`` (a process on POSIX)
WRITER = os.environ.get("LIDAR_MITSUBA_WRITER", "auto")


class GranuleFiles:
    """The ATL03 (and ATL06, when ``atl06_path`` is given) file of one streamed granule: the
    headers written on opening (``meta``: the :class:`~lidar_mitsuba.products.record.Granule`
    without beams; ``instruments``: ``[(beam, Instrument)]``; ``t_first``, ``t_last`` [s since
    the SDP epoch]), then :meth:`section` per section, then :meth:`close` (or :meth:`abort`)."""

    def __init__(self, *, meta, instruments, t_first: float, t_last: float, atl03_path,
                 atl06_path, sc_orient: int, segment_options: dict, beams):
        from . import granule_products as products
        from .products.atl03 import atomic_h5file
        self.products, self.sc_orient, self.fits = products, int(sc_orient), None
        self.stack = contextlib.ExitStack()
        try:
            self.f3 = self.stack.enter_context(atomic_h5file(atl03_path))
            products._atl03_header(self.f3, meta, instruments, t_first, t_last, path=atl03_path)
            if atl06_path is not None:
                f6 = self.stack.enter_context(atomic_h5file(atl06_path))
                products._atl06_header(f6, meta, instruments, t_first, t_last, path=atl06_path,
                                      atl03_path=atl03_path)
                self.fits = self.stack.enter_context(products._Fits(f6, sc_orient))
        except BaseException:
            self.abort()
            raise
        self.segments = {b.name: products._SegmentStream(dict(segment_options)) for b in beams}

    def section(self, run, *, replanned: bool, last: bool) -> None:
        """Append one section (a :class:`~lidar_mitsuba.products.record.BeamRun`) to ATL03
        and hand it to the ATL06 fits (``last``: the beam's last section)."""
        self.products._beam_atl03(self.f3, run, self.sc_orient, replanned=replanned)
        if self.fits is not None:
            self.fits.submit(run.beam, self.segments[run.beam.name], run, last=last)
            self.fits.write()

    def close(self) -> None:
        """Write the last fits and close both files (renamed into place)."""
        try:
            if self.fits is not None:
                self.fits.write(wait=True)
        except BaseException:
            self.abort()
            raise
        self.stack.close()

    def abort(self) -> None:
        """Close both files as failed: neither is left."""
        exc = RuntimeError("the granule was not finished")
        self.stack.__exit__(type(exc), exc, None)


class WriterError(RuntimeError):
    """The writer process failed (its traceback is the message)."""


class WriterProcess:
    """A :class:`GranuleFiles` in a process of its own (see the module docstring): the same
    methods, called from the simulating thread, which waits only when :data:`MAX_QUEUED`
    sections are already waiting, and at :meth:`close`."""

    def __init__(self, *, fork: bool = True):
        #: why the process was started afresh rather than forked (``None``: forked)
        self.refusal = forking.refusal() if fork else "not asked to fork"
        if self.refusal is None:          # the child inherits this process's imports
            from . import precompile      # and numba's start (the child's ATL06 fit needs it)
            if precompile.start_numba():
                self.refusal = forking.refusal()      # (still safe: it started no thread)
        self.forked = self.refusal is None
        r_child, w_parent = os.pipe()             # parent -> child
        _widen(w_parent)
        r_parent, w_child = os.pipe()             # child -> parent
        if self.forked:
            self.proc = forking.fork(_serve_fds, r_child, w_child, close=(w_parent, r_parent))
        else:                             # a fresh interpreter, which imports them again
            root = str(pathlib.Path(__file__).resolve().parents[1])
            env = dict(os.environ, PYTHONPATH=os.pathsep.join(
                [root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "lidar_mitsuba.granule_writer", str(r_child),
                 str(w_child)], pass_fds=(r_child, w_child), env=env, stdin=subprocess.DEVNULL)
        os.close(r_child)
        os.close(w_child)
        self.owner = os.getpid()
        self.out = Connection(w_parent, readable=False)
        self.back = Connection(r_parent, writable=False)
        self.jobs: queue.Queue = queue.Queue(maxsize=MAX_QUEUED)
        self.failed: BaseException | None = None      # the feeder's (a broken pipe)
        self.error = None                  # (exception, traceback) the child sent
        self.feeder = threading.Thread(target=self._feed, name="lidar-writer-feed", daemon=True)
        self.feeder.start()

    def alive(self) -> bool:
        """Usable by this process (not a forked child's copy, nor ended, nor cut off)."""
        return (self.owner == os.getpid() and self.proc.poll() is None
                and self.failed is None)

    def _feed(self) -> None:
        while True:
            item = self.jobs.get()
            if item is None:
                return
            try:
                _send(self.out, item)
            except BaseException as e:     # (a broken pipe: the child died)
                self.failed = e

    def _put(self, kind: str, payload) -> None:
        if self.failed is not None:
            raise WriterError(f"the writer process is gone ({self.failed!r})")
        self.jobs.put((kind, payload))

    def _read(self, *, until_done: bool) -> None:
        """Read the child's messages (an ``error`` it sent when a section failed; ``ok`` or
        ``done`` answering a close or abort): all that wait, or (``until_done``) up to the
        answer."""
        while until_done or self.back.poll():
            try:
                kind, value = self.back.recv()
            except EOFError:
                raise WriterError(f"the writer process ended (exit code "
                                  f"{self.proc.wait()})") from None
            if kind == "error":
                self.error = value
            elif until_done:
                return

    def _raise(self) -> None:
        if self.error is not None:
            (exc, text), self.error = self.error, None
            if isinstance(exc, BaseException):
                raise exc from WriterError(text)
            raise WriterError(text)

    def open(self, **files) -> None:
        self.error = None
        self._put("open", {**files, "cwd": os.getcwd()})   # (relative paths are the caller's)

    def section(self, run, *, replanned: bool, last: bool) -> None:
        self._read(until_done=False)      # a failed section: stop the granule now
        self._raise()
        self._put("section", (run, replanned, last))

    def close(self) -> None:
        self._put("close", None)
        self._read(until_done=True)
        self._raise()

    def abort(self) -> None:
        """Drop the granule's files (its simulation failed); the process stays usable."""
        if self.alive():
            self.jobs.put(("abort", None))
            with contextlib.suppress(Exception):
                self._read(until_done=True)
        self.error = None

    def stop(self) -> None:
        self.jobs.put(None)
        with contextlib.suppress(OSError):
            self.out.close()
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(timeout=10)


#: the sections' pipe's buffer [bytes] (Linux's default 64 KiB: a ~18 MB section crossed it
#: in ~300 writes and as many wake-ups of the writer; 1 MiB, Linux's default limit for a
#: user, cut the CPU of sending a granule's sections by ~15 % and of receiving them by ~20 %)
PIPE_BYTES = 1 << 20


def _widen(fd: int) -> None:
    """Give the pipe of ``fd`` a :data:`PIPE_BYTES` buffer where the system allows it."""
    with contextlib.suppress(ImportError, AttributeError, OSError):  # (not Linux, or over
        import fcntl                                                # its limit)
        fcntl.fcntl(fd, fcntl.F_SETPIPE_SZ, PIPE_BYTES)


def _send(conn: Connection, item) -> None:
    """Pickle ``item`` (protocol 5) and send it, its contiguous arrays out of band: their
    sizes with the pickle, then their bytes as they are (:func:`_receive` reads them)."""
    buffers: list = []
    head = pickle.dumps(item, protocol=5, buffer_callback=buffers.append)
    raws = [b.raw() for b in buffers]
    conn.send((len(head), [r.nbytes for r in raws]))
    conn.send_bytes(head)
    fd = conn.fileno()
    for view in raws:                 # (one-dimensional bytes: PickleBuffer.raw)
        while view.nbytes:
            view = view[os.write(fd, view):]


def _receive(conn: Connection):
    """What :func:`_send` sent: each array's bytes read straight into an array of its own
    (``Connection.recv_bytes_into`` read each message into an ``io.BytesIO`` first, from
    ``os.read``'s ``bytes``, and copied it out: ~3 copies more of a granule's ~170 MB than
    the pipe's one); writable, as the arrays were, and not zero-filled first."""
    _, sizes = conn.recv()
    head = conn.recv_bytes()
    fd = conn.fileno()
    buffers = []
    for n in sizes:
        b = np.empty(n, np.uint8)
        with memoryview(b) as view:
            while view.nbytes:
                got = os.readv(fd, [view])
                if not got:
                    raise EOFError("the pipe closed within a section")
                view = view[got:]
        buffers.append(b)
    return pickle.loads(head, buffers=buffers)


_WRITER: list = [None]


def writer(mode: str | None = None):
    """This process's :class:`WriterProcess` (started on first use, reused by every later
    granule), or ``None`` to write in the simulating thread (``mode`` ``"inline"``, or
    ``"auto"`` where processes cannot be started so: not POSIX). ``mode`` defaults to
    :data:`WRITER` (the environment's ``LIDAR_MITSUBA_WRITER``)."""
    mode = WRITER if mode is None else mode
    if mode not in ("auto", "process", "inline"):
        from .constants import ParameterError
        raise ParameterError("writer", f"must be auto, process or inline (got {mode!r})")
    if mode == "inline" or (mode == "auto" and os.name != "posix"):
        return None
    w = _WRITER[0]
    if w is None or not w.alive():
        if w is not None and w.owner == os.getpid():
            w.stop()
        w = _WRITER[0] = WriterProcess()
    return w


def _serve(conn_in: Connection, conn_out: Connection) -> None:
    """The writer process: one granule's files at a time, until its parent closes the pipe.
    A failure is sent back at once (``error``); the granule's later sections are dropped,
    and its close or abort answered ``done``."""
    with frozen_start():          # its imports and kernels, and what a fork inherited:
        _warm_up()                # never walked by its collections (startup.py)
    gc.enable()                   # (a fork inherits the collector off: the parent's start)
    files, failed = None, False
    while True:
        try:
            kind, payload = _receive(conn_in)
        except EOFError:
            break
        try:
            if kind == "open":
                files, failed = None, False
                os.chdir(payload.pop("cwd"))
                files = GranuleFiles(**payload)
            elif failed:
                if kind in ("close", "abort"):
                    failed = False
                    conn_out.send(("done", None))
            elif kind == "section":
                run, replanned, last = payload
                files.section(run, replanned=replanned, last=last)
            else:                            # close or abort
                f, files = files, None
                if f is not None and kind == "close":
                    f.close()
                elif f is not None:
                    f.abort()
                conn_out.send(("ok", None))
        except BaseException as e:   # noqa: BLE001 (sent back to the simulating process)
            if files is not None:
                with contextlib.suppress(BaseException):
                    files.abort()
                files = None
            conn_out.send(("error", (_picklable(e), traceback.format_exc())))
            if kind in ("close", "abort"):
                conn_out.send(("done", None))
            else:
                failed = True


def _warm_up() -> None:
    """Before the first section (while the simulating process sets its renderer up): the
    writer's imports (inherited when forked), the compiled ATL06 fit, ATL03 fields and HDF5
    chunks' shuffle loaded from numba's cache when they are there (never compiled here: a
    short track does not use the fit), and PROJ's ECEF transform that ATL03's velocities use (pyproj's import and the
    transform's set-up, ~0.2 s of CPU the first section would pay; never imported before a
    fork: :func:`lidar_mitsuba.forking.refusal`)."""
    from . import granule_products, precompile  # noqa: F401
    from .products.atl03 import beam
    for stage in ("atl06", "atl03", "h5"):
        if precompile.is_cached(stage):
            getattr(precompile, f"_{stage}")()
    beam._to_ecef()


def _picklable(e: BaseException):
    try:
        pickle.loads(pickle.dumps(e))
        return e
    except Exception:                   # noqa: BLE001
        return None


def _serve_fds(fd_in: int, fd_out: int) -> None:
    """:func:`_serve` on the two pipes' file descriptors (from the parent, to it)."""
    _serve(Connection(fd_in, writable=False), Connection(fd_out, readable=False))


if __name__ == "__main__":
    _serve_fds(int(sys.argv[1]), int(sys.argv[2]))
