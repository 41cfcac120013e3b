"""The layout of a subsurface kernel table (``snowkernel``), shared by the plugin and whatever
builds tables: nodes every :data:`THETA_STEP_DEG` of incidence angle from 0, and at each node
the weighted distribution of the extra optical path as its quantiles at the levels
:func:`quantile_levels` (dense toward the long tail). Pure numpy.
"""
from __future__ import annotations

import numpy as np

THETA_STEP_DEG = 5.0
"""Spacing of the table's nodes in incidence angle [deg] (node j at j * 5 deg)."""
U_POWER = 4.0
"""Quantile levels ``u_k = 1 - (1 - k / (M - 1))^U_POWER``: a quarter of the M levels lie
beyond u = 0.68, the last interval is (M - 1)^-4 wide."""


def node_angles_deg(n_nodes: int) -> np.ndarray:
    """The incidence angles [deg] of a table's ``n_nodes`` nodes."""
    return np.arange(n_nodes, dtype=np.float64) * THETA_STEP_DEG


def quantile_levels(n_quantiles: int) -> np.ndarray:
    """The levels ``u_k`` (n_quantiles,) at which a table stores the extra path."""
    k = np.arange(n_quantiles, dtype=np.float64) / (n_quantiles - 1)
    return 1.0 - (1.0 - k) ** U_POWER


def save(path, *, weight: np.ndarray, extra_path_m: np.ndarray, **meta) -> None:
    """Write a table: ``weight`` (J,) return weight per incident photon, ``extra_path_m``
    (J, M) the extra optical path [m] at :func:`quantile_levels` ``(M)``, and any metadata
    arrays, to ``path`` (``.npz``)."""
    np.savez(path, weight=np.asarray(weight, np.float32),
             extra_path_m=np.asarray(extra_path_m, np.float32), **meta)


def load(path) -> dict:
    """A table written by :func:`save`: every array it holds."""
    with np.load(str(path)) as t:
        return {k: t[k] for k in t.files}
