"""Sorts for the compiled ATL06 fit (:mod:`lidar_mitsuba.products.atl06.kernel`), in numba.

numba's own sorts take seconds each to compile, so the fit has its own: :func:`sort` (values
only) and :func:`argsort` (numpy's stable order), and :func:`first_at_least`, numpy's
``searchsorted``. Both sorts distribute first (issue 43): each value goes to one of ``n``
equal buckets between the array's least and greatest value (the bucket ``floor((v - min)
n / (max - min))``, which never decreases as ``v`` grows: the buckets are in order), in the
array's order (a counting sort: stable), then each bucket is put in order by insertion (a
bucket of more than :data:`BUCKET_MAX` values by the comparison sorts below). A segment's
~100-200 heights or residuals, comparison-sorted, cost ~38 ns a value, most of it branches
mispredicted on unpredictable comparisons; distributed they cost ~10 ns (3.8x faster for
the values, 4.2x for the order, on a strong beam's segments). The comparison sorts stay for
what distribution cannot take (a NaN, an infinite or single value, fewer than
:data:`DISTRIBUTE_MIN` values) and for crowded buckets: :func:`_quicksort` (Hoare's, the
median of three) for values and :func:`_merge_argsort` (insertion-sorted runs of 16, then
bottom-up merges) for the order. The fit's results depend only on the sorted values, or
(``argsort``) on the one stable order, so they are the same whichever sort gives them: a
NaN, which no comparison orders, takes :func:`_merge_argsort`'s order in both
(``tests/test_atl06.py`` checks the sorts against numpy's). (Only -0.0 and 0.0, equal to
every comparison, may trade places in :func:`sort`'s values: a residual is -0.0 only for a
photon at height -0.0 exactly on its line.) Each value's bucket is worked out once, and
where no bucket is crowded one insertion pass over the distributed values puts every bucket
in order (a value never passes one of a lower bucket, which is smaller): the same result as
bucket by bucket, ~20 % less time on a strong beam's segments (issue 43).
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


#: fewest values :func:`sort` and :func:`argsort` distribute into buckets (fewer are
#: compared: a choice, not a measurement, about the comparison sorts' runs of 16)
DISTRIBUTE_MIN = 16
#: most values a bucket is put in order by insertion (more: by the comparison sort, so that
#: a crowded bucket, e.g. a segment's surface photons among background spread over the
#: gate, costs n log n, not n^2; a choice, twice the comparison sorts' runs)
BUCKET_MAX = 32


@numba.njit(cache=True, nogil=True)
def _range(a):
    """The least value of the float64 array ``a``, its buckets per unit value (``n / (max -
    min)``), and whether distributing it is defined: at least :data:`DISTRIBUTE_MIN` values,
    none NaN, a finite positive spread and a finite scale."""
    lo, hi, nan = np.inf, -np.inf, False
    for i in range(a.size):
        v = a[i]
        if v != v:
            nan = True
        lo = min(lo, v)
        hi = max(hi, v)
    span = hi - lo
    ok = not nan and a.size >= DISTRIBUTE_MIN and 0.0 < span < np.inf
    scale = a.size / span if ok else 0.0
    return lo, scale, ok and scale < np.inf


@numba.njit(cache=True, nogil=True)
def _bucket(v, lo, scale, n):
    """The bucket (0 .. n - 1) of value ``v``: ``floor((v - lo) scale)``, the greatest value's
    (``n``) in the last; never smaller for a larger ``v`` (each step rounds monotonically)."""
    return min(int((v - lo) * scale), n - 1)


@numba.njit(cache=True, nogil=True)
def _buckets(a, lo, scale):
    """Each value's bucket (:func:`_bucket`), the (n + 1,) first position of each of the
    ``n`` buckets of ``a`` and the end, and whether a bucket holds more than
    :data:`BUCKET_MAX` values."""
    n = a.size
    bucket = np.empty(n, np.int64)
    start = np.zeros(n + 1, np.int64)
    for i in range(n):
        k = _bucket(a[i], lo, scale, n)
        bucket[i] = k
        start[k + 1] += 1
    crowded = False
    for k in range(n):
        crowded = crowded or start[k + 1] > BUCKET_MAX
        start[k + 1] += start[k]
    return bucket, start, crowded


@numba.njit(cache=True, nogil=True)
def sort(a):
    """The float64 array ``a`` sorted (a new array): the values of any sort, distributed into
    buckets (see the module docstring) or by :func:`_quicksort`; a NaN among them takes
    :func:`_merge_argsort`'s order."""
    lo, scale, spread = _range(a)
    if not spread:
        if has_nan(a):
            return a[_merge_argsort(a)]
        s = a.copy()
        _quicksort(s)
        return s
    n = a.size
    bucket, start, crowded = _buckets(a, lo, scale)
    pos = start[:n].copy()
    s = np.empty(n)
    for i in range(n):
        k = bucket[i]
        s[pos[k]] = a[i]
        pos[k] += 1
    if not crowded:      # one pass by insertion: no value passes a smaller bucket's (the
        _insertion(s)    # buckets are in order), so each bucket is put in order on its own
        return s
    for k in range(n):
        b0, b1 = start[k], start[k + 1]
        if b1 - b0 > BUCKET_MAX:
            _quicksort(s[b0:b1])
        else:
            _insertion(s[b0:b1])
    return s


