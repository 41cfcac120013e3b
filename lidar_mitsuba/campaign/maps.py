"""A campaign's map: bias and precision of ATL06 ``h_li`` per along-track bin of segments,
over the DEM's hillshade, in the DEM's projection (:func:`plot_map`); and the bins themselves
(:func:`bins`)."""
from __future__ import annotations

import math

import numpy as np

#: longest side [pixels] of the DEM read for the background (decimated by rasterio)
BACKGROUND_PX = 400
#: fewest good segments for a bin's precision
MIN_SEGMENTS = 3


def bins(segments, *, bin_m: float, crs) -> "object":
    """Good segments (flag 0, finite error) binned along each beam of each granule by
    ``floor(x_atc / bin_m)``: a DataFrame of ``task_index``, ``beam``, ``bin``, ``x``, ``y``
    (mean position in ``crs`` [m]), ``bias_m`` (mean error), ``std_m`` (its standard
    deviation, NaN below :data:`MIN_SEGMENTS`), ``n``, and the mean ``grain_um``."""
    import pandas as pd
    from pyproj import Transformer
    d = segments[(segments["atl06_quality_summary"] == 0) & np.isfinite(segments["error"])]
    if d.empty:
        return pd.DataFrame(columns=["task_index", "beam", "bin", "x", "y", "bias_m", "std_m",
                                     "n", "grain_um"])
    x, y = Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(
        d["longitude"].to_numpy(), d["latitude"].to_numpy())
    d = d.assign(x=x, y=y, bin=np.floor(d["x_atc"].to_numpy() / bin_m).astype(np.int64))
    g = d.groupby(["task_index", "beam", "bin"], sort=True)
    out = g.agg(x=("x", "mean"), y=("y", "mean"), bias_m=("error", "mean"),
                std_m=("error", "std"), n=("error", "size"),
                grain_um=("grain_um", "mean")).reset_index()
    out.loc[out["n"] < MIN_SEGMENTS, "std_m"] = math.nan
    return out


def _hillshade(z: np.ndarray, cell_m: float) -> np.ndarray:
    """Lambertian hillshade (sun from the north-west, 45 deg up) of ``z`` (rows north to
    south) with square cells of ``cell_m`` [m], its relief exaggerated until the steepest
    slopes (95th percentile) reach 0.5: an ice sheet's 0.5 % slopes show. NaN stays NaN."""
    gy, gx = np.gradient(z, cell_m)
    gy = -gy                                   # rows run south: d/dy is minus d/drow
    steep = np.nanpercentile(np.hypot(gx, gy), 95) if np.isfinite(gx).any() else 0.0
    k = float(np.clip(0.5 / steep, 1.0, 1e3)) if steep > 0 else 1.0
    gx, gy = k * gx, k * gy
    az, alt = math.radians(315.0), math.radians(45.0)
    lx, ly, lz = math.sin(az) * math.cos(alt), math.cos(az) * math.cos(alt), math.sin(alt)
    return (lz - lx * gx - ly * gy) / np.sqrt(1.0 + gx * gx + gy * gy)


