"""A fresh process's start-up without cyclic garbage collection (issue 43's cold start).

Before its first ray a fresh process creates some 260 000 objects that live as long as it:
modules, classes, functions, numba's type registries, Dr.Jit's and Mitsuba's bindings.
CPython's cyclic collector runs every 700 new container objects, and its older-generation
passes walk every object that survived so far: during the start-up it walks the growing heap
again and again and finds nothing to free (what is imported stays). Measured on the path of
bench's granule row (the imports, numba's start, the renderer's set-up; the main thread's CPU,
``time.thread_time``, three pairs of fresh processes under other agents' load, 2026-11-27):
1.22-1.23 s with the collector, 1.10-1.11 s without it. Turning it off and on again only
moves the walks: the first collections after it walk the whole heap, once per generation
(0.07 s each, measured the same way), more than they saved.

:func:`frozen_start` turns the collector off for the start-up and then moves every object
alive to the permanent generation (:func:`gc.freeze`), which no collection walks: the
imports' objects are never walked, in this process or in a child forked from it (whose
collections would otherwise also write to the inherited objects' headers, copying their
pages). Only for a process of our own (a command's, bench's row's, the writer process's):
frozen objects are never collected, so cyclic garbage made before the block's end (a
caller's, in a library call) would stay for the process's life. The command launcher
(``lidar_mitsuba_cli``) freezes its imports the same way and raises the youngest generation's
threshold (:func:`own_process`).

:func:`granule_process` is the one start of a process that simulates granules over DEMs:
``lidar-mitsuba simulate --dem`` and bench's granule rows
(:mod:`lidar_mitsuba.studies.track_length`) both call it, so that bench times what users run.
"""
from __future__ import annotations

import contextlib
import gc

#: the youngest generation's collection threshold in a process of our own (CPython's default
#: is 700 new container objects; the older generations keep CPython's 10 and 10): a granule
#: makes and drops many small containers, and its collections took 0.21 s of a six-beam
#: 100 km granule at 700 against 0.10 s at 10 000 when the command launcher adopted it
#: (5c7d8bc). With the start-up's objects frozen (:func:`frozen_start`) they cost ~3 ms a
#: granule at either (bench's granule, 2026-11-28: 9 young collections at 700, 1 at 10 000):
#: kept so that bench's rows and the commands run alike
GEN0_THRESHOLD = 10_000


@contextlib.contextmanager
def frozen_start():
    """The cyclic garbage collector off within the block; at its end every object alive is
    frozen (:func:`gc.freeze`: never walked by a collection again) and the collector back on
    as it was. Reference counting frees what it always frees. For a process of our own
    only (module docstring)."""
    was_on = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if was_on:
            gc.enable()


def own_process() -> None:
    """The collector's settings for the whole life of a process of our own (a command's,
    bench's rows'), from its start: every object alive frozen (:func:`gc.freeze`: the imports
    so far are never walked) and the youngest generation collected every
    :data:`GEN0_THRESHOLD` new containers. Not for a caller's process (a notebook's, the
    tests'): its cyclic garbage made so far would never be collected."""
    gc.freeze()
    gc.set_threshold(GEN0_THRESHOLD, 10, 10)


def granule_process():
    """Start a process of our own that simulates granules over DEMs (``simulate --dem``,
    bench's granule rows), in this order, within :func:`frozen_start`: the granule's imports;
    the writer process forked from this one (:func:`lidar_mitsuba.granule_writer.writer`:
    before any thread or the renderer, so that it inherits the imports and numba's start);
    the first kernels loading from numba's cache on a thread
    (:func:`lidar_mitsuba.precompile.load_kernels`); the renderer's set-up
    (:func:`lidar_mitsuba.trace.variant.ensure_renderer`). Returns the ``mitsuba`` module.
    Cheap when it already ran in this process (each step is once a process).

    Raises:
        RendererUnavailable: no usable libLLVM or variant (as ``ensure_renderer``).
    """
    with frozen_start():         # no garbage collection walks the start-up's objects
        from . import granule, granule_writer, precompile    # noqa: F401
        from .trace.variant import ensure_renderer
        granule_writer.writer()
        precompile.load_kernels()
        return ensure_renderer()