@numba.njit(cache=True, nogil=True)
def _insertion(s):
    """Sort ``s`` in place by insertion (stable)."""
    for i in range(1, s.size):
        key = s[i]
        j = i
        while j > 0 and s[j - 1] > key:
            s[j] = s[j - 1]
            j -= 1
        s[j] = key


@numba.njit(cache=True, nogil=True)
def _insertion_order(idx, s):
    """:func:`_insertion` of the values ``s`` in place, their indices ``idx`` moved beside
    them (stable: only a strictly greater value moves up)."""
    for i in range(1, s.size):
        v, key = idx[i], s[i]
        j = i
        while j > 0 and s[j - 1] > key:
            idx[j], s[j] = idx[j - 1], s[j - 1]
            j -= 1
        idx[j], s[j] = v, key


@numba.njit(cache=True, nogil=True)
def argsort(a):
    """Stable argsort of a float64 array (numpy's ``kind="stable"``): distributed into
    buckets in the array's order, each bucket's indices by insertion on strictly greater
    values, the values moved beside them (see the module docstring), or by
    :func:`_merge_argsort`."""
    lo, scale, spread = _range(a)
    if not spread:
        return _merge_argsort(a)
    n = a.size
    bucket, start, crowded = _buckets(a, lo, scale)
    pos = start[:n].copy()
    idx = np.empty(n, np.int64)
    s = np.empty(n)
    for i in range(n):
        k = bucket[i]
        idx[pos[k]], s[pos[k]] = i, a[i]
        pos[k] += 1
    if not crowded:      # one pass by insertion, as sort's
        _insertion_order(idx, s)
        return idx
    for k in range(n):
        b0, b1 = start[k], start[k + 1]
        if b1 - b0 > BUCKET_MAX:         # (its indices ascend: a stable sort keeps ties so)
            part = idx[b0:b1].copy()
            idx[b0:b1] = part[_merge_argsort(a[part])]
        else:
            _insertion_order(idx[b0:b1], s[b0:b1])
    return idx


@numba.njit(cache=True, nogil=True)
def sort_and_order(a):
    """``(sort(a), argsort(a))``, at the cost of the order and a gather: the values are
    :func:`sort`'s to the bit, ``a[argsort(a)]`` (both sorts put equal values in the same
    places, and equal values have the same bits, but for -0.0 and 0.0: an array with a zero
    gets :func:`sort`'s values and no order, an empty one)."""
    for i in range(a.size):
        if a[i] == 0.0:
            return sort(a), np.empty(0, np.int64)
    order = argsort(a)
    return a[order], order


@numba.njit(cache=True, nogil=True)
def merged_order(r, ext, sel, sel_order, r_ext):
    """``argsort(r_ext)`` of ``r_ext = r[ext]`` (the stable order) from ``sel_order``, the
    stable order of ``r[sel]``, when the selection ``sel`` is within ``ext`` and the rest of
    ``r[ext]`` lie above all of it (as a fit's window lies within its extended window): the
    selection's order, then the rest's, sorted on their own (a few values). Otherwise
    ``argsort(r_ext)`` itself: the same order either way."""
    n_rest = r_ext.size - sel_order.size
    if n_rest < 0:
        return argsort(r_ext)
    at_sel = np.empty(sel_order.size, np.int64)   # each selected value's place in r_ext
    rest_at, rest = np.empty(n_rest, np.int64), np.empty(n_rest)
    e = j = m = 0
    top = -np.inf                                 # (the selection's greatest value)
    for i in range(r.size):
        if sel[i]:
            if not ext[i] or j == sel_order.size or r[i] != r[i]:
                return argsort(r_ext)
            at_sel[j] = e
            top = max(top, r[i])
            j += 1
        elif ext[i]:
            if m == n_rest:
                return argsort(r_ext)
            rest_at[m], rest[m] = e, r[i]
            m += 1
        e += ext[i]
    if j != sel_order.size or (m and not rest.min() > top):
        return argsort(r_ext)
    order = np.empty(r_ext.size, np.int64)
    for k in range(j):
        order[k] = at_sel[sel_order[k]]
    if m:
        rest_order = argsort(rest)
        for k in range(m):
            order[j + k] = rest_at[rest_order[k]]
    return order


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
def _merge_argsort(a):
    """Stable argsort of a float64 array by comparisons (insertion-sorted runs of 16, then
    bottom-up merges): any values, NaN included."""
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
