"""Canopy cover against what ATL08 finds (issue 42): cover 0-95 % x strong / weak beam x day /
night over flat ground under a conifer stand, our ATL08 (:mod:`lidar_mitsuba.products.atl08`)
run on each simulated ATL03, beside Neuenschwander et al. 2020 ("Validation of ICESat-2
terrain and canopy heights in boreal forests", Remote Sens. Environ. 251, 112110; Finland:
terrain RMSE 0.73 m, canopy heights underestimated, least at 40-85 % cover, weak beams
about 1 m lower than strong ones).

Per configuration, over its 100 m segments:

* ``p_ground``: the share of segments with a terrain height (``h_te_best_fit`` not fill);
* ``terrain_bias_m``, ``terrain_rmse_m``: ``h_te_best_fit`` against the true ground (z = 0);
* ``canopy_bias_m``, ``canopy_rmse_m``: ``h_canopy`` against the stand's own RH98: the 98th
  percentile of the true canopy surface (the highest crown over each point, 0 in the gaps)
  over the segment's footprints (points within the footprint's 1/e^2 radius of the track);
* the photons per shot ATL08 classed ground and canopy.

The site: Hyytiala, southern Finland (61.85 N, 24.29 E, 180 m; the SMEAR II station, one of
Neuenschwander et al.'s sites), day at the June solstice's noon, night at the December
solstice's midnight. The stand: the conifer preset (:data:`~lidar_mitsuba.vegetation.stand.PRESETS`)
18 m tall (ESTIMATE: a mature Scots pine / Norway spruce stand there), LAI
:data:`LAI_PER_COVER` times the cover (the crowns' own leaf density the same at every cover),
``gap`` representation (the forest twin's reasons, :mod:`~lidar_mitsuba.studies.forest_twin`),
the 2018 pulse energies of ATLAS.

Run: ``python -m lidar_mitsuba.studies.canopy_cover [--quick] [--strong|--weak] [OUT_DIR]``:
``canopy_cover.json`` and ``canopy_cover.png``.
"""
from __future__ import annotations

import json
import pathlib
import sys
import tempfile
import time

import numpy as np

COVERS = (0.0, 0.2, 0.4, 0.6, 0.8, 0.95)
"""Canopy covers simulated (fraction)."""
HEIGHT_M = 18.0
"""Mean tree height [m] (ESTIMATE: a mature boreal conifer stand, module docstring)."""
LAI_PER_COVER = 5.0
"""Stand LAI per unit cover (ESTIMATE: the conifer preset's LAI 3 at its cover 0.6)."""
TILE_M = 256.0
"""Side of the periodic ground tile [m]; the track crosses it at :data:`HEADING_DEG`."""
HEADING_DEG = 11.31
"""The track's heading [deg from +x]: tan = 0.2, so each 256 m wrap of the tile lies 51 m
beside the last (footprints never repeat)."""
SITE = {"lat_deg": 61.85, "lon_deg": 24.29, "height_m": 180.0}
EPOCHS = {"day": "2019-06-21T10:20:00Z", "night": "2019-12-21T22:20:00Z"}
PUBLISHED = {"terrain_rmse_m": 0.73, "canopy": "underestimated, least at 40-85 % cover",
             "weak_minus_strong_canopy_m": -1.0,
             "source": "Neuenschwander et al. 2020, Remote Sens. Environ. 251, 112110"}


def stand_surface(cover: float, *, seed: int):
    """The ground plane with the study's stand of ``cover`` (a bare plane at 0)."""
    from ..ground.surface import Plane
    from ..vegetation.forest import forest
    ground = Plane(size_m=TILE_M)
    if cover <= 0:
        return ground
    return forest(species="conifer", ground=ground, representation="gap", height_m=HEIGHT_M,
                  cover=cover, lai=LAI_PER_COVER * cover, seed=seed)


def true_rh98(surface, x_m, y_m, *, radius_m: float) -> float:
    """RH98 [m] of the true canopy surface (the highest crown point over each point, 0 in the
    gaps) over points within ``radius_m`` of the footprint centres ``x_m``, ``y_m``
    (sampled: 8 points per centre, seeded), folded into the stand's tile."""
    from ..vegetation import gap, turbid
    if not hasattr(surface, "stand"):
        return 0.0
    rng = np.random.default_rng(0)
    r = radius_m * np.sqrt(rng.random((x_m.size, 8)))
    a = 2 * np.pi * rng.random((x_m.size, 8))
    px = np.mod(x_m[:, None] + r * np.cos(a), TILE_M).ravel()
    py = np.mod(y_m[:, None] + r * np.sin(a), TILE_M).ravel()
    table = turbid.canopy_table(surface.stand, rho=0.1, tau=0.0)
    _, hi = gap.vertical_chords(table, px, py)
    top = np.clip(hi.max(1), 0.0, None)
    return float(np.percentile(top, 98))


