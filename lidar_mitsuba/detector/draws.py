"""The detector's binomial thinning (fill factor and PDE) as numpy's ``Generator.binomial``
draws it, from the same stream, in a compiled loop that sets each count's constants up once a
track instead of once a shot.

For ``n * p <= 30`` (``p <= 0.5``; else ``1 - p``, and ``n`` less the draw) numpy draws
``Binomial(n, p)`` by inversion (``random_binomial_inversion`` in numpy's
``random/src/distributions/distributions.c``, Kachitvichyanukul & Schmeiser 1988): with
``q = 1 - p``, ``P(0) = q^n`` computed as ``exp(n log q)`` and a bound ``min(n, n p + 10
sqrt(n p q + 1))`` on the search, one uniform a try (``next_double``), the probabilities
stepped up ``P(x) = P(x - 1) (n - x + 1) p / (x q)``. Its set-up (a log, an exp and a sqrt)
runs for every shot whose count differs from the shot before, half a draw's cost; here it is
computed once for each count of the track (Python's ``math``, the same C library functions on
the same doubles) and the loop is numpy's, with numba's ``Generator.random``, the same
``next_double``. A check on first use against ``Generator.binomial`` falls back to it where a
draw differs; counts beyond inversion's range go to numpy too.
"""
from __future__ import annotations

import functools
import math
import threading

import numba
import numpy as np

#: numpy's inversion range: ``n * min(p, 1 - p) <= 30`` (``random_binomial``)
INVERSION_MAX_MEAN = 30.0


@numba.njit(cache=True, nogil=True)
def binomial_inversion(rng, n, p, q_pow_n, bound):
    """(k,) int64 draws of ``Binomial(n[i], p)`` by numpy's inversion, from ``rng`` (a numpy
    ``Generator``); ``q_pow_n[m]`` and ``bound[m]`` numpy's set-up for a count ``m``
    (:func:`_set_up`); ``0 < p <= 0.5``, ``n * p <= 30``."""
    out = np.empty(n.size, np.int64)
    q = 1.0 - p
    for i in range(n.size):
        m = n[i]
        if m == 0:
            out[i] = 0
            continue
        qn = q_pow_n[m]
        top = bound[m]
        x = 0
        px = qn
        u = rng.random()
        while u > px:
            x += 1
            if x > top:
                x = 0
                px = qn
                u = rng.random()
            else:
                u -= px
                px = ((m - x + 1) * p * px) / (x * q)
        out[i] = x
    return out


@functools.lru_cache(maxsize=64)
def _set_up(p: float, n_max: int) -> tuple[np.ndarray, np.ndarray]:
    """numpy's inversion set-up for every count 0 .. ``n_max``: ``exp(n log q)`` and the
    search bound ``(int64) min(n, n p + 10 sqrt(n p q + 1))``, in its order of operations."""
    q = 1.0 - p
    log_q = math.log(q)
    qn = np.array([math.exp(m * log_q) for m in range(n_max + 1)], np.float64)
    bound = np.array([int(min(m, m * p + 10.0 * math.sqrt(m * p * q + 1))) if m else 0
                      for m in range(n_max + 1)], np.int64)
    return qn, bound


_CHECKED: list = []
_LOCK = threading.Lock()


def _compiled_ok() -> bool:
    """Whether the compiled draws are numpy's, checked once a process on counts of 0-40 at
    both sides of p = 1/2 (the stream after them too)."""
    with _LOCK:
        if not _CHECKED:
            n = np.random.default_rng(7).integers(0, 41, 512)
            ok = True
            for p in (0.05, 0.4, 0.5, 0.75, 0.97):
                a, b = np.random.default_rng(3), np.random.default_rng(3)
                ok &= np.array_equal(a.binomial(n, p), _draw(b, n, p)) and \
                    a.random() == b.random()
            _CHECKED.append(bool(ok))
        return _CHECKED[0]


def _draw(rng, n: np.ndarray, p: float) -> np.ndarray:
    if p <= 0.5:
        return binomial_inversion(rng, n, p, *_set_up(p, int(n.max())))
    q = 1.0 - p
    return n - binomial_inversion(rng, n, q, *_set_up(q, int(n.max())))


def binomial(rng: np.random.Generator, n: np.ndarray, p: float) -> np.ndarray:
    """``rng.binomial(n, p)`` for (k,) integer counts ``n >= 0`` and a probability ``p``:
    the same draws and the same stream after them (see the module docstring); (k,) int64."""
    n = np.asarray(n)
    p = float(p)
    if (n.ndim == 1 and n.size and n.dtype.kind in "iu" and 0.0 < p < 1.0
            and int(n.min()) >= 0 and min(p, 1.0 - p) * int(n.max()) <= INVERSION_MAX_MEAN
            and _compiled_ok()):
        return _draw(rng, n.astype(np.int64, copy=False), p)
    return rng.binomial(n, p)
