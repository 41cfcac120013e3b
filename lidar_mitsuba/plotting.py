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
    return _finish_cloud(fig, ax, title=title, path=path, own=own,
                         loc="best", fontsize=8)


def _finish_cloud(fig, ax, *, title: str, path, own: bool, **legend):
    """A photon-cloud panel's axes labelled (along track [m], elevation [m]), titled, its
    legend (``legend``: matplotlib's keywords) and grid drawn; a figure of its ``own`` laid
    out, and saved to ``path`` and closed when one is given. Returns ``fig``."""
    ax.set_xlabel("along-track distance [m]")
    ax.set_ylabel("elevation [m]")
    ax.set_title(title)
    ax.legend(**legend)
    ax.grid(alpha=0.3)
    if own:
        fig.tight_layout()
        if path is not None:
            fig.savefig(path)
            plt.close(fig)
    return fig


def granule_clouds(atl03_path, path, *, max_points: int = 200_000) -> None:
    """One photon-cloud panel per beam of an ATL03 granule written by
    :mod:`lidar_mitsuba.granule` (gt1l on top), read back from the file (at most
    ``max_points`` photons and shots per beam, evenly strided), written to the PNG ``path``."""
    import h5py
    with h5py.File(atl03_path, "r") as f:
        names = sorted(k for k in f if k.startswith("gt"))
        fig, axes = plt.subplots(len(names), 1, figsize=(10, 2.6 * len(names)), dpi=110,
                                 squeeze=False)
        for ax, name in zip(axes[:, 0], names):
            h, geo, t = f[f"{name}/heights"], f[f"{name}/geolocation"], f[f"truth/{name}"]
            n = h["h_ph"].shape[0]
            step = max(1, -(-n // max_points))
            seg = np.repeat(np.arange(geo["segment_ph_cnt"].shape[0]),
                            geo["segment_ph_cnt"][()])[::step]
            along = geo["segment_dist_x"][()][seg] + h["dist_ph_along"][::step]
            ns = t["shots/along_track_m"].shape[0]
            sstep = max(1, -(-ns // max_points))
            sig = t["photons/is_signal"][::step] == 1
            dh = (t["photons/h_m"][()] - t["shots/z_ref_m"][()][t["photons/shot"][()]])[
                t["photons/is_signal"][()] == 1]
            photon_cloud(along_track_m=t["shots/along_track_m"][::sstep],
                         surface_z_m=t["shots/surface_z_m"][::sstep],
                         z_ref_m=t["shots/z_ref_m"][::sstep], photon_along_m=along,
                         photon_h_m=h["h_ph"][::step], is_signal=sig, ax=ax,
                         title=f"{name} (spot {f[name].attrs['atlas_spot_number']}, "
                               f"{f[name].attrs['atlas_beam_type']}): bias "
                               f"{100 * dh.mean():+.1f} cm, precision {100 * dh.std():.1f} cm"
                               + (f" (every {step}th photon drawn)" if step > 1 else ""))
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


#: ATL08 class -> (label, colour) of :func:`classified_cloud` (``classed_pc_flag`` 0-3)
CLASS_STYLE = ((0, "noise", "0.7"), (1, "ground", "saddlebrown"), (2, "canopy", "forestgreen"),
               (3, "top of canopy", "limegreen"))


def classified_cloud(*, photon_along_m: np.ndarray, photon_h_m: np.ndarray,
                     classes: np.ndarray, ground_h_m: np.ndarray | None = None,
                     toc_h_m: np.ndarray | None = None, truth_along_m: np.ndarray | None = None,
                     truth_surface_z_m: np.ndarray | None = None, title: str = "", path=None,
                     ax=None):
    """A photon cloud coloured by ATL08 class (:data:`CLASS_STYLE`; our classifier's
    :class:`~lidar_mitsuba.products.atl08.classify.Classification` or NASA's
    ``classed_pc_flag``), with the classifier's ground and top-of-canopy surfaces at the
    photons (dashed, dotted) and the true ground along the track (blue) where known.

    Args:
        photon_along_m, photon_h_m, classes: (n,) along-track position [m], height [m] and
            class (0 noise, 1 ground, 2 canopy, 3 top of canopy) of each photon.
        ground_h_m, toc_h_m: (n,) the classifier's surfaces at each photon [m] (NaN: none).
        truth_along_m, truth_surface_z_m: (shots,) the true ground along the track [m].
        path: PNG to write (with no ``ax``). Returns the matplotlib Figure.
    """
    own = ax is None
    fig, ax = plt.subplots(figsize=(10, 4), dpi=110) if own else (ax.figure, ax)
    x, h, c = (np.asarray(a) for a in (photon_along_m, photon_h_m, classes))
    for k, label, colour in CLASS_STYLE:
        m = c == k
        ax.plot(x[m], h[m], ".", ms=2.5 if k else 1.5, color=colour, label=f"{label} ({m.sum()})")
    order = np.argsort(x, kind="stable")
    for surf, style, label in ((ground_h_m, "--", "classifier's ground"),
                               (toc_h_m, ":", "classifier's top of canopy")):
        if surf is not None and np.isfinite(surf).any():
            ax.plot(x[order], np.asarray(surf)[order], style, lw=1.0, color="k", label=label)
    if truth_along_m is not None and truth_surface_z_m is not None:
        ax.plot(truth_along_m, truth_surface_z_m, "-", lw=1.0, color="tab:blue",
                label="true ground")
    return _finish_cloud(fig, ax, title=title, path=path, own=own,
                         loc="upper left", fontsize=7, ncol=2, markerscale=3)
