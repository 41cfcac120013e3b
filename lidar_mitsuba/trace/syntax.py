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
with the real ``drjit.syntax`` (the same source, the same options, the same compiled code as
at the definition) and from then on calls the rewritten function. Only the moment of the
rewriting changes (and a failure to rewrite surfaces at the first call rather than at the
import); the rewritten function, and so every kernel it traces, is the same.
"""
from __future__ import annotations

import contextlib
import functools
import threading

_lock = threading.Lock()


def _on_first_call(eager, f, options: dict):
    """A stand-in for ``eager(f, **options)`` (``eager``: Dr.Jit's own ``syntax``) that
    rewrites ``f`` on its first call (once, under a lock) and then calls the rewritten
    function."""
    rewritten = []

    @functools.wraps(f)
    def stand_in(*args, **kwargs):
        if not rewritten:
            with _lock:
                if not rewritten:
                    rewritten.append(eager(f, **options))
        return rewritten[0](*args, **kwargs)

    return stand_in


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
