"""The sweep chart: bias and precision against one swept parameter, with error bars
(``lidar-mitsuba sweep SPEC.toml --plot PARAM``)."""
from __future__ import annotations

import math

import numpy as np

from .spec import parameter_names

#: columns never drawn as lines: realisations are averaged over
SEED_COLUMNS = ("seed", "terrain_seed")


def parameter_columns(df) -> list[str]:
    """The table's parameter columns (the spec's keys), in table order."""
    known = parameter_names()
    return [c for c in df.columns if c in known or c.startswith("params.")]


def swept(df) -> list[str]:
    """Parameter columns with more than one value, seeds left out."""
    return [c for c in parameter_columns(df) if c not in SEED_COLUMNS
            and df[c].astype(str).nunique(dropna=False) > 1]


def _missing(v) -> bool:
    return v is None or isinstance(v, float) and math.isnan(v)


def _order(values) -> list:
    try:
        return sorted(values)
    except TypeError:                      # mixed types: as text
        return sorted(values, key=str)


def points(df, x: str, y: str) -> dict[tuple, list[tuple]]:
    """``{(other parameter values...): [(x, mean of y, its error, replicates), ...]}`` over
    the ``ok`` rows: the mean of ``y`` over the replicates (and any other seeds) of each
    point; its error is their standard error (std / sqrt(R)) when R >= 2, else the run's
    own Monte Carlo standard error (column ``y`` with ``_m`` -> ``_se_m``)."""
    ok = df[df["status"] == "ok"]
    others = [c for c in swept(ok) if c != x]
    se = y[:-2] + "_se_m"
    groups = ok.groupby(others, dropna=False, sort=True) if others else [((), ok)]
    out: dict[tuple, list[tuple]] = {}
    for label, part in groups:
        line = []
        for xv in _order(set(part[x].dropna())):
            rows = part[(part[x] == xv) & np.isfinite(part[y].to_numpy(float))]
            if len(rows) == 0:
                continue
            v = rows[y].to_numpy(float)
            err = (float(np.std(v, ddof=1) / math.sqrt(v.size)) if v.size >= 2
                   else float(rows[se].iloc[0]))
            line.append((xv, float(np.mean(v)), err, int(v.size)))
        if line:
            out[tuple(label) if isinstance(label, tuple) else (label,)] = line
    return out


def plot(df, x: str, *, path=None, title: str = ""):
    """Bias and precision (photon level, in cm) against the parameter ``x``, one line per
    combination of the other swept parameters, error bars from :func:`points`. Writes
    ``path`` (PNG) when given; returns the matplotlib Figure."""
    from ..plotting import plt
    others = [c for c in swept(df[df["status"] == "ok"]) if c != x]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), dpi=110)
    reps = set()
    for ax, (y, name) in zip(axes, (("bias_m", "bias"), ("std_m", "precision (std)"))):
        for label, line in points(df, x, y).items():
            xs, ys, es, ns = zip(*line)
            reps.update(ns)
            ax.errorbar(xs, [100 * v for v in ys], yerr=[100 * e for e in es], marker="o",
                        ms=4, capsize=3, label=", ".join(f"{k} = {v}" for k, v in zip(
                            others, label) if not _missing(v)) or None)
        ax.set_xlabel(x)
        ax.set_ylabel(f"{name} of h - z_ref [cm]")
        ax.grid(alpha=0.3)
    if others:
        axes[1].legend(fontsize=8)
    err = ("standard error over " + "/".join(map(str, sorted(reps))) + " replicates"
           if reps and min(reps) >= 2 else "Monte Carlo standard error of each run"
           if not reps or max(reps) == 1 else "standard error over the replicates (one run: "
           "its Monte Carlo standard error)")
    fig.suptitle((title + "\n" if title else "") + f"error bars: {err}", fontsize=10)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path)
        plt.close(fig)
    return fig
