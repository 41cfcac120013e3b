"""Figures. matplotlib's backend is left as the session chose it (a notebook's inline backend,
or Agg, which matplotlib falls back to where there is no display); every figure is saved and
closed when given a path, and returned."""
from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np


def photon_cloud(*, along_track_m: np.ndarray, surface_z_m: np.ndarray, z_ref_m: np.ndarray,
                 photon_along_m: np.ndarray, photon_h_m: np.ndarray,
                 is_signal: np.ndarray | None = None, title: str = "",
                 path=None, max_points: int = 200_000, ax=None):
    """The paper's Fig. 10: detected photons over the along-track surface profile.

    Args:
        along_track_m, surface_z_m, z_ref_m: (n_shots,) footprint centres' along-track
            distance, surface height at the centre and reference elevation [m].
        photon_along_m, photon_h_m: (n_photons,) photon along-track position and elevation [m].
        is_signal: (n_photons,) truth; noise photons are drawn in grey.
        path: PNG file to write (optional). Returns the matplotlib Figure.
        ax: draw into these axes instead of a new figure (``path`` is then ignored).
    """
    own = ax is None
    if own:
        fig, ax = plt.subplots(figsize=(10, 4), dpi=120)
    else:
        fig = ax.figure
    k = photon_h_m.size
    sel = np.arange(k) if k <= max_points else np.sort(np.random.default_rng(0).choice(k, max_points, False))
    sig = np.ones(k, bool) if is_signal is None else np.asarray(is_signal, bool)
    noise = sel[~sig[sel]]
    if noise.size:
        ax.plot(photon_along_m[noise], photon_h_m[noise], ".", ms=2, color="0.6",
                label=f"noise photons ({int((~sig).sum())})")
    sel = sel[sig[sel]]
    ax.plot(photon_along_m[sel], photon_h_m[sel], ".", ms=2, color="tab:red",
            label=f"signal photons ({int(sig.sum())})")
    ax.plot(along_track_m, surface_z_m, "-", lw=1.0, color="tab:blue",
            label="surface along track")
    ax.plot(along_track_m, z_ref_m, "-", lw=1.0, color="k", alpha=0.6,
            label="reference elevation (footprint mean)")
    ax.set_xlabel("along-track distance [m]")
    ax.set_ylabel("elevation [m]")
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8)
    ax.grid(alpha=0.3)
    if own:
        fig.tight_layout()
        if path is not None:
            fig.savefig(path)
            plt.close(fig)
    return fig


def granule_clouds(granule, path) -> None:
    """One photon-cloud panel per beam of a :class:`~lidar_mitsuba.granule.Granule`, stacked
    left to right across track (gt1l on top), written to the PNG ``path``."""
    runs = granule.beams
    fig, axes = plt.subplots(len(runs), 1, figsize=(10, 2.6 * len(runs)), dpi=110,
                             squeeze=False)
    for ax, r in zip(axes[:, 0], runs):
        res, d = r.result, r.result.detections
        rep = res.report().overall
        photon_cloud(along_track_m=res.along_track_m, surface_z_m=res.surface_z_m,
                     z_ref_m=res.z_ref_m, photon_along_m=res.along_track_m[d.shot],
                     photon_h_m=res.h_m, is_signal=d.is_signal, ax=ax,
                     title=f"{r.beam.name} (spot {r.beam.spot}, {r.beam.strength}): bias "
                           f"{100 * rep.bias_m:+.1f} cm, precision {100 * rep.std_m:.1f} cm")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
