"""A supraglacial lake (melt pond) as ATLAS sees it: the bottom's apparent depth, the refraction
correction that gives the true depth back, and the bottom's brightness.

The scene is ``scenes/melt_pond.xml``: water (``<bsdf type="water">``: Cox-Munk slopes for a
3 m/s wind, Quan & Fry's 532 nm phase and group index at 0 C) with pure water's absorption
(Pope & Fry 1997) and scattering (Morel 1974) as a medium, over a Lambertian ice bottom of
albedo 0.6, run with the default flags (the scene's materials choose ``mediapathlength``).
Per depth, the run is written to ATL03 and read back, and the surface and bottom are found from
the photons the classifier calls signal (``signal_conf_ph >= 2``), as a user of the product
would: the surface as the median height within 0.5 m of the reference, the bottom as the
median within 0.3 m of the densest 5 cm bin below it.

Closed forms beside each measurement:

- apparent depth = n_g x depth (light in water travels at c / n_g; Parrish et al. 2019);
- Parrish et al.'s correction (phase index 1.34116, :func:`lidar_mitsuba.ground.water.refraction_correction`)
  gives the true depth times n_g / 1.34116; the same correction with our group index gives it
  exactly at nadir;
- the bottom's return weight per photon path: T^2 rho e^{-2 c d} / (n^2 0.9) (Fresnel
  transmission in and out, the radiance's 1/n^2, Beer-Lambert with c = a + b), counted from the
  traced returns of the bottom's first reflection (light the surface reflects back down adds
  more, later: listed apart).
"""
from __future__ import annotations

import pathlib
import tempfile

import numpy as np

from ..products import atl03
from ..ground import water
from ..run import simulate

SCENE = pathlib.Path(__file__).resolve().parents[2] / "scenes" / "melt_pond.xml"
DEPTHS_M = (0.5, 1.0, 2.0, 4.0)
BOTTOM_ALBEDO = 0.6
#: the pond's medium in melt_pond.xml: Pope & Fry's absorption plus Morel's scattering
ATTENUATION_PER_M = water.PURE_WATER_ABSORPTION_532_PER_M + water.PURE_WATER_SCATTERING_532_PER_M


def _surface_and_bottom(h_m: np.ndarray, z_ref_m: float) -> tuple[float, float, int]:
    """Surface and bottom heights [m] from signal photon heights, and the bottom's count."""
    surf = h_m[np.abs(h_m - z_ref_m) < 0.5]
    z_surf = float(np.median(surf))
    below = h_m[h_m < z_surf - 0.3]
    if below.size < 10:
        return z_surf, float("nan"), int(below.size)
    edges = np.arange(below.min(), below.max() + 0.05, 0.05)
    counts, edges = np.histogram(below, edges) if edges.size > 1 else (np.array([1]), edges)
    mode = edges[np.argmax(counts)] + 0.025
    near = below[np.abs(below - mode) < 0.3]
    return z_surf, float(np.median(near)), int(near.size)


def one_depth(depth_m: float, *, shots: int, seed: int, out_dir: pathlib.Path) -> dict:
    """Simulate the pond at ``depth_m``, write and read its ATL03, find surface and bottom."""
    res = simulate(scene_file=str(SCENE), params={"depth_m": str(depth_m)}, shots=shots,
                   seed=seed, progress=False, keep_returns=True)
    path = atl03.write(res, out_dir / f"pond_{depth_m:g}m.h5")
    beam = atl03.read(path)
    sig = beam["signal_conf"] >= 2
    z_surf, z_bot, n_bot = _surface_and_bottom(beam["h_m"][sig], float(np.median(beam["z_ref_m"])))
    apparent = z_surf - z_bot
    n_g = water.WATER_GROUP_INDEX_532
    n = water.WATER_INDEX_532
    r = res.returns
    first = (r.depth == 2) & (r.z_m < -0.5 * depth_m)
    later = (r.depth > 2) & (r.z_m < -0.5 * depth_m)
    paths = r.n_shots * r.paths_per_shot
    t = 1.0 - float(water.fresnel_normal(n / water.AIR_IOR))
    closed = t * t * BOTTOM_ALBEDO * np.exp(-2 * ATTENUATION_PER_M * depth_m) / (n * n * 0.9)
    per_shot = np.bincount(r.shot[first], weights=r.weight[first], minlength=r.n_shots)
    per_shot /= r.paths_per_shot
    return {"depth_m": depth_m, "shots": shots, "bottom_photons": n_bot,
            "surface_h_m": z_surf, "bottom_h_m": z_bot, "apparent_depth_m": apparent,
            "apparent_over_true": apparent / depth_m, "group_index": n_g,
            "parrish_depth_m": float(water.refraction_correction(apparent)),
            "group_corrected_depth_m": float(water.refraction_correction(
                apparent, n_water=n_g, n_air=1.0)),
            "bottom_weight": float(per_shot.mean()),
            "bottom_weight_se": float(per_shot.std(ddof=1) / np.sqrt(r.n_shots)),
            "bottom_weight_closed": float(closed),
            "reflected_back_weight": float(r.weight[later].sum() / paths),
            "wall_s": float(res.timings_s["total_s"]),
            "max_depth": int(res.config["max_depth"]),
            "integrator": res.config["integrator"]}


def run(*, quick: bool = False, seed: int = 3) -> dict:
    """Every depth of :data:`DEPTHS_M` (``quick``: 300 shots each, else 1500)."""
    shots = 300 if quick else 1500
    with tempfile.TemporaryDirectory() as tmp:
        rows = [one_depth(d, shots=shots, seed=seed + i, out_dir=pathlib.Path(tmp))
                for i, d in enumerate(DEPTHS_M)]
    return {"rows": rows, "attenuation_per_m": ATTENUATION_PER_M,
            "parrish_index": water.PARRISH_SEAWATER_INDEX}


def plot(doc: dict, path) -> None:
    """Apparent and corrected depth against true depth, and the bottom's brightness."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = doc["rows"]
    d = np.array([r["depth_m"] for r in rows])
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    ax[0].plot(d, d, "k:", label="true depth")
    ax[0].plot(d, [r["apparent_depth_m"] for r in rows], "o", label="apparent (our ATL03)")
    ax[0].plot(d, rows[0]["group_index"] * d, "-", color="tab:blue", lw=0.8,
               label=f"n_g x depth (n_g = {rows[0]['group_index']:.4f})")
    ax[0].plot(d, [r["parrish_depth_m"] for r in rows], "s", mfc="none",
               label="Parrish et al. 2019 correction (n = 1.34116)")
    ax[0].set(xlabel="true depth [m]", ylabel="depth below the surface [m]")
    ax[0].legend(fontsize=8)
    ax[1].errorbar(d, [r["bottom_weight"] for r in rows],
                   yerr=[r["bottom_weight_se"] for r in rows], fmt="o", label="traced")
    dd = np.linspace(d.min(), d.max(), 50)
    scale = rows[0]["bottom_weight_closed"] / np.exp(-2 * doc["attenuation_per_m"] * d[0])
    ax[1].plot(dd, scale * np.exp(-2 * doc["attenuation_per_m"] * dd), "k-",
               label="T^2 rho e^{-2cd} / (n^2 0.9)")
    ax[1].plot(d, [r["reflected_back_weight"] for r in rows], "^",
               label="after a reflection back down (later)")
    ax[1].set(xlabel="true depth [m]", ylabel="bottom return weight per path")
    ax[1].legend(fontsize=8)
    fig.suptitle("A melt pond (scenes/melt_pond.xml), default flags")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
