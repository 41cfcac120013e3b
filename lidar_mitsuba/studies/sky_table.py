"""The reference sky: Mitsuba renders the radiance a nadir-looking receiver sees above a
spherical Earth wrapped in shells of Rayleigh, aerosol and ozone, with every order of
scattering, tabulated once against solar elevation, albedo and aerosol optical depth
(``python -m lidar_mitsuba.studies.sky_table``, about half an hour on two shared cores; writes
``lidar_mitsuba/data/sky_table.json`` and the chart ``docs/physics/sky_vs_render.png``).

The scene, in kilometres (float32 keeps 0.4 m at the Earth's radius): the Earth a sphere of
radius 6371 km with a ``diffuse`` BSDF of the given albedo; around it the closed form's 48
layers (:class:`lidar_mitsuba.sky.Column`, surface at sea level) as nested ``null``-BSDF
spheres, each the interior of one ``homogeneous`` medium holding the layer's mean extinction
(Rayleigh + aerosol + ozone absorption), its single-scattering albedo and a ``blendphase`` of
the ``rayleigh`` and ``hg`` (g = 0.7) phase functions weighted by their scattering optical
depths; the sun a ``directional`` emitter of unit irradiance at elevation ``h`` (straight
rays: no refraction); a ``radiancemeter`` 200 km above the top, looking straight down at the
surface point; ``volpath`` with ``max_depth`` 64. The Monte Carlo error of each entry is the
spread of 8 independent renders (different seeds), divided by sqrt(8).

Used by ``tests/test_sky.py`` (closed form against rendered, tolerances per regime) and
``docs/physics/sky.md``; never at run time.
"""
from __future__ import annotations

import json
import pathlib
import time

import numpy as np

from .. import sky
from ..radiometry import rayleigh_optical_depth

ELEVATIONS_DEG = (-8.0, -6.0, -4.0, -3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 4.0, 8.0, 15.0, 30.0)
ALBEDOS = (0.0, 0.5, 0.9)
AEROSOL_DEPTHS = (0.02, 0.1)
SPP = 1 << 17
SEEDS = 8
TABLE = pathlib.Path(__file__).resolve().parents[1] / "data" / "sky_table.json"
CHART = pathlib.Path(__file__).resolve().parents[2] / "docs" / "physics" / "sky_vs_render.png"
R_KM = sky.EARTH_RADIUS_M / 1000.0
RENDER_LAYERS = 24


def column(aerosol_optical_depth: float) -> sky.Column:
    """The closed form's layers over a sea-level surface at 532 nm."""
    return sky.Column.build(z_m=0.0, tau_rayleigh=float(rayleigh_optical_depth(532.0)),
                            aerosol_optical_depth=aerosol_optical_depth,
                            aerosol_scale_height_m=2000.0, aerosol_ssa=0.95,
                            ozone_optical_depth=sky.OZONE_COLUMN_ATM_CM
                            * sky.OZONE_ABSORPTION_PER_ATM_CM, n_layers=RENDER_LAYERS)


