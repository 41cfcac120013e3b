"""Dr.Jit's ``@dr.syntax`` applied on a function's first call instead of at its definition,
while the renderer is set up (issue 43's cold start).

``@dr.syntax`` rewrites a function's source so that its Python ``while`` and ``if`` on Dr.Jit
arrays become symbolic loops and conditionals: it reads the source (``inspect.getsource``),
parses it, walks and rewrites the tree and compiles it again, ~5-10 ms a function. Importing
Mitsuba and activating its variant define 10 such functions (the differentiable integrators'
and ``mitsuba.python.ad.projective``'s), our plugins 9 more, and each is rewritten at its
definition: 0.15 s of the main thread's CPU in every fresh process (0.09 s Mitsuba's, 0.06 s
ours; measured here in three fresh processes, 2026-11-27), before the first ray, for
functions that a lidar run never calls but one (the ``pathlength`` integrator's
``sample``).

:func:`deferred` replaces ``drjit.syntax`` while the renderer is set up by a decorator that
returns a stand-in for the function: on its first call the stand-in rewrites the function
with the real ``drjit.syntax`` (the same options, and the same source: the file's lines as
they were at the definition, kept then, whatever the file holds by the first call) and from
then on calls the rewritten function. Only the moment of the
rewriting changes (and a failure to rewrite surfaces at the first call rather than at the
import); the rewritten function, and so every kernel it traces, is the same.
"""
from __future__ import annotations

import contextlib
import functools
import linecache
import threading

_lock = threading.Lock()


def _on_first_call(eager, f, options: dict):
    """A stand-in for ``eager(f, **options)`` (``eager``: Dr.Jit's own ``syntax``) that
    rewrites ``f`` on its first call (once, under a lock) and then calls the rewritten
    function. The source it rewrites is the file's as it was at the definition (its lines
    kept then, and shown to ``inspect`` at the rewriting): a file edited or checked out
    anew while a long process runs changes nothing, as with the eager rewriting."""
    filename = f.__code__.co_filename
    lines = linecache.getlines(filename, f.__globals__)       # (one read a file)
    rewritten = []

    @functools.wraps(f)
    def stand_in(*args, **kwargs):
        if not rewritten:
            with _lock:
                if not rewritten:
                    with _source_as_defined(filename, lines):
                        rewritten.append(eager(f, **options))
        return rewritten[0](*args, **kwargs)

    return stand_in


@contextlib.contextmanager
def _source_as_defined(filename: str, lines: list[str]):
    """``linecache`` (which ``inspect.getsource`` reads) serves ``lines`` for ``filename``
    within the block, whatever the file holds now (an entry without a modification time is
    one ``linecache.checkcache`` leaves alone); its entry as it was afterwards."""
    if not lines:                        # (no source kept: Dr.Jit reads what there is)
        yield
        return
    before = linecache.cache.get(filename)
    linecache.cache[filename] = (sum(map(len, lines)), None, lines, filename)
    try:
        yield
    finally:
        if before is None:
            linecache.cache.pop(filename, None)
        else:
            linecache.cache[filename] = before


@contextlib.contextmanager
def deferred():
    """Within the block, ``drjit.syntax`` (``@dr.syntax`` and ``@dr.syntax(...)``) defers each
    function's rewriting to its first call (the module docstring); restored afterwards."""
    import drjit as dr
    eager = dr.syntax
    if getattr(eager, "_deferred", False):          # (nested: already deferred)
        yield
        return

    def syntax(f=None, **options):
        if f is None:                    # @dr.syntax(recursive=True, ...)
            return lambda g: syntax(g, **options)
        return _on_first_call(eager, f, options)

    syntax._deferred = True
    dr.syntax = syntax
    try:
        yield
    finally:
        dr.syntax = eager
