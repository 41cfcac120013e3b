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

import warnings as _warnings

from ..constants import SimulationWarning as _SimulationWarning

# The studies run degenerate settings on purpose (too few paths, coarse meshes, near-mirror
# BRDFs, to find where methods fail): their SimulationWarnings are expected, and the studies
# record what matters in their own rows.
_warnings.filterwarnings("ignore", category=_SimulationWarning, module=r"lidar_mitsuba\.studies\.")
