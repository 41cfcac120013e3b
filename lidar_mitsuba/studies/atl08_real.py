"""Our ATL08 classifier on the real forest ATL03 clip beside NASA's ATL08 of it (issue 42).

Validation only: nothing in :mod:`lidar_mitsuba.products.atl08` was set from these files. Per
100 m segment (matched by ``segment_id_beg``): ``h_te_best_fit`` and ``h_canopy`` differences
(median, RMSE), photon counts; per photon: the confusion matrix of the classes, NASA's mapped
to ATL03 photons by ``ph_segment_id`` and ``classed_pc_indx`` (photon ``beg0 + indx - 1``
with ``beg0`` the 0-based first photon of the 20 m segment; every match is checked on
``delta_time``); ATL03 photons NASA's ``signal_photons`` does not list are its noise (0).

Run: ``python -m lidar_mitsuba.studies.atl08_real``.
"""
from __future__ import annotations

import numpy as np

REAL_DIR = "/work/shared/real/"
ATL03 = REAL_DIR + "ATL03_gt1r_20220401_forest_wyoming.h5"
ATL08 = REAL_DIR + "ATL08_gt1r_20220401_forest_wyoming.h5"
F4_FILL = np.finfo(np.float32).max
LAND = ("segment_id_beg", "terrain/h_te_best_fit", "canopy/h_canopy", "terrain/n_te_photons",
        "canopy/n_ca_photons", "canopy/n_toc_photons")
"""What :func:`compare` reads of an ATL08 beam's ``land_segments``."""
PHOTONS = ("ph_segment_id", "classed_pc_indx", "classed_pc_flag", "delta_time")
"""... and of its ``signal_photons`` (in this order)."""


def compare(atl03_path: str = ATL03, atl08_path: str = ATL08, beam: str = "gt1r", *,
            ours=None, settings=None) -> dict:
    """The comparison (module docstring) as a JSON-able dict; ``ours``: our
    :class:`~lidar_mitsuba.products.atl08.Atl08Beam` of the ATL03 beam, if already made;
    ``settings``: the classifier's (:class:`~lidar_mitsuba.products.atl08.Settings`, e.g.
    ``Settings(slope_capped_ground=True)``; default its defaults)."""
    import h5py
    from ..products import atl08
    ours = ours if ours is not None else atl08.from_atl03(atl03_path, beam, settings=settings)
    d = atl08.read_atl03_beam(atl03_path, beam)
    with h5py.File(atl08_path) as f:
        ls, sp = f[f"{beam}/land_segments"], f[f"{beam}/signal_photons"]
        real = {k: ls[k][()] for k in LAND}
        sid, indx, flag, t_real = (sp[k][()] for k in PHOTONS)
    seg = ours.segments
    ids = seg["land_segments/segment_id_beg"]
    j = np.searchsorted(real["segment_id_beg"], ids)
    out = {"n_segments": int(ids.size), "segments": []}
    for key in ("terrain/h_te_best_fit", "canopy/h_canopy"):
        a = seg["land_segments/" + key].astype(np.float64)
        b = real[key][j].astype(np.float64)
        ok = (a < F4_FILL) & (b < F4_FILL)
        dd = a[ok] - b[ok]
        out[key] = {"n": int(ok.sum()), "median_m": float(np.median(dd)) if dd.size else None,
                    "rmse_m": float(np.sqrt(np.mean(dd ** 2))) if dd.size else None}
    for k in range(ids.size):
        out["segments"].append({"segment_id_beg": int(ids[k]), **{
            f"{w}_{key.split('/')[1]}": float(src[key][i]) if src[key][i] < F4_FILL else None
            for w, src, i in (("ours", {x: seg["land_segments/" + x] for x in real}, k),
                              ("nasa", real, j[k]))
            for key in ("terrain/h_te_best_fit", "canopy/h_canopy", "terrain/n_te_photons",
                        "canopy/n_ca_photons", "canopy/n_toc_photons")}})
    out["confusion"] = _confusion(ours, d, sid, indx, flag, t_real)
    return out


def _confusion(ours, d, sid, indx, flag, t_real) -> dict:
    """4 x 4 counts [NASA class, our class] over the ATL03 photons inside 20 m segments."""
    ok = d["segment"] >= 0
    n = d["h_m"].size
    nasa = np.zeros(n, np.int64)
    pos = np.searchsorted(d["seg_id"], sid)
    inside = (pos < d["seg_id"].size) & (d["seg_id"][np.minimum(pos, d["seg_id"].size - 1)]
                                         == sid)
    ph = d["beg0"][pos[inside]] + indx[inside] - 1
    good = (ph >= 0) & (ph < n) & (flag[inside] >= 0) & (flag[inside] <= 3)   # (not fill)
    ph = ph[good]
    matched = np.abs(d["delta_time_s"][ph] - t_real[inside][good]) < 1e-6
    nasa[ph[matched]] = flag[inside][good][matched]
    mine = np.zeros(n, np.int64)
    mine[ok] = ours.classification.classes
    cm = np.zeros((4, 4), np.int64)
    np.add.at(cm, (nasa[ok], mine[ok]), 1)
    return {"matrix_nasa_rows_ours_cols": cm.tolist(), "n_mapped": int(matched.sum()),
            "n_listed": int(sid.size), "agreement": float(np.trace(cm) / max(cm.sum(), 1))}