def _read_decimated(path):
    """``(z, extent, cell_m, crs)`` of a GeoTIFF read at most :data:`BACKGROUND_PX` pixels
    on a side (nodata as NaN); extent ``(x0, x1, y0, y1)`` [m] for ``imshow``."""
    import rasterio
    with rasterio.open(path) as ds:
        k = max(1, math.ceil(max(ds.width, ds.height) / BACKGROUND_PX))
        shape = (max(2, ds.height // k), max(2, ds.width // k))
        z = ds.read(1, out_shape=shape, masked=True).astype(np.float64).filled(np.nan)
        b = ds.bounds
        cell = (b.right - b.left) / shape[1]
        return z, (b.left, b.right, b.bottom, b.top), cell, ds.crs


def _background(ax, dems: list[str]):
    """Draw each DEM (in the first's CRS) as hillshade with elevation contours; its CRS."""
    crs = None
    for path in dems:
        z, extent, cell, c = _read_decimated(path)
        if crs is not None and c != crs:
            continue
        crs = c
        shade = _hillshade(z, cell)
        lo, hi = (np.nanpercentile(shade, [1, 99]) if np.isfinite(shade).any() else (0, 1))
        ax.imshow(shade, extent=extent, cmap="gray", vmin=lo - 1.5 * (hi - lo),
                  vmax=hi + 0.1 * (hi - lo), origin="upper", interpolation="bilinear")
        x = np.linspace(extent[0], extent[1], z.shape[1])
        y = np.linspace(extent[3], extent[2], z.shape[0])
        if np.isfinite(z).sum() > 4:
            cs = ax.contour(x, y, z, levels=8, colors="0.35", linewidths=0.4)
            ax.clabel(cs, fontsize=6, fmt="%.0f m")
    return crs


def _raster_contours(ax, path, label: str) -> None:
    z, extent, _, _ = _read_decimated(path)
    if np.isfinite(z).sum() < 4 or np.nanmax(z) == np.nanmin(z):
        return
    x = np.linspace(extent[0], extent[1], z.shape[1])
    y = np.linspace(extent[3], extent[2], z.shape[0])
    cs = ax.contour(x, y, z, levels=6, colors="darkgreen", linewidths=0.8, linestyles="--")
    ax.clabel(cs, fontsize=7, fmt=f"%.0f {label}")


def plot_map(segments, *, dems: list[str], bin_m: float, path=None, title: str = "",
             grain_raster: str | None = None):
    """Two panels over the DEM(s) in the first DEM's projection: the bias (mean ``h_li`` -
    truth) and the precision (its standard deviation) of each along-track bin of ``bin_m``
    [m] (:func:`bins`), in cm, with every beam's track drawn and, given ``grain_raster``,
    the grain size's contours. Writes ``path`` (PNG) when given; returns the Figure."""
    from ..plotting import plt
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5), dpi=90, sharex=True, sharey=True)
    for ax, (key, name, cmap) in zip(axes, (("bias_m", "bias: mean h_li - truth", "RdBu_r"),
                                            ("std_m", "precision: std of h_li - truth",
                                             "viridis"))):
        crs = _background(ax, dems)
        b = bins(segments, bin_m=bin_m, crs=crs)
        _tracks(ax, segments, crs)
        v = 100.0 * b[key].to_numpy(np.float64)
        ok = np.isfinite(v)
        kw = _colours(v[ok], key, cmap)
        sc = ax.scatter(b["x"][ok], b["y"][ok], c=v[ok], s=22, edgecolors="k",
                        linewidths=0.3, zorder=3, **kw)
        fig.colorbar(sc, ax=ax, shrink=0.8, label=f"{name} [cm]")
        if grain_raster:
            _raster_contours(ax, grain_raster, "um")
        ax.set_title(f"{name}, per {bin_m:g} m of track", fontsize=10)
        ax.set_xlabel(f"x [km] ({crs.to_string() if crs else ''})")
        ax.set_aspect("equal")
        km = plt.FuncFormatter(lambda v, _: f"{v / 1e3:g}")
        ax.xaxis.set_major_formatter(km)
        ax.yaxis.set_major_formatter(km)
    axes[0].set_ylabel("y [km]")
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path)
        plt.close(fig)
    return fig


def _colours(v: np.ndarray, key: str, cmap: str) -> dict:
    """``scatter``'s colour keywords: the 2nd to 98th percentile of ``v``; a bias spanning
    zero on a diverging map centred there, one of a single sign on a sequential map."""
    from matplotlib.colors import Normalize, TwoSlopeNorm
    lo, hi = (np.percentile(v, [2, 98]) if v.size else (0.0, 1.0))
    lo, hi = float(lo), float(max(hi, lo + 0.1))
    if key != "bias_m":
        return {"cmap": cmap, "norm": Normalize(0.0, hi)}
    if lo < 0 < hi:
        return {"cmap": cmap, "norm": TwoSlopeNorm(0.0, lo, hi)}
    return {"cmap": "viridis" if lo >= 0 else "viridis_r", "norm": Normalize(lo, hi)}


def _tracks(ax, segments, crs) -> None:
    """Every beam of every granule as a thin line through its segment centres."""
    from pyproj import Transformer
    if segments.empty:
        return
    to = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    for _, s in segments.groupby(["task_index", "beam"], sort=True):
        x, y = to.transform(s["longitude"].to_numpy(), s["latitude"].to_numpy())
        ax.plot(x, y, color="k", lw=0.6, alpha=0.6, zorder=2)
