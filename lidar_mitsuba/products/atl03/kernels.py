"""Compiled per-photon fields of ATL03's beam groups (numba; issue 43: the writer's CPU).

Each kernel is one pass over a section's photons, in shot order, where numpy took a sort or
several passes; each gives the very values of its numpy form in
:mod:`lidar_mitsuba.products.atl03.beam` (``tests/test_atl03.py`` compares them), which stays
for the photons a kernel does not take (not in shot order). ``cache=True`` keeps the compiled
code beside the package (:mod:`lidar_mitsuba.precompile`'s ``"atl03"`` stage).
"""
from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def ph_id_count(shot, channel, out):
    """ATL03's ``ph_id_count`` into ``out`` (n,) uint8: the 1-based index of each event among
    the events of its shot and channel, in order, at most 255, for photons whose ``shot`` (n,)
    never decreases and whose ``channel`` (n,) is at least 0 (a shot's events are together:
    one counter per channel, cleared as each shot ends). Returns ``False``, with ``out``
    unfinished, where the photons are not so (the caller's numpy form then takes them)."""
    n = shot.size
    if n == 0:
        return True
    top = 0
    for i in range(n):
        c = channel[i]
        if c < 0 or (i > 0 and shot[i] < shot[i - 1]):
            return False
        top = max(top, c)
    count = np.zeros(top + 1, np.int64)
    first = 0                                   # the current shot's first event
    for i in range(n):
        if i > 0 and shot[i] != shot[i - 1]:
            for j in range(first, i):
                count[channel[j]] = 0
            first = i
        c = channel[i]
        count[c] += 1
        out[i] = min(count[c], 255)
    return True
