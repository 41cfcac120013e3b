"""Small synthetic ICESat-2 subsets shared by the hold-out rounds' tests
(``tests/test_real_unseen3.py``, ``tests/test_real_unseen4.py``). Pure h5py."""
from __future__ import annotations

import numpy as np


def atl06_pair(path, *, release: str | None = None, version: str | None = None, dem: int = 2,
               asr=0, atm=0, n: int = 8):
    """An ATL06 beam pair (gt1l weak, gt1r strong; ``n`` segments over the Juneau Icefield)
    as NSIDC's subsets of release 001 keep it: both cloud flags (``asr``, ``atm``) on every
    segment, ``dem_flag`` ``dem`` (2 ``gmted``: land; 4 ``antarctic``: land ice), r_eff 0.08,
    a 1.7 MHz background. ``release``: written as ``ancillary_data/release`` (none: no
    ``ancillary_data``); ``version``: as ``METADATA/DatasetIdentification``'s ``VersionID``,
    as a trajectory subsetter keeps it (none: no ``METADATA``)."""
    import h5py
    with h5py.File(path, "w") as f:
        if release is not None:
            f["ancillary_data/release"] = np.bytes_(release.encode())
        if version is not None:
            f.create_group("METADATA/DatasetIdentification").attrs["VersionID"] = \
                np.bytes_(version.encode())
        for name in ("gt1l", "gt1r"):
            g = f.create_group(name)
            g.attrs["atlas_beam_type"] = "weak" if name == "gt1l" else "strong"
            s = g.create_group("land_ice_segments")
            s["delta_time"] = 2.4e7 + np.arange(n) * 20.0 / 7000.0
            s["latitude"] = 58.5 + np.arange(n) * 20.0 / 111_000.0
            s["longitude"] = np.full(n, -134.2)
            s["h_li"] = np.full(n, 1400.0, np.float32)
            s["geophysical/bckgrd"] = np.full(n, 1.7e6, np.float32)
            s["geophysical/r_eff"] = np.full(n, 0.08, np.float32)
            s["geophysical/cloud_flg_asr"] = np.full(n, asr, np.int8)
            s["geophysical/cloud_flg_atm"] = np.full(n, atm, np.int8)
            d = s.create_dataset("dem/dem_flag", data=np.full(n, dem, np.int8))
            d.attrs["flag_meanings"] = np.bytes_(b"none gimp gmted mss antarctic")
            d.attrs["flag_values"] = np.arange(5, dtype=np.int8)
            s["dem/dem_h"] = np.full(n, 1400.0, np.float32)
            s["dem/geoid_h"] = np.full(n, 5.0, np.float32)
    return path
