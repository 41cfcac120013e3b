"""The BRDF comparison's figure (:func:`plot_sweep`): photons per shot, bias and precision of
:func:`~lidar_mitsuba.studies.brdf_variants.sweep` rows against slope or p, one curve per
variant, and below them the same against a reference variant.

In the study's data flow this is the end: it reads rows (through
:mod:`~lidar_mitsuba.studies.brdf_rows`) and draws them, so a figure can be redrawn, and
tested, from saved rows. Import :func:`plot_sweep` from :mod:`~lidar_mitsuba.studies.brdf_variants`.
"""
from __future__ import annotations

from collections.abc import Sequence

import matplotlib.pyplot as plt
import numpy as np

from ..instrument import Instrument
from .brdf_rows import relative_to, select

#: Plot style per variant name (colour, marker); unknown names get matplotlib's cycle.
STYLES: dict[str, tuple[str, str]] = {
    "Ward ward1992": ("#08519c", "o"),
    "Ward duer": ("#3182bd", "s"),
    "Ward balanced": ("#6baed6", "D"),
    "Lambertian": ("black", "x"),
    "roughplastic Beckmann": ("#e6550d", "^"),
    "roughplastic GGX": ("#fdae6b", "v"),
    "roughconductor": ("#a50f15", "*"),
}

_PANELS = (
    # (row key, error key, scale, absolute label,
    #  relative key, its error, its scale, its label, shift subtracted before scaling)
    ("photons_per_shot", "photons_per_shot_se", 1.0, "photons per shot",
     "photons_ratio", "photons_ratio_se", 1.0, "photons per shot ÷ {ref}'s", 0.0),
    ("bias_m", "bias_se_m", 100.0, "elevation bias [cm]",
     "bias_diff_m", "bias_diff_se_m", 100.0, "bias − {ref}'s [cm]", 0.0),
    ("std_m", "std_se_m", 100.0, "precision (std) [cm]",
     "std_ratio", "std_ratio_se", 100.0, "precision ÷ {ref}'s − 1 [%]", 1.0),
)


def plot_sweep(rows: Sequence[dict], *, x: str, reference: str | None = "Lambertian",
               variants: Sequence[str] | None = None, instrument: Instrument | None = None,
               title: str = "", path=None):
    """Photons per shot, bias and precision against slope or p, one curve per BRDF variant.

    Top row: the values. Bottom row (when ``reference`` is among the rows): the same against
    the ``reference`` variant on the same surface (see
    :func:`~lidar_mitsuba.studies.brdf_rows.relative_to`): photons per shot as a ratio, bias
    as a difference [cm], precision as a relative difference [%].

    Args:
        rows: output of :func:`~lidar_mitsuba.studies.brdf_variants.sweep` for one beam and
            detector (rows of other surfaces than those of ``x`` are ignored).
        x: ``"slope_deg"`` (flat and sloped planes) or ``"p"`` (fractal tiles).
        reference: variant the bottom row compares with (``None``: no bottom row).
        variants: the variants to draw, in legend order (default: all, in row order).
        instrument: for ``x="slope_deg"``, draw the ideal-detector closed form of the precision,
            hypot(c sigma_t / 2, sigma_fp tan(slope)), as a dashed line (default: the rows'
            beam's instrument); that panel's y axis is logarithmic.
        title: figure title. path: PNG file to write (optional).

    Error bars are +-1 Monte Carlo standard error; points of the variants are spread a little
    along x so that their error bars do not hide one another.
    Returns the matplotlib Figure (2 x 3 panels, or 1 x 3 without a reference).
    """
    if x not in ("slope_deg", "p"):
        raise ValueError(f"x must be 'slope_deg' or 'p' (got {x!r})")
    sel = select(rows, kind="plane") if x == "slope_deg" else select(rows, kind="fractal")
    if not sel:
        raise ValueError(f"no rows to plot against {x}")
    names = list(dict.fromkeys(r["variant"] for r in sel)) if variants is None else list(variants)
    rel = relative_to(sel, reference=reference) if reference is not None else []
    nrows = 2 if rel else 1
    xs_all = sorted({r[x] for r in sel})
    fig, axes = plt.subplots(nrows, 3, figsize=(15, 4.3 * nrows + 0.4), dpi=110, squeeze=False,
                             sharex=True)
    _draw_variants(axes, (sel, rel)[:nrows], names, x=x, xs_all=xs_all)
    if x == "slope_deg":
        _draw_closed_form_precision(axes[0][2], instrument or Instrument(beam=sel[0]["beam"]),
                                    xs_all)
    _label_axes(axes, x=x, reference=reference)
    fig.suptitle(_title(sel[0], title), fontsize=11)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path)
        plt.close(fig)
    return fig


