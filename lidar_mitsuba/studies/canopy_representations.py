"""The same stand in three representations: speed against accuracy (issue 42).

One conifer stand (18 m, cover 0.6, LAI 3, spherical needles, clumping 0.6: the species
preset) over a flat Lambertian ground, the same shots and paths traced as

* bare ground (``pathlength``, the ground alone: the cost every ratio is taken against);
* ``gap``: the gap-probability layer (``canopy`` integrator, ``mode="gap"``);
* ``turbid``: the crowns as a turbid medium (``mode="turbid"``), single scattering
  (``max_depth`` 1) and with leaf-leaf and leaf-ground light (3 vertices);
* ``explicit``: the forest helper's instanced leaves (``ForestSurface(representation=
  "explicit")``, ``pathlength``), in the full run.

Per representation: photon paths per second and the time relative to bare ground; the
ground's share of its bare return (``ground_share``: the gap probability the lidar sees,
hot spot included) and its standard error, and ``ground_noise_cost``, the squared error
times the time (what a given noise in the ground share costs: the gap layer's weights carry
no sampling noise of the collision, the turbid medium's do); the canopy's return per photon;
the canopy returns' height distribution (relative heights RH25/50/75/98 of the canopy return
weight above the ground) and its L1
distance to explicit leaves' (or, without them, to the turbid medium's). The closed form
(:func:`lidar_mitsuba.vegetation.gap.return_profile` over the photons' own lines: the
expected ground share) sits beside them.
"""
from __future__ import annotations

import statistics
import time

import numpy as np

from ..vegetation import gap, turbid
from ..vegetation.optics import OPTICS
from ..vegetation.stand import stand as make_stand

#: the canopy return's height bins above the ground [m]
EDGES_M = np.arange(0.0, 26.0, 1.0)
GROUND_ALBEDO = 0.3       # ESTIMATE: a litter floor at 532 nm, any value serves the ratios


def _stand(size_m: float):
    return make_stand(species="conifer", bounds_m=((0.0, 0.0), (size_m, size_m)), seed=1)


def _ground_scene(size_m: float):
    import mitsuba as mi
    half = size_m / 2 + 60.0
    return mi.load_dict({"type": "scene", "ground": {
        "type": "rectangle",
        "to_world": mi.ScalarTransform4f().translate([size_m / 2, size_m / 2, 0.0]).scale(
            [half, half, 1.0]),
        "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": GROUND_ALBEDO}}}})


def _summary(ret, *, n_photons: int, bare_weight: float) -> dict:
    """Ground share, canopy weight per photon and the canopy's height distribution."""
    ground = ret.z_m < 0.05
    w = ret.weight.astype(float)
    canopy_w, canopy_z = w[~ground], ret.z_m[~ground].astype(float)
    hist = np.histogram(canopy_z, EDGES_M, weights=canopy_w)[0]
    wg = w[ground & (ret.depth == 1)] * (n_photons / bare_weight)  # per photon, bare = 1
    var = float(np.sum(wg ** 2) / n_photons - (wg.sum() / n_photons) ** 2)
    out = {"ground_share": float(wg.sum() / n_photons),
           # its standard error from this run's photons (one ground record at most each)
           "ground_share_se": float(np.sqrt(max(var, 0.0) / n_photons)),
           "canopy_weight": float(canopy_w.sum() / n_photons),
           "profile": (hist / max(hist.sum(), 1e-30)).tolist()}
    if canopy_w.size:
        order = np.argsort(canopy_z)
        cum = np.cumsum(canopy_w[order]) / canopy_w.sum()
        for q in (25, 50, 75, 98):
            out[f"rh{q}_m"] = float(canopy_z[order][np.searchsorted(cum, q / 100.0)])
    return out