def table(res: dict) -> str:
    """A short text table of :func:`compare`'s result."""
    lines = ["segment_id_beg  h_te ours  h_te NASA  h_can ours  h_can NASA  n_te o/N  "
             "n_ca+toc o/N"]

    def f(v):
        return "     -" if v is None else f"{v:9.2f}"
    for s in res["segments"]:
        lines.append(f"{s['segment_id_beg']:14d}  {f(s['ours_h_te_best_fit'])}  "
                     f"{f(s['nasa_h_te_best_fit'])}  {f(s['ours_h_canopy'])}   "
                     f"{f(s['nasa_h_canopy'])}  {s['ours_n_te_photons']:.0f}/"
                     f"{s['nasa_n_te_photons']:.0f}  "
                     f"{s['ours_n_ca_photons'] + s['ours_n_toc_photons']:.0f}/"
                     f"{s['nasa_n_ca_photons'] + s['nasa_n_toc_photons']:.0f}")
    for key in ("terrain/h_te_best_fit", "canopy/h_canopy"):
        r = res[key]
        lines.append(f"{key}: n={r['n']} median diff={r['median_m']} m, RMSE={r['rmse_m']} m")
    c = res["confusion"]
    lines.append(f"photon classes (rows NASA 0-3, columns ours 0-3), agreement "
                 f"{c['agreement']:.3f}, NASA photons mapped {c['n_mapped']}/{c['n_listed']}:")
    lines += ["  " + " ".join(f"{v:6d}" for v in row) for row in c["matrix_nasa_rows_ours_cols"]]
    return "\n".join(lines)


def main() -> None:
    print(table(compare()))


if __name__ == "__main__":
    main()


def pairs(paths) -> list[tuple[str, str]]:
    """``(ATL03, ATL08)`` file pairs among ``paths`` (files, or folders: their HDF5 files):
    an ATL08 file and the ATL03 file beside it of the same name with ``ATL03`` for
    ``ATL08`` wherever it stands and in any case (NASA's ``ATL08_...``, the NSIDC
    subsetter's ``processed_ATL08_...``, a clip's ``atl08_clip.h5``), else the one ATL03
    file beside it of the same granule (``YYYYMMDDhhmmss_ttttccss``: the release or
    revision may differ)."""
    import pathlib
    import re
    from .realism import hdf5_files
    files = []
    for p in map(pathlib.Path, paths or []):
        files += hdf5_files(p) if p.is_dir() else [p]
    out = []
    for f in files:
        low = f.name.lower()
        if "atl08" not in low:
            continue
        beside = [g for g in sorted(f.parent.glob("*")) if g.is_file() and g != f]
        want = low.replace("atl08", "atl03", 1)
        twin = next((g for g in beside if g.name.lower() == want), None)
        granule = re.search(r"\d{14}_\d{8}", f.name)
        if twin is None and granule:
            same = [g for g in beside if "atl03" in g.name.lower()
                    and granule.group(0) in g.name and g.suffix.lower() == f.suffix.lower()]
            twin = same[0] if len(same) == 1 else None
        if twin is not None:
            out.append((str(twin), str(f)))
    return out


NEEDS = (tuple(f"land_segments/{k}" for k in LAND)
         + tuple(f"signal_photons/{k}" for k in PHOTONS))
"""What :func:`compare` reads of an ATL08 beam: a beam lacking any (a subset dropped it) is
passed by, said in one line."""


def run(paths, out_dir, *, progress=print) -> list[dict]:
    """:func:`compare` on every ATL03/ATL08 pair among ``paths`` (:func:`pairs`), every beam
    both have; writes ``atl08_real.md`` and ``atl08_real.json`` to ``out_dir`` when there is
    one. Returns the results."""
    import json
    import pathlib
    import h5py
    from ..products.atl08 import atl03_lacks
    from .forest_twin import UNREADABLE
    results = []
    for a03, a08 in pairs(paths):
        with h5py.File(a08) as f8, h5py.File(a03) as f3:
            beams = [b for b in f8 if b.startswith("gt") and f"{b}/heights/h_ph" in f3
                     and f"{b}/signal_photons" in f8]               # a clip's empty beams
            lacks = {b: [n for n in NEEDS if f"{b}/{n}" not in f8]
                     + [f"ATL03 {n}" for n in atl03_lacks(f3[b])] for b in beams}
        for beam in beams:
            if lacks[beam]:
                if progress is not None:
                    progress(f"ATL08 classifier on {pathlib.Path(a03).name} {beam}: passed "
                             f"by, the pair lacks {', '.join(lacks[beam])}")
                continue
            if progress is not None:
                progress(f"ATL08 classifier on {pathlib.Path(a03).name} {beam} against "
                         "NASA's ATL08")
            try:
                r = compare(a03, a08, beam)
            except UNREADABLE as e:      # fill where a time, place or index should be
                if progress is not None:
                    progress(f"ATL08 classifier on {pathlib.Path(a03).name} {beam}: passed "
                             f"by, the pair cannot be read ({type(e).__name__}: {e})")
                continue
            r.update({"atl03": pathlib.Path(a03).name, "atl08": pathlib.Path(a08).name,
                      "beam": beam})
            results.append(r)
    if results:
        out = pathlib.Path(out_dir)
        (out / "atl08_real.json").write_text(json.dumps(results, indent=1))
        text = ["# Our ATL08 classifier against NASA's ATL08", "",
                "Validation only: no constant of lidar_mitsuba.products.atl08 was set from "
                "these files (docs/guide/atl08.md).", ""]
        for r in results:
            text += [f"## {r['atl03']} {r['beam']}", "", "```", table(r), "```", ""]
        (out / "atl08_real.md").write_text("\n".join(text))
    return results