def _draw_variants(axes, sources: Sequence[Sequence[dict]], names: Sequence[str], *, x: str,
                   xs_all: Sequence[float]) -> None:
    """Every variant's error bars, in legend order ``names``: the rows (``sources[0]``) on the
    top row of ``axes``, the :func:`relative_to` dicts (``sources[1]``, when given) on the
    bottom row; each variant shifted along ``x`` by a share of 1 % of the span ``xs_all``."""
    span = (xs_all[-1] - xs_all[0]) if len(xs_all) > 1 else 1.0
    dodge = 0.01 * span
    for k, name in enumerate(names):
        colour, marker = STYLES.get(name, (None, "o"))
        off = (k - (len(names) - 1) / 2) * dodge
        for i, source in enumerate(sources):
            rs = sorted((r for r in source if r["variant"] == name), key=lambda r: r[x])
            if not rs:
                continue
            xv = np.array([r[x] for r in rs])
            for j, (ax, panel) in enumerate(zip(axes[i], _PANELS)):
                key, err, scale = panel[0:3] if i == 0 else panel[4:7]
                shift = panel[8] if i == 1 else 0.0
                y = scale * (np.array([r[key] for r in rs]) - shift)
                # no spread for the absolute precision: its error bars are tiny, and a spread
                # along x would read as a difference on the steep curve
                ax.errorbar(xv + (0.0 if (i, j) == (0, 2) else off), y,
                            yerr=scale * np.array([r[err] for r in rs]), color=colour,
                            marker=marker, ms=5, lw=1.2, capsize=2.5, label=name)


def _draw_closed_form_precision(ax, inst: Instrument, xs_all: Sequence[float]) -> None:
    """The ideal detector's precision on a plane, hypot(c sigma_t / 2, sigma_fp tan(slope))
    [cm], dashed over the slopes of ``xs_all`` [deg]; the panel's y axis logarithmic."""
    s = np.linspace(xs_all[0], xs_all[-1], 200)
    closed = np.hypot(inst.ranging_sigma_m, inst.footprint_sigma_m * np.tan(np.radians(s)))
    ax.plot(s, 100 * closed, "--", color="grey", lw=1, label="closed form, ideal detector")
    ax.set_yscale("log")


def _label_axes(axes, *, x: str, reference: str | None) -> None:
    """Axis labels, grids, the reference lines (1 for the ratio, 0 for differences), the
    bias's zero line, the legend and a zero floor for photons per shot."""
    nrows = len(axes)
    xlabel = "surface slope [deg]" if x == "slope_deg" else "fractal spectral exponent p"
    for i in range(nrows):
        for ax, panel in zip(axes[i], _PANELS):
            ax.set_ylabel(panel[3] if i == 0 else panel[7].format(ref=reference))
            ax.grid(alpha=0.3)
            if i == nrows - 1:
                ax.set_xlabel(xlabel)
            if i == 1:
                ax.axhline(1.0 if panel[4] == "photons_ratio" else 0.0, color="grey", lw=0.8)
    axes[0][0].set_ylim(bottom=0)
    axes[0][1].axhline(0.0, color="grey", lw=0.8)
    axes[0][2].legend(fontsize=7.5, loc="best")


def _title(meta: dict, title: str) -> str:
    """The figure's title: ``title`` over the beam, detector and shots of the row ``meta``."""
    det = ("ideal detector (no dead time)" if meta["ideal_detector"]
           else f"{meta['dead_time_ns']:g} ns dead time")
    sub = f"{meta['beam']} beam, {det}, {meta['shots']} shots per point, ±1 s.e."
    return f"{title}\n{sub}" if title else sub
