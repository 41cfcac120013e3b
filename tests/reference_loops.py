"""Deliberately simple reference implementations for the tests: one event at a time, in time
order, with a dict per channel. The library's compiled dead-time kernels are checked against
these."""
import numpy as np


def loop_nonparalyzable(group, t, dead):
    """Non-paralyzable dead time: recorded when >= ``dead`` after the last recorded event."""
    keep = np.zeros(t.size, bool)
    last = {}
    for i in np.lexsort((t, group)):
        g = group[i]
        if g not in last or t[i] >= last[g] + dead:
            keep[i] = True
            last[g] = t[i]
    return keep


def loop_paralyzable(group, t, dead):
    """Paralyzable dead time: recorded when >= ``dead`` after the previous event, recorded or not."""
    keep = np.zeros(t.size, bool)
    prev = {}
    for i in np.lexsort((t, group)):
        g = group[i]
        if g not in prev or t[i] - prev[g] >= dead:
            keep[i] = True
        prev[g] = t[i]
    return keep
