"""Sorts for the compiled ATL06 fit (:mod:`lidar_mitsuba.products.atl06.kernel`), in numba.

numba's own sorts take seconds each to compile, so the fit has its own: :func:`sort` (values
only: a quicksort, ~1.2-2x the merge sort's speed at a segment's ~100 photons, whose
comparisons, unpredictable branches, are most of a sort's cost) and :func:`argsort` (stable:
insertion-sorted runs of 16, then bottom-up merges), and :func:`first_at_least`, numpy's
``searchsorted``. The fit's results depend only on the sorted values, or (``argsort``) on the
one stable order, so they are the same whichever sort gives them: a NaN, which no comparison
orders, takes ``argsort``'s order in both (``tests/test_atl06.py`` checks the sorts against
numpy's). (Only -0.0 and 0.0, equal to every comparison, may trade places: a residual is -0.0
only for a photon at height -0.0 exactly on its line.)
"""
from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def has_nan(a):
    """Some value of the float64 array ``a`` is NaN."""
    for i in range(a.size):
        if math.isnan(a[i]):
            return True
    return False


@numba.njit(cache=True, nogil=True)
def sort(a):
    """The float64 array ``a`` sorted (a new array): the values of any sort, by a quicksort
    (:func:`_quicksort`); a NaN among them takes :func:`argsort`'s order."""
    if has_nan(a):
        return a[argsort(a)]
    s = a.copy()
    _quicksort(s)
    return s


@numba.njit(cache=True, nogil=True)
def _quicksort(s):
    """Sort ``s`` in place (no NaN in it): Hoare's partition about the median of three, the
    smaller part first (a stack of log2 n), runs of 16 or fewer by insertion."""
    stack = np.empty(128, np.int64)
    top, lo, hi = 0, 0, s.size
    while True:
        if hi - lo <= 16:
            for i in range(lo + 1, hi):
                key = s[i]
                j = i
                while j > lo and s[j - 1] > key:
                    s[j] = s[j - 1]
                    j -= 1
                s[j] = key
            if top == 0:
                return
            top -= 2
            lo, hi = stack[top], stack[top + 1]
            continue
        mid = (lo + hi) >> 1
        if s[mid] < s[lo]:
            s[mid], s[lo] = s[lo], s[mid]
        if s[hi - 1] < s[mid]:
            s[hi - 1], s[mid] = s[mid], s[hi - 1]
            if s[mid] < s[lo]:
                s[mid], s[lo] = s[lo], s[mid]
        s[mid], s[lo] = s[lo], s[mid]             # the pivot at lo, out of the way
        i, j = lo + 1, hi - 1
        while True:
            while i <= j and s[i] < s[lo]:
                i += 1
            while i <= j and s[lo] < s[j]:
                j -= 1
            if i >= j:
                break
            s[i], s[j] = s[j], s[i]
            i += 1
            j -= 1
        s[lo], s[j] = s[j], s[lo]               # the pivot in its place, j
        if j - lo < hi - j - 1:                      # the larger part waits on the stack
            stack[top], stack[top + 1] = j + 1, hi
            hi = j
        else:
            stack[top], stack[top + 1] = lo, j
            lo = j + 1
        top += 2


@numba.njit(cache=True, nogil=True)
def argsort(a):
    """Stable argsort of a float64 array (insertion-sorted runs of 16, then bottom-up merges);
    :func:`sort` where only the values are needed."""
    n = a.size
    idx = np.arange(n)
    run = 16
    for lo in range(0, n, run):
        hi = min(lo + run, n)
        for i in range(lo + 1, hi):
            v = idx[i]
            key = a[v]
            j = i - 1
            while j >= lo and a[idx[j]] > key:
                idx[j + 1] = idx[j]
                j -= 1
            idx[j + 1] = v
    src = idx
    dst = np.empty(n, np.int64)
    width = run
    while width < n:
        for lo in range(0, n, 2 * width):
            mid = min(lo + width, n)
            hi = min(lo + 2 * width, n)
            i, j, k = lo, mid, lo
            while i < mid and j < hi:
                if a[src[j]] < a[src[i]]:
                    dst[k] = src[j]
                    j += 1
                else:
                    dst[k] = src[i]
                    i += 1
                k += 1
            while i < mid:
                dst[k] = src[i]
                i += 1
                k += 1
            while j < hi:
                dst[k] = src[j]
                j += 1
                k += 1
        src, dst = dst, src
        width *= 2
    return src


@numba.njit(cache=True, nogil=True)
def first_at_least(a, v, right):
    """``np.searchsorted(a, v, side="right" if right else "left")`` for sorted ``a``."""
    lo, hi = 0, a.size
    while lo < hi:
        mid = (lo + hi) // 2
        if a[mid] < v or (right and a[mid] == v):
            lo = mid + 1
        else:
            hi = mid
    return lo
