"""Snow's optics against ICESat-2's validated accuracy: the sensitivity of ATL06 ``h_li`` to
each optical choice (``bench``; ``docs/guide/snow.md``).

ATLAS as flown (:meth:`~lidar_mitsuba.instrument.Instrument.atlas`, strong and weak beam) over a
flat, semi-infinite snowpack on the East Antarctic plateau in the polar night (no solar
background: the snow's delay alone), traced with the snow kernel
(:mod:`lidar_mitsuba.ground.snow.kernel`), ATL06 segments against the surface. One row per change
from the baseline (100 um, 350 kg/m^3, the module's default optics: natural snow, g 0.80 and
B 1.6), each changing one thing:

* the phase function's asymmetry g (0.89 for spheres; 0.80 and 0.75 for non-spherical
  grains) and a backscattering lobe (two-term Henyey-Greenstein);
* the absorption enhancement B (1.25 for spheres, 1.6 recommended for natural snow by
  Libois et al. 2014) and ice's absorption at 532 nm (x0.5 and x2.5: the spread between
  compilations, see :mod:`lidar_mitsuba.ground.snow`);
* the grain radius and the density, and a denser, finer-grained surface layer (a wind
  crust: 2 cm of 50 um grains at 450 kg/m^3, our estimate of a plateau crust).

The standard error of each bias counts the independent (every other) 40 m segment. The
published numbers it is set beside are in :data:`PUBLISHED`.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..products import atl06
from ..ground import snow
from ..ground.snow import kernel as snow_kernel
from ..geotrack import Site
from ..instrument import Instrument
from ..run import simulate
from ..ground.surface import SurfaceSpec

#: interior East Antarctica, winter solstice noon: the sun 10 deg below the horizon
SITE = Site(lat_deg=-80.0, lon_deg=77.0, height_m=3000.0, epoch_utc="2019-06-21T12:00:00Z")
BASELINE = {"grain_radius_um": 100.0, "density_kg_m3": 350.0}
ROWS = (  # name, changes from the baseline
    ("default (natural snow)", {}),
    ("spheres (g 0.89, B 1.25)", {"g": 0.89, "absorption_enhancement_b": None}),
    ("g 0.89 (spheres' phase function)", {"g": 0.89}),
    ("g 0.75", {"g": 0.75}),
    ("backscatter lobe 5 % (g -0.5)", {"backscatter_fraction": 0.05}),
    ("B 1.25 (spheres' absorption)", {"absorption_enhancement_b": None}),
    ("ice absorption x0.5", {"ice_absorption_scale": 0.5}),
    ("ice absorption x2.5", {"ice_absorption_scale": 2.5}),
    ("grains 50 um", {"grain_radius_um": 50.0}),
    ("grains 200 um", {"grain_radius_um": 200.0}),
    ("density 450 kg/m^3", {"density_kg_m3": 450.0}),
    ("2 cm wind crust (50 um, 450 kg/m^3)", {"crust_m": 0.02, "crust_grain_um": 50.0,
                                             "crust_density_kg_m3": 450.0}),
    ("50 um grains under the crust", {"grain_radius_um": 50.0, "crust_m": 0.02,
                                      "crust_grain_um": 50.0, "crust_density_kg_m3": 450.0}),
)
QUICK_ROWS = ("default (natural snow)", "spheres (g 0.89, B 1.25)")
#: published ICESat-2 ATL06 accuracy over interior snow (ground validation)
PUBLISHED = (
    ("Brunt et al. 2019, GRL 46, 13072 (88 S traverse, GNSS)", "bias < 1 cm"),
    ("Li et al. 2021 (Chinese inland traverse, East Antarctica; validate's source)",
     "bias 1.5 cm"),
    ("Smith et al. 2025, The Cryosphere 19, 975 (ATM waveforms, Greenland)",
     "subsurface-scattering biases of green lidar over snow: not read here"),
)


def _volume(changes: dict) -> snow.SnowVolume:
    opts = {**BASELINE, **changes}
    scale = opts.pop("ice_absorption_scale", 1.0)
    opts["ice_absorption_per_m"] = snow.ICE_ABSORPTION_532_PER_M * scale
    return snow.snow_from_grains(**opts)


def one(changes: dict, *, shots: int, seed: int = 3) -> dict:
    """``h_li`` bias (and its SE) [m] of both beams over the snowpack ``changes`` makes."""
    vol = _volume(changes)
    out = {"changes": {k: None if v is None else float(v) for k, v in changes.items()}}
    t0 = time.perf_counter()
    for beam in ("strong", "weak"):
        res = simulate(instrument=Instrument.atlas(beam), surface=SurfaceSpec(kind="flat"),
                       snow=vol, shots=shots, seed=seed, progress=False, site=SITE)
        seg = atl06.segments_from_result(res)
        good = (seg.atl06_quality_summary == 0) & np.isfinite(seg.h_li)
        x = (seg.h_li - seg.h_ref_m)[good]
        out[f"{beam}_bias_m"] = float(x.mean())
        out[f"{beam}_bias_se_m"] = float(x.std() / math.sqrt(max(x.size / 2, 1)))
        out[f"{beam}_segments"] = int(x.size)
        out["mean_extra_path_m"] = float(res.config["snow_kernel"]["mean_extra_path_nadir_m"])
    out["seconds"] = time.perf_counter() - t0
    return out


def run(*, quick: bool = False, smoke: bool = False) -> dict:
    """The sensitivity table (:data:`ROWS`; quick: :data:`QUICK_ROWS`, 2000 shots and
    kernel tables of 2^14 photons per node; ``smoke``, the tests' size: the quick run with
    tables of :data:`.snow_bias.SMOKE_TABLE_PHOTONS`)."""
    quick = quick or smoke
    rows = [(n, c) for n, c in ROWS if not quick or n in QUICK_ROWS]
    from .snow_bias import SMOKE_TABLE_PHOTONS
    with snow_kernel.photons_per_node(SMOKE_TABLE_PHOTONS if smoke else
                                      1 << 14 if quick else None):
        out = [{"name": n, **one(c, shots=2000 if quick else 20000)} for n, c in rows]
    return {"baseline": BASELINE, "site": SITE.to_dict(), "rows": out,
            "published": [list(p) for p in PUBLISHED], "quick": quick}


def format_table(doc: dict) -> list[str]:
    """The table as markdown lines."""
    lines = ["| snowpack (change from the default: 100 um, 350 kg/m^3, g 0.80, B 1.6) | "
             "strong h_li bias | "
             "weak h_li bias |", "|---|---|---|"]
    for r in doc["rows"]:
        lines.append(f"| {r['name']} | {100 * r['strong_bias_m']:+.1f} ± "
                     f"{100 * r['strong_bias_se_m']:.1f} cm | {100 * r['weak_bias_m']:+.1f} ± "
                     f"{100 * r['weak_bias_se_m']:.1f} cm |")
    return lines
