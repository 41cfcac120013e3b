"""A granule's ATL08 beside its ATL03 and ATL06 (issue 42): :func:`write_from_atl03` classifies
every beam of a simulated (or real) ATL03 file with our ATL08 classifier and writes their
100 m land segments as one ATL08 file. :func:`lidar_mitsuba.granule.stream_granule` calls it
once its ATL03 file is complete (``atl08_path=``): one separate step after the simulation,
on the file as any reader sees it.
"""
from __future__ import annotations

import os
import pathlib


def atl03_beams(atl03_path: str | os.PathLike) -> list[str]:
    """The beam groups (``gt1l`` ... ``gt3r``) of an ATL03 file that hold photons."""
    import h5py
    with h5py.File(atl03_path, "r") as f:
        return [b for b in sorted(f) if b.startswith("gt") and "heights" in f[b]
                and f[f"{b}/heights/h_ph"].size > 0]


def write_from_atl03(atl03_path: str | os.PathLike, atl08_path: str | os.PathLike, *,
                     beams: list[str] | None = None, instrument=None) -> pathlib.Path:
    """Our ATL08 of ``beams`` (default: every beam with photons) of ``atl03_path``, written
    to ``atl08_path`` atomically (:func:`lidar_mitsuba.products.atl08.write`; ``instrument``:
    the ATLAS of its METADATA)."""
    from . import from_atl03, write
    names = atl03_beams(atl03_path) if beams is None else list(beams)
    return write([from_atl03(atl03_path, b) for b in names], atl08_path,
                 instrument=instrument)