def run(*, quick: bool = False) -> dict:
    """Trace the stand in each representation (module docstring); ``quick``: fewer shots,
    no explicit leaves and single scattering only (the test suite's bench run)."""
    import mitsuba as mi
    from ..instrument import Instrument
    size = 100.0
    st = _stand(size)
    scene = _ground_scene(size)
    n_shots, k = (40, 64) if quick else (400, 256)
    xs = 10.0 + (np.arange(n_shots) * 0.7) % (size - 20.0)
    ys = np.full(n_shots, size / 2)
    base = Instrument().integrator_dict(max_depth=1)
    # the foliage's optics as the explicit forest's (ForestSurface's default: needles for a
    # conifer), so that the representations differ in geometry only
    leaf = OPTICS["needle" if st.species == "conifer" else "leaf"]
    cases = {"bare ground": (mi.load_dict(base), scene)}
    kinds = [("gap", "gap", None), ("turbid, 1 vertex", "turbid", 1)]
    for name, mode, depth in kinds + ([] if quick else [("turbid, 3 vertices", "turbid", 3)]):
        d = turbid.integrator_dict(st, mode=mode, base=base, rho=leaf.reflectance,
                                   tau=leaf.transmittance, max_depth=depth)
        cases[name] = (mi.load_dict(d), scene)
    if not quick:
        cases.update(_explicit_cases(st, base))
    reps = 1 if quick else 3
    rows, bare_s = {}, None
    for name, (integ, sc) in cases.items():
        integ.trace(sc, shot_x_m=xs, shot_y_m=ys, paths_per_shot=k, seed=1)     # compile
        times = []
        for _ in range(reps):
            t = time.perf_counter()
            ret = integ.trace(sc, shot_x_m=xs, shot_y_m=ys, paths_per_shot=k, seed=2)
            times.append(time.perf_counter() - t)
        sec = statistics.median(times)
        if bare_s is None:
            bare_s, bare_weight = sec, float(ret.weight.sum())
        row = {"seconds": sec, "paths_per_s": n_shots * k / sec, "time_vs_bare": sec / bare_s,
               **_summary(ret, n_photons=n_shots * k, bare_weight=bare_weight)}
        # the cost of a given noise in the ground share: se^2 x time (lower is better)
        row["ground_noise_cost"] = row["ground_share_se"] ** 2 * sec
        rows[name] = row
    ref = next(r for r in ("explicit", "turbid, 3 vertices", "turbid, 1 vertex") if r in rows)
    for r in rows.values():
        if "profile" in r and r is not rows["bare ground"]:
            r["profile_l1_vs_" + ref.split(",")[0]] = float(
                np.abs(np.subtract(r["profile"], rows[ref]["profile"])).sum())
    table = turbid.canopy_table(st, rho=leaf.reflectance, tau=leaf.transmittance)
    rng = np.random.default_rng(5)
    lx = np.repeat(xs, 64) + 2.5 * rng.standard_normal(n_shots * 64)
    ly = np.repeat(ys, 64) + 2.5 * rng.standard_normal(n_shots * 64)
    _, pred = gap.return_profile(table, lx, ly, 0.0, np.array([0.0, 1.0]))
    return {"leaf": {"name": leaf.name, "R": leaf.reflectance, "T": leaf.transmittance},
            "stand": {"species": st.species, "trees": st.n_trees, "lai": st.lai(),
                      "cover": st.canopy_cover(), "clumping": st.clumping,
                      "leaf_angle": st.leaf_angle, "crown_shape": st.crown_shape},
            "shots": n_shots, "paths_per_shot": k, "reference": ref,
            "closed_form_ground_share": pred, "rows": rows}


def _explicit_cases(st, base: dict) -> dict:
    """The explicit representation (the forest helper's), where its module is present."""
    try:
        from ..vegetation.forest import ForestSurface
    except ImportError:
        return {}
    import mitsuba as mi
    from ..ground.surface import Plane
    size = st.bounds_m[1][0] - st.bounds_m[0][0]
    f = ForestSurface(ground=Plane(size_m=size), stand=st, representation="explicit")
    bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": GROUND_ALBEDO}}
    # the track's corridor (y = size/2 +- the field of view): the whole tile's leaves are
    # too many to trace
    scene, _ = f.mitsuba_scene(bsdf=bsdf, margin_m=0.0,
                               bounds_m=(0.0, size, size / 2 - 21.0, size / 2 + 21.0))
    return {"explicit": (mi.load_dict(base), scene),
            "explicit, 3 vertices": (mi.load_dict({**base, "max_depth": 3}), scene)}


def format_rows(doc: dict) -> list[str]:
    """One line per representation."""
    lines = [f"canopy ({doc['stand']['species']}, LAI {doc['stand']['lai']:.2f}, cover "
             f"{doc['stand']['cover']:.2f}; closed-form ground share "
             f"{doc['closed_form_ground_share']:.3f}):"]
    for name, r in doc["rows"].items():
        extra = "".join(f", {k} {v:.3f}" for k, v in r.items() if k.startswith("profile_l1"))
        lines.append(f"  {name:<22} {r['paths_per_s'] / 1e6:7.2f} M paths/s, "
                     f"{r['time_vs_bare']:5.2f}x bare; ground {r['ground_share']:.3f} +- "
                     f"{r['ground_share_se']:.3f} (se^2 x s {r['ground_noise_cost']:.2g}), canopy "
                     f"{r['canopy_weight']:.4f}/photon, RH50 {r.get('rh50_m', float('nan')):.1f}"
                     f" m, RH98 {r.get('rh98_m', float('nan')):.1f} m{extra}")
    return lines


def chart(doc: dict, path) -> None:
    """Speed against accuracy: each representation's time relative to bare ground against
    its ground share's distance from the reference (explicit leaves where traced), and the
    canopy returns' height profiles."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = {k: r for k, r in doc["rows"].items() if k != "bare ground"}
    ref = rows[doc["reference"]]
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2))
    for i, (name, r) in enumerate(rows.items()):
        err = abs(r["ground_share"] - ref["ground_share"])
        ax[0].errorbar(r["time_vs_bare"], err, yerr=r["ground_share_se"], fmt="o",
                       color=f"C{i}", capsize=2, label=name)
        centres = 0.5 * (EDGES_M[1:] + EDGES_M[:-1])
        ax[1].step(centres, r["profile"], where="mid", color=f"C{i}", label=name)
    ax[0].set(xscale="log", xlabel="trace time / bare ground's",
              ylabel=f"|ground share - {doc['reference']}'s|",
              title=f"speed vs accuracy (ground share, closed form "
                    f"{doc['closed_form_ground_share']:.3f})")
    ax[0].legend(fontsize=7)
    ax[1].set(xlabel="height above ground [m]", ylabel="share of the canopy return",
              title=f"canopy returns ({doc['stand']['species']}, LAI {doc['stand']['lai']:.1f}"
                    f", cover {doc['stand']['cover']:.2f})")
    ax[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
