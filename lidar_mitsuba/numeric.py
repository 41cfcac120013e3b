"""numpy's float64 sum, replayed in numba: compiled kernels that stand in for numpy code give
its bits, not merely its value to rounding.

numpy sums a contiguous float64 run pairwise (``pairwise_sum`` in its ``loops_utils``):
fewer than 8 values one after another from 0; up to 128 in eight running sums over the
values' positions mod 8, combined as ``((s0 + s1) + (s2 + s3)) + ((s4 + s5) + (s6 + s7))``,
then the last ``n % 8`` added one by one; above 128 the two halves (the first a multiple of
8 long) summed so and added. ``np.sum`` over the trailing axes of a C-contiguous array sums
each row of those axes as one run. ``tests/test_atl06.py`` and ``tests/test_granule.py``
check these functions against numpy on this machine's numpy, bit for bit.
"""
from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def block_sum(a, lo, n):
    """numpy's sum of ``a[lo:lo + n]`` (float64, contiguous) for ``n <= 128``."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    m = n - n % 8
    while i < m:
        j = lo + i
        r0 += a[j]
        r1 += a[j + 1]
        r2 += a[j + 2]
        r3 += a[j + 3]
        r4 += a[j + 4]
        r5 += a[j + 5]
        r6 += a[j + 6]
        r7 += a[j + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@numba.njit(cache=True, nogil=True)
def pairwise_sum(a, lo, n):
    """``a[lo:lo + n].sum()`` as numpy sums a contiguous float64 array, for any ``n``. The
    halving above 128 is walked with a stack of its own (numba's cache does not keep recursive
    functions safely: a recursive version crashed when loaded from the cache)."""
    if n <= 128:
        return block_sum(a, lo, n)
    todo_lo = np.empty(64, np.int64)       # spans to split or sum (depth < 64 for any n)
    todo_n = np.empty(64, np.int64)
    todo_add = np.zeros(64, np.bool_)      # both halves summed: add them
    vals = np.empty(64)
    todo_lo[0], todo_n[0], todo_add[0] = lo, n, False
    k, v = 1, 0
    while k > 0:
        k -= 1
        lo_k, n_k = todo_lo[k], todo_n[k]
        if todo_add[k]:
            v -= 1
            vals[v - 1] = vals[v - 1] + vals[v]
        elif n_k <= 128:
            vals[v] = block_sum(a, lo_k, n_k)
            v += 1
        else:
            n2 = n_k // 2
            n2 -= n2 % 8
            todo_lo[k], todo_n[k], todo_add[k] = lo_k, n_k, True
            todo_lo[k + 1], todo_n[k + 1], todo_add[k + 1] = lo_k + n2, n_k - n2, False
            todo_lo[k + 2], todo_n[k + 2], todo_add[k + 2] = lo_k, n2, False
            k += 3
    return vals[0]
