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
(``lidar_mitsuba_cli``) freezes its imports the same way.
"""
from __future__ import annotations

import contextlib
import gc


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
