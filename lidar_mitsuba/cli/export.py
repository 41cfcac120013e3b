"""``export-las`` (an ATL03 file's photons as LAS/LAZ, :mod:`lidar_mitsuba.products.las`) and
``atl08`` (our ATL08-like product of an ATL03 file, :mod:`lidar_mitsuba.products.atl08`)."""
from __future__ import annotations

from ..products.real import BEAM_NAMES as BEAMS
from .args import UsageError, out_path, read_input


def add_parsers(sub) -> None:
    e = sub.add_parser("export-las", help="an ATL03 file's photons as LAS/LAZ for point-cloud "
                       "tools (PDAL, CloudCompare)", description="Write every photon of an "
                       "ATL03 file (ours or NASA's) as LAS 1.4 point format 6: longitude, "
                       "latitude, ellipsoidal height (EPSG:4979 WKT), GPS time, ASPRS class "
                       "(ground 2, vegetation 4/5, noise 7 by our ATL08 classifier; or "
                       "signal 1 / noise 7 by ATL03's confidence), beam spot as point source, "
                       "confidence as user data, photon rank in its shot as return number.")
    e.add_argument("file", metavar="ATL03.h5", help="ATL03 file")
    e.add_argument("--out", required=True, metavar="FILE.laz",
                   help=".las or .laz (compressed) to write")
    e.add_argument("--beams", metavar="LIST", help="comma-separated beams (default: all)")
    e.add_argument("--no-classify", action="store_true", help="classes from ATL03's signal "
                   "confidence instead of our ATL08 classifier")
    a = sub.add_parser("atl08", help="our ATL08-like land and canopy product of an ATL03 file",
                       description="Classify an ATL03 file's photons (noise, ground, canopy, "
                       "top of canopy) and write 100 m terrain and canopy segments laid out as "
                       "NASA's ATL08 (docs/guide/atl08.md).")
    a.add_argument("file", metavar="ATL03.h5", help="ATL03 file (ours or NASA's)")
    a.add_argument("--out", required=True, metavar="FILE.h5", help="ATL08-like HDF5 to write")
    a.add_argument("--beams", metavar="LIST", help="comma-separated beams (default: all)")
    a.add_argument("--plot", metavar="FILE.png", help="also draw each beam's photons coloured "
                   "by class, with the ground and top of canopy found (and the true ground "
                   "of our own files)")


def _beams(text: str | None) -> list[str] | None:
    if text is None:
        return None
    beams = [b.strip() for b in text.split(",") if b.strip()]
    bad = [b for b in beams if b not in BEAMS]
    if not beams or bad:
        raise UsageError("--beams", f"{text!r}: give beams of {', '.join(BEAMS)}")
    return beams


def cmd_export_las(a) -> int:
    from ..products import las
    out = out_path(a.out, (".las", ".laz"))
    pts = read_input(a.file, lambda p: las.photons(p, beams=_beams(a.beams),
                                                   classify=not a.no_classify))
    las.write(pts, out)
    print(f"wrote {out} ({pts['lon'].size} photons)")
    return 0


def cmd_atl08(a) -> int:
    import h5py
    from ..products import atl08, las
    out = out_path(a.out, (".h5",))
    plot = out_path(a.plot, (".png",), "--plot") if a.plot else None   # (before any output)
    beams = _beams(a.beams) or read_input(a.file, lambda p: las._beams_in(h5py.File(p, "r")))
    made = [read_input(a.file, lambda p, b=b: atl08.from_atl03(p, b)) for b in beams]
    atl08.write(made, out)
    print(f"wrote {out} ({', '.join(f'{m.beam}: {len(m)} segments' for m in made)})")
    if plot is not None:
        _plot_classes(a.file, made, plot)
        print(f"wrote {plot}")
    return 0


def _plot_classes(atl03_path, made, path) -> None:
    """One :func:`~lidar_mitsuba.plotting.classified_cloud` panel per beam, to ``path``."""
    import matplotlib.pyplot as plt
    from ..plotting import classified_cloud
    from ..products import atl08
    fig, axes = plt.subplots(len(made), 1, figsize=(10, 3.6 * len(made)), dpi=110,
                             squeeze=False)
    for ax, m in zip(axes[:, 0], made):
        d = atl08.read_atl03_beam(atl03_path, m.beam)
        c = m.classification
        classified_cloud(photon_along_m=d["x_m"][m.atl03_index], photon_h_m=c.h_m,
                         classes=c.classes, ground_h_m=c.ground_h_m, toc_h_m=c.toc_h_m,
                         truth_along_m=d.get("truth_along_m"),
                         truth_surface_z_m=d.get("truth_surface_z_m"), ax=ax,
                         title=f"{m.beam}: photons classed by our ATL08 classifier")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
