"""A granule writes ATL03, ATL06 and our ATL08 together (``stream_granule(atl08_path=...)``,
:mod:`lidar_mitsuba.products.atl08.granule`), issue 42."""
from __future__ import annotations

import h5py
import numpy as np

import lidar_mitsuba as lm


def test_a_granule_writes_atl03_atl06_and_atl08_together(tmp_path):
    """Two beams, 300 shots each (two 100 m land segments) over the test DEM: the ATL08 file
    holds both beams' land segments, on the ATL03's 20 m segment ids, and its terrain lies on
    the DEM's true surface (bare snow: the segments' h_te_best_fit within 0.5 m of the true
    surface under their shots; the pulse spreads 0.1 m, a segment fits ~100 ground photons)."""
    from lidar_mitsuba import granule
    from lidar_mitsuba.ground import dem as dems
    path = dems.synthetic_ice_sheet(tmp_path / "ice.tif")
    surf = dems.DEMSurface(dems.DEM.open(path), tile_shots=512)
    track = lm.GeoTrack(start_lat_deg=69.97, start_lon_deg=-45.0, azimuth_deg=0.0)
    a3, a6, a8 = tmp_path / "a3.h5", tmp_path / "a6.h5", tmp_path / "a8.h5"
    granule.stream_granule(surface=surf, track=track, shots=300, beams="gt1l,gt1r",
                           atl03_path=a3, atl06_path=a6, atl08_path=a8, seed=1,
                           progress=False, max_depth=1)
    assert a3.exists() and a6.exists()
    with h5py.File(a8) as f, h5py.File(a3) as f3:
        for beam in ("gt1l", "gt1r"):
            ls = f[f"{beam}/land_segments"]
            ids = ls["segment_id_beg"][()]
            assert ids.size >= 2 and np.isin(ids, f3[f"{beam}/geolocation/segment_id"][()]).all()
            h = ls["terrain/h_te_best_fit"][()].astype(float)
            truth = f[f"truth/{beam}/land_segments/h_surface_true"][()]
            ok = h < np.finfo(np.float32).max
            assert ok.all(), beam
            assert np.abs(h - truth).max() < 0.5, (beam, h - truth)