def scene_dict(*, col: sky.Column, elevation_deg: float, albedo: float) -> dict:
    """The Mitsuba scene (a dict for ``mi.load_dict``)."""
    h = np.deg2rad(elevation_deg)
    centre = [0.0, 0.0, -R_KM]          # the surface point at the origin: small coordinates
    edges_km = col.edges_m / 1000.0
    media = []
    for i in range(col.d_ext.size):
        thick = edges_km[i + 1] - edges_km[i]
        sca = col.d_sca[i]
        w_aer = col.aerosol_ssa * col.d_aerosol[i] / max(sca, 1e-30)
        media.append({"type": "homogeneous", "sigma_t": float(col.d_ext[i] / thick),
                      "albedo": float(sca / col.d_ext[i]),
                      "phase": {"type": "blendphase", "weight": float(w_aer),
                                "phase1": {"type": "rayleigh"},
                                "phase2": {"type": "hg", "g": sky.AEROSOL_ASYMMETRY}}})
    d = {"type": "scene",
         "integrator": {"type": "volpath", "max_depth": 64, "rr_depth": 32},
         "sun": {"type": "directional", "irradiance": 1.0,
                 "direction": [float(-np.cos(h)), 0.0, float(-np.sin(h))]},
         "sensor": {"type": "radiancemeter",
                    "origin": [0.0, 0.0, float(edges_km[-1] + 200.0)],
                    "direction": [0.0, 0.0, -1.0],
                    "film": {"type": "hdrfilm", "width": 1, "height": 1,
                             "rfilter": {"type": "box"}, "pixel_format": "luminance"},
                    "sampler": {"type": "independent", "sample_count": SPP // SEEDS}},
         "earth": {"type": "sphere", "radius": float(R_KM + edges_km[0]), "center": centre,
                   "bsdf": {"type": "diffuse", "reflectance": float(albedo)},
                   "exterior": media[0]}}
    for i, medium in enumerate(media):
        shell = {"type": "sphere", "radius": float(R_KM + edges_km[i + 1]), "center": centre,
                 "bsdf": {"type": "null"}, "interior": medium}
        if i + 1 < len(media):
            shell["exterior"] = media[i + 1]
        d[f"shell_{i:02d}"] = shell
    return d


def render(*, col: sky.Column, elevation_deg: float, albedo: float,
           spp: int = SPP) -> tuple[float, float]:
    """``(radiance, its standard error)`` per unit solar irradiance [sr^-1]: ``SEEDS``
    independent renders of ``spp / SEEDS`` samples each."""
    from ..trace.lazy import mi
    from ..trace.variant import set_variant
    set_variant("llvm_ad_mono")
    scene = mi.load_dict(scene_dict(col=col, elevation_deg=elevation_deg, albedo=albedo))
    values = [float(np.asarray(mi.render(scene, seed=s, spp=spp // SEEDS)).ravel()[0])
              for s in range(SEEDS)]
    return float(np.mean(values)), float(np.std(values, ddof=1) / np.sqrt(SEEDS))


def render_once(*, col: sky.Column, elevation_deg: float, albedo: float) -> float:
    """One render of ``SPP / SEEDS`` samples (the scene loaded too) [sr^-1]."""
    from ..trace.lazy import mi
    from ..trace.variant import set_variant
    set_variant("llvm_ad_mono")
    scene = mi.load_dict(scene_dict(col=col, elevation_deg=elevation_deg, albedo=albedo))
    return float(np.asarray(mi.render(scene, seed=0)).ravel()[0])


def closed_form(*, aerosol_optical_depth: float, albedo: float, elevations_deg,
                multiple_scattering: bool = True) -> np.ndarray:
    """The closed form in the render's conditions (straight rays, sea-level surface)."""
    return sky.sky(solar_elevation_deg=np.asarray(elevations_deg, np.float64), z_m=0.0,
                   albedo=albedo, tau_rayleigh=float(rayleigh_optical_depth(532.0)),
                   aerosol_optical_depth=aerosol_optical_depth, refraction=False,
                   multiple_scattering=multiple_scattering).toa_radiance


def _grid(render_fn, albedos, *, label: str, **kw) -> tuple[np.ndarray, np.ndarray]:
    """``(values, standard errors)``, each (aerosol, albedo, elevation): ``render_fn(col=,
    elevation_deg=, albedo=, **kw)`` over :data:`AEROSOL_DEPTHS` x ``albedos`` x
    :data:`ELEVATIONS_DEG`, one line printed per entry."""
    shape = (len(AEROSOL_DEPTHS), len(albedos), len(ELEVATIONS_DEG))
    val, err = np.zeros(shape), np.zeros(shape)
    for i, aod in enumerate(AEROSOL_DEPTHS):
        col = column(aod)
        for j, alb in enumerate(albedos):
            for k, e in enumerate(ELEVATIONS_DEG):
                val[i, j, k], err[i, j, k] = render_fn(col=col, elevation_deg=e, albedo=alb,
                                                       **kw)
                print(f"{label}aod {aod} albedo {alb} elev {e:+5.1f}: {val[i, j, k]:.4e} "
                      f"+- {err[i, j, k]:.1e}", flush=True)
    return val, err


def build(*, path: pathlib.Path = TABLE) -> dict:
    """Render every entry and write the table (JSON: the grid, the radiances, their standard
    errors, how it was made)."""
    t0 = time.perf_counter()
    rad, err = _grid(render, ALBEDOS, label="")
    from ..trace.lazy import mi
    doc = {"about": __doc__.strip().splitlines()[0] + " See lidar_mitsuba/studies/sky_table.py.",
           "quantity": "radiance toward a nadir-looking receiver above the atmosphere per unit "
                       "top-of-atmosphere solar irradiance [sr^-1], 532 nm, sea-level surface",
           "mitsuba": mi.__version__, "variant": "llvm_ad_mono", "spp": SPP, "seeds": SEEDS,
           "seconds": round(time.perf_counter() - t0, 1),
           "tau_rayleigh": float(rayleigh_optical_depth(532.0)), "layers": RENDER_LAYERS,
           "elevations_deg": list(ELEVATIONS_DEG), "albedos": list(ALBEDOS),
           "aerosol_optical_depths": list(AEROSOL_DEPTHS),
           "radiance_per_sr": rad.tolist(), "standard_error_per_sr": err.tolist()}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1))
    return doc


IRRADIANCE_ALBEDOS = (0.0, 0.9)


def render_irradiance(*, col: sky.Column, elevation_deg: float, albedo: float,
                      spp: int = SPP) -> tuple[float, float]:
    """``(diffuse irradiance, its standard error)`` on the horizontal surface per unit solar
    irradiance [1]: an ``irradiancemeter`` on a 10 m disk 0.5 m above the surface point,
    starting its rays in the lowest layer's medium (without it they start in vacuum and miss
    that layer: a 6 % deficit the first-order check caught). The direct sun, a delta
    emitter, is not in it: it is the diffuse sky alone."""
    from ..trace.lazy import mi
    from ..trace.variant import set_variant
    set_variant("llvm_ad_mono")
    d = scene_dict(col=col, elevation_deg=elevation_deg, albedo=albedo)
    film = d.pop("sensor")["film"]
    ground = d["earth"]["exterior"]
    d["meter"] = {"type": "disk", "exterior": ground, "interior": ground,
                  "to_world": mi.ScalarTransform4f().translate([0.0, 0.0, 0.0005]).scale(0.01),
                  "sensor": {"type": "irradiancemeter", "medium": ground, "film": film,
                             "sampler": {"type": "independent", "sample_count": spp // SEEDS}}}
    scene = mi.load_dict(d)
    values = [float(np.asarray(mi.render(scene, seed=s)).ravel()[0]) for s in range(SEEDS)]
    return float(np.mean(values)), float(np.std(values, ddof=1) / np.sqrt(SEEDS))


def build_irradiance(*, path: pathlib.Path = TABLE) -> dict:
    """Add the diffuse irradiance at the surface (albedos 0 and 0.9, both aerosol depths,
    every elevation) to the table."""
    doc = json.loads(pathlib.Path(path).read_text())
    val, err = _grid(render_irradiance, IRRADIANCE_ALBEDOS, label="irradiance ", spp=SPP // 2)
    doc.update(irradiance_albedos=list(IRRADIANCE_ALBEDOS), irradiance_spp=SPP // 2,
               diffuse_irradiance=val.tolist(), diffuse_irradiance_standard_error=err.tolist())
    pathlib.Path(path).write_text(json.dumps(doc, indent=1))
    return doc


DEEP = ((-6.0, 1 << 20), (-8.0, 1 << 21))
"""Deep twilight, rendered again with 8x and 16x the samples (albedo 0.9, AOD 0.02): the few
paths that reach the sunlit air 35-60 km up carry the radiance there."""


def refine(*, path: pathlib.Path = TABLE) -> dict:
    """Add the deep-twilight renders (:data:`DEEP`) to the table as ``deep_twilight``."""
    doc = json.loads(pathlib.Path(path).read_text())
    col = column(0.02)
    rows = []
    for e, spp in DEEP:
        t = time.perf_counter()
        r, se = render(col=col, elevation_deg=e, albedo=0.9, spp=spp)
        rows.append({"elevation_deg": e, "albedo": 0.9, "aerosol_optical_depth": 0.02,
                     "spp": spp, "radiance_per_sr": r, "standard_error_per_sr": se,
                     "seconds": round(time.perf_counter() - t, 1)})
        print(rows[-1], flush=True)
    doc["deep_twilight"] = rows
    pathlib.Path(path).write_text(json.dumps(doc, indent=1))
    return doc


def load(path: pathlib.Path = TABLE) -> dict:
    """The committed table, arrays as numpy."""
    doc = json.loads(pathlib.Path(path).read_text())
    for key in ("radiance_per_sr", "standard_error_per_sr", "diffuse_irradiance",
                "diffuse_irradiance_standard_error"):
        if key in doc:
            doc[key] = np.asarray(doc[key])
    return doc


def lookup(doc: dict, *, elevation_deg: float, albedo: float,
           aerosol_optical_depth: float) -> float:
    """The table's radiance [sr^-1] interpolated linearly in albedo and aerosol optical depth
    and in log radiance against elevation (inside the table's grid)."""
    from scipy.interpolate import RegularGridInterpolator
    log = np.log(np.maximum(doc["radiance_per_sr"], 1e-30))
    f = RegularGridInterpolator((doc["aerosol_optical_depths"], doc["albedos"],
                                 doc["elevations_deg"]), log)
    return float(np.exp(f([[aerosol_optical_depth, albedo, elevation_deg]])[0]))


def bench(*, quick: bool) -> dict:
    """Seconds for one evaluation of the nadir radiance at 4 deg over snow (albedo 0.9, AOD
    0.05): the closed form (:func:`lidar_mitsuba.sky.sky`), the table's lookup, one render
    (``SPP / SEEDS`` samples per pixel: one of the table's 8 seeds); and their ratios."""
    import statistics
    kw = dict(elevation_deg=4.0, albedo=0.9, aerosol_optical_depth=0.05)
    doc = load()

    def timed(fn, repeats):
        fn()
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t)
        return statistics.median(times)
    closed_s = timed(lambda: closed_form(aerosol_optical_depth=0.05, albedo=0.9,
                                         elevations_deg=[4.0]), 20)
    lookup_s = timed(lambda: lookup(doc, **kw), 20)
    col = column(0.05)
    render_s = timed(lambda: render_once(col=col, elevation_deg=4.0, albedo=0.9),
                     1 if quick else 3)
    return {"closed_form_s": closed_s, "table_lookup_s": lookup_s, "render_s": render_s,
            "render_over_closed_form": render_s / closed_s,
            "closed_form_over_lookup": closed_s / lookup_s}


def format_bench(row: dict) -> str:
    return (f"sky, one nadir radiance (4 deg, snow): closed form {row['closed_form_s'] * 1e3:.1f} "
            f"ms, table lookup {row['table_lookup_s'] * 1e3:.2f} ms "
            f"({row['closed_form_over_lookup']:.0f}x faster), one render "
            f"{row['render_s']:.1f} s ({row['render_over_closed_form']:.0f}x the closed form)")


def chart(doc: dict, path: pathlib.Path = CHART) -> None:
    """Closed form (lines: all orders solid, first order dotted) against the renders (points
    with 2-sigma bars; open squares: the deep-twilight renders with more samples), and their
    ratio."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    e = np.asarray(doc["elevations_deg"])
    fine = np.linspace(e.min(), e.max(), 200)
    fig, (ax, rx, ix) = plt.subplots(3, 1, figsize=(6.4, 8.0), sharex=True,
                                     gridspec_kw={"height_ratios": [2, 1, 1]})
    for i, aod in enumerate(doc["aerosol_optical_depths"]):
        for j, alb in enumerate(doc["albedos"]):
            c = f"C{j + 3 * i}"
            lab = f"albedo {alb:g}, AOD {aod:g}"
            ax.plot(fine, closed_form(aerosol_optical_depth=aod, albedo=alb, elevations_deg=fine),
                    color=c, lw=1)
            ax.plot(fine, closed_form(aerosol_optical_depth=aod, albedo=alb, elevations_deg=fine,
                                      multiple_scattering=False), color=c, lw=0.7, ls=":")
            r, s = doc["radiance_per_sr"][i, j], doc["standard_error_per_sr"][i, j]
            ax.errorbar(e, r, yerr=2 * s, fmt="o", ms=3, color=c, label=lab)
            cf = closed_form(aerosol_optical_depth=aod, albedo=alb, elevations_deg=e)
            rx.errorbar(e, cf / r, yerr=2 * s * cf / r ** 2, fmt="o-", ms=3, lw=0.7, color=c)
    for row in doc.get("deep_twilight", []):
        r, s = row["radiance_per_sr"], row["standard_error_per_sr"]
        cf = closed_form(aerosol_optical_depth=row["aerosol_optical_depth"], albedo=row["albedo"],
                         elevations_deg=[row["elevation_deg"]])[0]
        ax.errorbar([row["elevation_deg"]], [r], yerr=[2 * s], fmt="s", ms=4, mfc="none",
                    color="k")
        rx.errorbar([row["elevation_deg"]], [cf / r], yerr=[2 * s * cf / r ** 2], fmt="s",
                    ms=4, mfc="none", color="k")
    ax.set_yscale("log")
    ax.set_ylabel("nadir radiance / E0 [sr$^{-1}$]")
    ax.legend(fontsize=7)
    ax.set_title("Sky at 532 nm: closed form (lines; dotted: first order) vs Mitsuba (points)",
                 fontsize=9)
    rx.axhline(1.0, color="k", lw=0.5)
    rx.set_ylabel("nadir radiance:\nclosed form / render", fontsize=8)
    rx.set_ylim(0.3, 1.7)
    _irradiance_panel(doc, ix)
    ix.set_xlabel("solar elevation [deg] (geometric, no refraction)")
    for a in (ax, rx, ix):
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _irradiance_panel(doc: dict, ix) -> None:
    """The diffuse irradiance at the surface: closed form / render."""
    e = np.asarray(doc["elevations_deg"])
    for i, aod in enumerate(doc.get("aerosol_optical_depths", [])):
        for j, alb in enumerate(doc.get("irradiance_albedos", [])):
            r = doc["diffuse_irradiance"][i, j]
            s = doc["diffuse_irradiance_standard_error"][i, j]
            ok = r > 0
            cf = sky.sky(solar_elevation_deg=e[ok], z_m=0.0, albedo=alb,
                         tau_rayleigh=doc["tau_rayleigh"], aerosol_optical_depth=aod,
                         refraction=False).diffuse
            c = f"C{doc['albedos'].index(alb) + 3 * i}"
            ix.errorbar(e[ok], cf / r[ok], yerr=2 * s[ok] * cf / r[ok] ** 2, fmt="o-", ms=3,
                        lw=0.7, color=c)
    ix.axhline(1.0, color="k", lw=0.5)
    ix.set_ylabel("diffuse irradiance:\nclosed form / render", fontsize=8)
    ix.set_ylim(0.3, 1.7)


if __name__ == "__main__":
    build()
    refine()
    chart(load(build_irradiance()))
