"""Reproduce the paper's results section (Zhang & Kerekes, Figs. 3-13) and compare with it.

``lidar-mitsuba reproduce --out DIR [--quick] [--profile FILE]`` (or :func:`run`) regenerates
every figure of the paper's results at the paper's own sample counts (200 000 shots on the flat
plate, 50 000 per slope, one 1000-shot track per fractal scene) and writes ``DIR/report.md`` and
``DIR/report.json``: per figure, the quantity, our value with its Monte Carlo error, the paper's
stated value or trend, and whether they agree (and, where they do not, why).

Every run is seeded: the same command gives the same numbers. Each *primary* number is what one
:func:`~lidar_mitsuba.run.simulate` call gives (the report prints its CLI equivalent). Other
detectors on the same traced photons cost only the detector: :func:`redetect` reruns the PMT on a
run's kept returns, and :func:`flat_plate_tracks` (Fig. 7, 200,000 shots) runs several detectors
on one trace chunk by chunk without keeping it; both give exactly what ``simulate`` would give
for that detector with the same seed (tests check this).

Monte Carlo errors: bias SE = std / sqrt(n), std SE from the photons' kurtosis
(:func:`lidar_mitsuba.products.retrieval.std_standard_error`; std / sqrt(2 (n - 1)) for normal
residuals), n the photons. On a
single 1000-shot fractal track the photon noise is not the whole story: the terrain under that
one track is one realisation, so every complex-surface configuration is also run over
``terrain_seeds`` independent fractal realisations (ours, not the paper's) and the report gives
their mean, their scatter and the standard error of the mean.

One module per section of the paper, each holding the compute (``fig*``), the plot
(``plot_fig*``, returning the matplotlib Figure) and the agreement rows (``rows_fig*``) of its
figures side by side: :mod:`.terrain_figs` (Figs. 3-5), :mod:`.brdf_fig` (Fig. 6),
:mod:`.plates` (Figs. 7-9), :mod:`.complex_surfaces` (Figs. 10-12), :mod:`.albedo` (Fig. 13);
:mod:`.common` holds the counts, seeds, tracks and statistics they share and :mod:`.report`
the report and :func:`run`. The notebook ``notebooks/00-reproduce-paper.ipynb`` walks
through them.
"""
from .albedo import fig13_albedo, plot_fig13, rows_fig13
from .brdf_fig import fig6_brdf, plot_fig6, rows_fig6
from .common import (FULL, PAPER, PNG, QUICK, SEEDS, TITLES, Counts, Track, counts_for,
                     flat_plate_tracks, redetect, return_offset_m, track_of)
from .complex_surfaces import (fig10_12_complex, plot_fig10, plot_fig11, plot_fig12, rows_fig10,
                               rows_fig11, rows_fig12)
from .plates import (fig7_flat, fig8_9_slopes, plot_fig7, plot_fig8, plot_fig9, rows_fig7,
                     rows_fig8, rows_fig9)
from .report import agreement_rows, format_markdown, format_summary, headline, markdown_table, run
from .terrain_figs import (fig3_spectra, fig4_surfaces, fig5_rms, fit_profile, load_profile,
                           plot_fig3, plot_fig4, plot_fig5, rows_fig3, rows_fig4, rows_fig5)

__all__ = [
    "Counts",
    "FULL",
    "PAPER",
    "PNG",
    "QUICK",
    "SEEDS",
    "TITLES",
    "Track",
    "agreement_rows",
    "counts_for",
    "fig10_12_complex",
    "fig13_albedo",
    "fig3_spectra",
    "fig4_surfaces",
    "fig5_rms",
    "fig6_brdf",
    "fig7_flat",
    "fig8_9_slopes",
    "fit_profile",
    "flat_plate_tracks",
    "format_markdown",
    "format_summary",
    "headline",
    "load_profile",
    "markdown_table",
    "plot_fig10",
    "plot_fig11",
    "plot_fig12",
    "plot_fig13",
    "plot_fig3",
    "plot_fig4",
    "plot_fig5",
    "plot_fig6",
    "plot_fig7",
    "plot_fig8",
    "plot_fig9",
    "redetect",
    "return_offset_m",
    "rows_fig10",
    "rows_fig11",
    "rows_fig12",
    "rows_fig13",
    "rows_fig3",
    "rows_fig4",
    "rows_fig5",
    "rows_fig6",
    "rows_fig7",
    "rows_fig8",
    "rows_fig9",
    "run",
    "track_of",
]