def run_one(*, cover: float, strength: str, light: str, shots: int, seed: int) -> dict:
    """One configuration: simulate, write ATL03, our ATL08, the metrics (module docstring)."""
    import warnings
    from ..geotrack import Site
    from ..instrument import Instrument
    from ..products import atl03, atl08
    from ..run import simulate
    from ..track import Track
    from ..vegetation.optics import OPTICS
    surface = stand_surface(cover, seed=seed)
    inst = Instrument.atlas(strength)
    site = Site(lat_deg=SITE["lat_deg"], lon_deg=SITE["lon_deg"], epoch_utc=EPOCHS[light],
                height_m=SITE["height_m"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = simulate(instrument=inst, surface=surface, shots=shots, seed=seed,
                       track=Track(heading_deg=HEADING_DEG), site=site, progress=False,
                       bsdf=OPTICS["litter"].bsdf_dict())      # the forest floor, bare too
    beam = "gt1l" if strength == "strong" else "gt1r"
    with tempfile.TemporaryDirectory() as tmp:
        path = atl03.write(res, pathlib.Path(tmp) / "ATL03.h5")
        b08 = atl08.from_atl03(path, beam)
    return metrics(b08, res, surface, cover=cover, strength=strength, light=light)


def metrics(b08, res, surface, *, cover, strength, light) -> dict:
    """The configuration's row from our ATL08 ``b08`` of the run ``res`` over ``surface``."""
    from .forest_twin import F4_FILL
    s = b08.segments
    h_te = s["land_segments/terrain/h_te_best_fit"].astype(float)
    h_can = s["land_segments/canopy/h_canopy"].astype(float)
    found = h_te < F4_FILL
    along = res.along_track_m
    seg_x = s["land_segments/segment_id_beg"].astype(float)       # 20 m segment ids
    seg_x = (seg_x - seg_x.min()) * 20.0 if seg_x.size else seg_x
    radius = res.instrument.footprint_diameter_m / 2.0
    truth = []
    for x0 in seg_x:
        m = (along - along[0] >= x0) & (along - along[0] < x0 + 100.0)
        truth.append(true_rh98(surface, res.shot_x_m[m], res.shot_y_m[m], radius_m=radius)
                     if m.any() else np.nan)
    truth = np.asarray(truth)
    dz = h_te[found]                                        # the true ground is z = 0
    has_can = (h_can < F4_FILL) & np.isfinite(truth) & (truth > 0)
    dc = h_can[has_can] - truth[has_can]
    shots = 100.0 * b08_shots_per_m(res)
    n_te = s["land_segments/terrain/n_te_photons"].astype(float)
    n_ca = (s["land_segments/canopy/n_ca_photons"].astype(float)
            + s["land_segments/canopy/n_toc_photons"].astype(float))

    def stat(a, f):
        return float(f(a)) if a.size else None
    return {"cover": cover, "stand_cover": float(surface.stand.canopy_cover())
            if hasattr(surface, "stand") else 0.0, "strength": strength, "light": light,
            "segments": int(h_te.size), "p_ground": float(found.mean()) if found.size else None,
            "terrain_bias_m": stat(dz, np.mean),
            "terrain_rmse_m": stat(dz, lambda a: np.sqrt(np.mean(a ** 2))),
            "canopy_segments": int(has_can.sum()), "truth_rh98_m": stat(truth[np.isfinite(truth)],
                                                                        np.mean),
            "canopy_bias_m": stat(dc, np.mean),
            "canopy_rmse_m": stat(dc, lambda a: np.sqrt(np.mean(a ** 2))),
            "ground_per_shot": float(n_te.sum() / (shots * max(n_te.size, 1))),
            "canopy_per_shot": float(n_ca.sum() / (shots * max(n_ca.size, 1)))}


def b08_shots_per_m(res) -> float:
    """Shots per metre of track of a run."""
    a = res.along_track_m
    return float((a.size - 1) / np.ptp(a)) if a.size > 1 and np.ptp(a) > 0 else 1.0 / 0.7


def run(out_dir=None, *, quick: bool = False, seed: int = 1, progress=print,
        strengths=("strong", "weak")) -> dict:
    """The study: every cover x strength (of ``strengths``) x light (``quick``: covers 0
    and 0.8, the strong beam by night, 300 shots: a test's seconds); ``canopy_cover.json``
    and ``.png`` in ``out_dir`` when given."""
    t0 = time.perf_counter()
    covers = (0.0, 0.8) if quick else COVERS
    combos = [("strong", "night")] if quick else [(s, ll) for s in strengths
                                                for ll in ("day", "night")]
    shots = 300 if quick else 1000
    rows = []
    for strength, light in combos:
        for c in covers:
            row = run_one(cover=c, strength=strength, light=light, shots=shots, seed=seed)
            rows.append(row)
            if progress:
                progress(format_row(row))
    doc = {"quick": quick, "shots": shots, "rows": rows, "published": PUBLISHED,
           "height_m": HEIGHT_M, "lai_per_cover": LAI_PER_COVER,
           "seconds": time.perf_counter() - t0}
    if out_dir is not None:
        out = pathlib.Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        (out / "canopy_cover.json").write_text(json.dumps(doc, indent=1))
        plot(doc, out / "canopy_cover.png")
    return doc


def _fmt(v, spec=".2f") -> str:
    return "-" if v is None else format(v, spec)


def format_row(r: dict) -> str:
    return (f"cover {r['cover']:.2f} {r['strength']:<6} {r['light']:<5} segments "
            f"{r['segments']:2d} p_ground {_fmt(r['p_ground'])} terrain bias/rmse "
            f"{_fmt(r['terrain_bias_m'])}/{_fmt(r['terrain_rmse_m'])} m canopy bias/rmse "
            f"{_fmt(r['canopy_bias_m'])}/{_fmt(r['canopy_rmse_m'])} m (truth RH98 "
            f"{_fmt(r['truth_rh98_m'])}) ground/canopy per shot {_fmt(r['ground_per_shot'], '.3f')}"
            f"/{_fmt(r['canopy_per_shot'], '.3f')}")


def table_md(doc: dict) -> str:
    """The study's rows as a Markdown table."""
    lines = ["| cover | beam | light | P(ground) | terrain bias / RMSE [m] | canopy segments "
             "| h_canopy - true RH98, mean / RMSE [m] | ground / canopy photons per shot |",
             "|---|---|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        lines.append(f"| {100 * r['cover']:.0f} % | {r['strength']} | {r['light']} | "
                     f"{_fmt(r['p_ground'])} | {_fmt(r['terrain_bias_m'])} / "
                     f"{_fmt(r['terrain_rmse_m'])} | {r['canopy_segments']}/{r['segments']} | "
                     f"{_fmt(r['canopy_bias_m'])} / {_fmt(r['canopy_rmse_m'])} | "
                     f"{_fmt(r['ground_per_shot'], '.3f')} / "
                     f"{_fmt(r['canopy_per_shot'], '.3f')} |")
    return "\n".join(lines)


def plot(doc: dict, path) -> None:
    """Three panels against cover: the probability of finding the ground, the terrain RMSE
    (Neuenschwander et al.'s 0.73 m drawn), the canopy-height bias; one line per beam and
    light."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 3, figsize=(13, 4))
    style = {("strong", "day"): ("tab:red", "-"), ("strong", "night"): ("tab:red", "--"),
             ("weak", "day"): ("tab:blue", "-"), ("weak", "night"): ("tab:blue", "--")}
    for (s, ll), (col, ls) in style.items():
        rows = [r for r in doc["rows"] if r["strength"] == s and r["light"] == ll]
        if not rows:
            continue
        c = [100 * r["cover"] for r in rows]
        for k, key in enumerate(("p_ground", "terrain_rmse_m", "canopy_bias_m")):
            y = [np.nan if r[key] is None else r[key] for r in rows]
            ax[k].plot(c, y, color=col, ls=ls, marker="o", label=f"{s}, {ll}")
    ax[1].axhline(PUBLISHED["terrain_rmse_m"], color="k", lw=1,
                  label="Neuenschwander et al. 2020 (all beams)")
    ax[2].axhline(0.0, color="k", lw=0.8)
    ax[2].axvspan(40, 85, color="0.85", label="least underestimated (N. et al. 2020)")
    for a, t in zip(ax, ("P(ground found) per 100 m segment", "terrain RMSE [m]",
                         "h_canopy - true RH98 [m]")):
        a.set_xlabel("canopy cover [%]")
        a.set_xlim(-3, 100)
        a.set_title(t, fontsize=10)
        a.grid(alpha=0.3)
    ax[0].legend(fontsize=8)
    ax[1].legend(fontsize=8)
    ax[2].legend(fontsize=8)
    fig.suptitle(f"Our ATL08 over a simulated {doc['height_m']:g} m conifer stand "
                 f"({doc['shots']} shots per run)", fontsize=11)
    fig.tight_layout()
    fig.savefig(pathlib.Path(path), dpi=100)
    plt.close(fig)


def main(argv=None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    quick = "--quick" in args
    strengths = [a[2:] for a in args if a in ("--strong", "--weak")] or ["strong", "weak"]
    args = [a for a in args if not a.startswith("--")]
    run(args[0] if args else "canopy_cover_out", quick=quick, strengths=tuple(strengths))


if __name__ == "__main__":
    main()
