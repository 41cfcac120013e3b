"""The cost of a cloud in a granule (``bench``'s ``cloud`` row): the same six-beam granule
over the synthetic ice sheet of :mod:`.track_length`, streamed to ATL03 and ATL06, clear and
under a water cloud (tau 1, 1-1.5 km), each timed after a warm-up (kernels compiled, the
cloud's table made once and cached: its own time is reported apart; ``quick``: 0.3 km, no
warm-up, the cloudy run first, a table of 32 000 paths), and both against the
time the granule's rays take to cast alone (:func:`.track_length.cast_time`: the granule's own
ray count, as the ``granule`` row's ``of_cast``)."""
from __future__ import annotations

import pathlib
import statistics
import tempfile
import time

from . import track_length

CLOUD = dict(optical_depth=1.0, base_m=1000.0, top_m=1500.0)


def _granule_s(surf, track, shots: int, cloud, tmp: pathlib.Path, repeats: int):
    from .. import granule
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = granule.stream_granule(surface=surf, track=track, shots=shots, beams="all",
                                     max_depth=1, progress=False, paths_per_shot="auto",
                                     atl03_path=tmp / "a3.h5", atl06_path=tmp / "a6.h5",
                                     **({} if cloud is None else {"cloud": cloud}))
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def run(*, quick: bool) -> dict:
    """One row: seconds clear and cloudy, their ratio, the cloud table's seconds, and each
    run's time over its rays cast alone."""
    from ..atmosphere import cloud_kernel
    from ..atmosphere.cloud_layer import Cloud
    from ..instrument import Instrument
    km = 0.3 if quick else 10.0
    shots = int(round(km * 1e3 / 0.7))
    repeats = 1 if quick else 3
    cloud = Cloud.water(**CLOUD)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        surf, track = track_length.ice_sheet(tmp, km)
        t0 = time.perf_counter()
        small = {"shots": 500, "paths_per_shot": 64} if quick else {}   # (quick: a small table)
        table = cloud_kernel.table_for(cloud, Instrument(), **small)   # the paper's geometry
        table_s = time.perf_counter() - t0
        if quick:            # the runs use it: the module's size for this study only
            sizes = cloud_kernel.SHOTS, cloud_kernel.PATHS
            cloud_kernel.SHOTS, cloud_kernel.PATHS = table.shots, table.paths_per_shot
        if not quick:            # (quick: the cloudy run first, any compiling charged to it)
            _granule_s(surf, track, min(shots, 300), cloud, tmp, 1)      # warm-up
        try:
            cloud_s, _ = _granule_s(surf, track, shots, cloud, tmp, repeats)
        finally:
            if quick:
                cloud_kernel.SHOTS, cloud_kernel.PATHS = sizes
        clear_s, out = _granule_s(surf, track, shots, None, tmp, repeats)
        rays = track_length.granule_rays(out)
        cast = track_length.cast_time(surf, track, rays=rays, shots=shots,
                                      paths_per_shot=out[0].config["paths_per_shot"])
    cast_s = cast["cast_s"]
    return {"length_km": km, "beams": len(out), "shots": shots, "cloud": CLOUD,
            "clear_s": clear_s, "cloud_s": cloud_s, "cloud_over_clear": cloud_s / clear_s,
            "table_s": table_s, "rays": rays, **cast,
            "clear_of_cast": clear_s / cast_s, "cloud_of_cast": cloud_s / cast_s,
            "repeats": repeats}
