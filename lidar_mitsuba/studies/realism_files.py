"""Which real files the realism matrix reads (:mod:`lidar_mitsuba.studies.realism`): the
files and folders named (a folder's HDF5 files by their names), each file's name in the
matrix, and the forest twins of the ATL03 + ATL08 pairs among them."""
from __future__ import annotations

import pathlib

from ..constants import ParameterError
from ..products.real import HDF5_SUFFIXES

PACKAGE_DATA = pathlib.Path(__file__).resolve().parents[1] / "data"
"""The real files the package ships (``validate --real`` with no file)."""


def hdf5_files(folder) -> list[pathlib.Path]:
    """The files of ``folder`` named as HDF5 files (:data:`HDF5_SUFFIXES`), sorted."""
    return sorted(p for p in pathlib.Path(folder).iterdir()
                  if p.suffix.lower() in HDF5_SUFFIXES and p.is_file())


def real_files(paths=None, *, found=None) -> list[pathlib.Path]:
    """The HDF5 files among ``paths`` (files or folders; folders give their files named as
    HDF5 files, :func:`hdf5_files`); ``None`` or empty: the package's shipped real files.
    ``found``: a list that receives the files found in folders (not named themselves:
    :func:`~lidar_mitsuba.studies.realism.run` passes by those it cannot read)."""
    if not paths:
        paths = [PACKAGE_DATA]
    out = []
    for p in map(pathlib.Path, paths):
        if p.is_dir():
            inside = hdf5_files(p)
            out += inside
            if found is not None:
                found += inside
        elif p.is_file():
            out.append(p)
        else:
            raise ParameterError("real", f"{p}: no such file or folder")
    seen: set = set()                     # a file named twice (itself and in its folder): once
    out = [p for p in out if not (p.resolve() in seen or seen.add(p.resolve()))]
    if not out:
        raise ParameterError("real", f"no HDF5 file ({', '.join(HDF5_SUFFIXES)}) in "
                             f"{', '.join(map(str, paths))}")
    return out


def labels(paths) -> dict:
    """Each file's name in the matrix: its name, or where two files of ``paths`` share it
    (subsets of one granule in two folders: ``a/processed_ATL06_X.h5``, ``b/...``) as much
    of its path as tells them apart."""
    paths = [pathlib.Path(p) for p in paths]
    depth = dict.fromkeys(paths, 1)
    while True:
        lab = {p: "/".join(p.parts[-depth[p]:]) for p in paths}
        count: dict = {}
        for v in lab.values():
            count[v] = count.get(v, 0) + 1
        clash = [p for p in paths if count[lab[p]] > 1 and depth[p] < len(p.parts)]
        if not clash:
            return lab
        for p in clash:
            depth[p] += 1


def _forest_twins(paths, *, signal_shots: int, seed: int, progress):
    """``(docs, by_row, paired)``: the forest twins of the ATL03 + ATL08 forest pairs among
    ``paths`` (:func:`~lidar_mitsuba.studies.forest_twin.twins`, every shot of the clip, seed
    ``seed + 1``; none with ``signal_shots`` 0), the docs by the matrix rows they judge
    (``(file, beam)``, the file by its whole path: two clips of one name in two folders are
    two pairs), and the files in a pair (their whole paths)."""
    from . import forest_twin
    from .atl08_real import pairs
    found = pairs(paths)
    paired = {_whole(f) for pair in found for f in pair}
    if signal_shots <= 0 or not found:
        return [], {}, paired
    docs, by_row = [], {}
    for a03, a08 in found:
        twins = forest_twin.twins([a08], seed=seed + 1, progress=progress)
        docs += twins
        for d in twins:
            for f in (a03, a08):
                by_row[(_whole(f), d["beam"])] = d
    return docs, by_row, paired


def _whole(path) -> str:
    """A file's whole path, as the forest rows are keyed."""
    return str(pathlib.Path(path).resolve())
