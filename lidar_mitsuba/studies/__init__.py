"""Studies built on the pipeline: they call it, the pipeline never calls them.

- :mod:`.reproduce`: the paper's Figs. 3-13 and an agreement report (``lidar-mitsuba reproduce``).
- :mod:`.bench`: throughput benchmarks (``lidar-mitsuba bench``), which also run:
- :mod:`.accuracy`: accuracy against time for every knob, the Pareto front, the cost of each
  default simplification;
- :mod:`.breaking_points`: each model swept to where it fails;
- :mod:`.peer`: the comparison with mitransient.
- :mod:`.brdf_variants`: Ward normalisations and Mitsuba BSDFs compared (notebook 01).
- :mod:`.fpb_matrix`: the first-photon-bias correction's test matrix, without rendering.

Each computes JSON-able numbers (a dict or rows; ``run`` for the bench's studies and the
reproduction) and draws from them (``chart`` / ``plot_*``, returning the Figure).
"""

import math as _math
import warnings as _warnings

import numpy as _np

from ..constants import SimulationWarning as _SimulationWarning

# The studies run degenerate settings on purpose (too few paths, coarse meshes, near-mirror
# BRDFs, to find where methods fail): their SimulationWarnings are expected, and the studies
# record what matters in their own rows.
_warnings.filterwarnings("ignore", category=_SimulationWarning, module=r"lidar_mitsuba\.studies\.")


def json_safe(obj, *, skip=lambda key: False):
    """``obj`` (dicts, lists, tuples, NumPy arrays and scalars, numbers, strings) as plain
    JSON values, for a study's ``*.json``: keys as strings, those ``skip`` (called with the
    key) says to leave out dropped, NumPy values as Python ones, and every non-finite float,
    Python's or NumPy's, as None (JSON has no NaN or infinity)."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v, skip=skip) for k, v in obj.items() if not skip(str(k))}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v, skip=skip) for v in obj]
    if isinstance(obj, _np.ndarray):
        return json_safe(obj.tolist(), skip=skip)
    if isinstance(obj, _np.generic):
        value = obj.item()
        return value if isinstance(value, _np.generic) else json_safe(value, skip=skip)
    if isinstance(obj, float) and not _math.isfinite(obj):
        return None
    return obj
