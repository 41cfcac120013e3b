"""Compare BRDF variants on the simulated returns: sweeps over surfaces, a table and figures.

One *row* is one :func:`~lidar_mitsuba.run.simulate` run (one BRDF on one surface) reduced
to photons per shot, elevation bias and precision of the signal photons, each with its Monte
Carlo standard error. Every variant on a surface is run with the same ``seed``, so the footprint
positions and pulse times of the traced photons are the same for all of them (common random
numbers): the *differences* between variants are less noisy than the per-row error bars.

Where the code is: this module runs the simulations (:func:`sweep`);
:mod:`~lidar_mitsuba.studies.brdf_rows` reduces a run to a row and reads rows
(:func:`row_of`, :func:`select`, :func:`relative_to`, :func:`format_table`);
:mod:`~lidar_mitsuba.studies.brdf_plots` draws them (:func:`plot_sweep`) and
:mod:`~lidar_mitsuba.studies.brdf_conclusions` puts them in words (:func:`conclusions`). Every
name is importable from here.

>>> import lidar_mitsuba
>>> from lidar_mitsuba.studies import brdf_variants as compare
>>> rows = compare.sweep(variants=compare.BRDF_VARIANTS,
...                      surfaces=compare.slope_surfaces(slopes_deg=(0, 10, 20)),
...                      shots=2000, seed=1, beam="strong")          # doctest: +SKIP
>>> fig = compare.plot_sweep(rows, x="slope_deg")                    # doctest: +SKIP
"""
from __future__ import annotations

import functools
import math
import time
from collections.abc import Iterable, Mapping, Sequence

from ..instrument import Instrument
from ..run import simulate
from ..ground.surface import SurfaceSpec
from .brdf_conclusions import conclusions  # noqa: F401 (re-exported)
from .brdf_plots import STYLES, plot_sweep  # noqa: F401 (re-exported)
from .brdf_rows import ROW_FIELDS, format_table, relative_to, row_of, select, surface_label  # noqa: F401 (re-exported)

_WARD = {"type": "ward", "rho_d": 0.9, "rho_s": 0.05, "alpha": 0.3}

#: BRDF variants compared, name -> Mitsuba BSDF dict (mono variants: one scalar per quantity).
#:
#: * the paper's Ward snow (rho_d 0.9, rho_s 0.05, alpha 0.3) with its three normalisations of
#:   the specular lobe (they agree exactly at normal incidence and differ off normal);
#: * a Lambertian 0.9 plate, the instrument's radiometric reference (return weight exactly 1
#:   on a flat plate at nadir);
#: * Mitsuba's ``roughplastic`` (diffuse 0.9 under a dielectric coating of IOR 1.49 with a
#:   rough interface, alpha 0.3), Beckmann and GGX. Its diffuse part is attenuated by the
#:   coating's Fresnel transmission and internal reflection, which Mitsuba integrates over the
#:   chosen microfacet distribution, so ``diffuse_reflectance`` 0.9 returns less than the 0.9
#:   Lambertian plate, and GGX (longer tails) less than Beckmann;
#: * Mitsuba's ``roughconductor`` (Beckmann, alpha 0.3) with ``material="none"`` (a Fresnel
#:   factor of exactly 1, spectrally flat, so nothing depends on how a mono variant reduces a
#:   metal's spectral IOR) scaled by ``specular_reflectance`` 0.9 to the snow's albedo. With no
#:   diffuse part its nadir return is the lobe peak, 1/(4 alpha^2) * 0.9 / 0.9 = 2.78 times the
#:   Lambertian plate's, and it falls off as the Beckmann distribution exp(-tan^2(theta)/alpha^2).
BRDF_VARIANTS: dict[str, dict] = {
    "Ward ward1992": {**_WARD, "normalization": "ward1992"},
    "Ward duer": {**_WARD, "normalization": "duer"},
    "Ward balanced": {**_WARD, "normalization": "balanced"},
    "Lambertian": {"type": "diffuse", "reflectance": 0.9},
    "roughplastic Beckmann": {"type": "roughplastic", "diffuse_reflectance": 0.9, "alpha": 0.3,
                              "distribution": "beckmann"},
    "roughplastic GGX": {"type": "roughplastic", "diffuse_reflectance": 0.9, "alpha": 0.3,
                         "distribution": "ggx"},
    "roughconductor": {"type": "roughconductor", "material": "none", "alpha": 0.3,
                       "distribution": "beckmann", "specular_reflectance": 0.9},
}

def slope_surfaces(*, slopes_deg: Iterable[float] = (0, 5, 10, 15, 20, 25, 30),
                   azimuth_deg: float = 0.0) -> list[SurfaceSpec]:
    """Sloped planes, one per slope [deg] (0 is the flat plate), rising along ``azimuth_deg``."""
    return [SurfaceSpec(kind="slope", slope_deg=float(s), slope_azimuth_deg=float(azimuth_deg))
            for s in slopes_deg]


def fractal_surfaces(*, ps: Iterable[float] = (1.5, 1.6, 1.8, 2.0), relief_m: float = 10.0,
                     size_m: float = 1024.0, grid_m: float = 1.0,
                     terrain_seed: int = 0) -> list[SurfaceSpec]:
    """Fractal snow tiles, one per spectral exponent ``p``, all from the same white noise
    (``terrain_seed``), each scaled to ``relief_m`` max - min [m] over a ``size_m`` tile [m]."""
    return [SurfaceSpec(kind="fractal", p=float(p), relief_m=float(relief_m), size_m=float(size_m),
                        grid_m=float(grid_m), terrain_seed=int(terrain_seed)) for p in ps]


def _instrument(beam: str | Instrument, ideal_detector: bool | None) -> Instrument:
    inst = beam if isinstance(beam, Instrument) else Instrument(beam=beam)
    if ideal_detector is not None and inst.ideal_detector != ideal_detector:
        inst = inst.replace(ideal_detector=bool(ideal_detector))
    return inst


def sweep(*, variants: Mapping[str, dict], surfaces: Sequence[SurfaceSpec], shots: int,
          seed: int = 0, beam: str | Instrument = "strong", ideal_detector: bool | None = None,
          paths_per_shot: int = 128, max_depth: int | str = 1,
          progress: bool = False, workers: int | None = None) -> list[dict]:
    """Simulate every BRDF variant on every surface and summarise each run.

    Args:
        variants: name -> Mitsuba BSDF dict (e.g. :data:`BRDF_VARIANTS`), replacing the
            surface's Ward BSDF.
        surfaces: the surfaces (e.g. :func:`slope_surfaces`, :func:`fractal_surfaces`); their
            own Ward parameters are ignored.
        shots: laser shots per run (the track: ``shots`` x 0.7 m, folded into the tile).
        seed: photon and detector seed, the same for every run (common random numbers).
        beam: ``"strong"``, ``"weak"`` or an :class:`~lidar_mitsuba.instrument.Instrument`.
        ideal_detector: override the instrument's dead time (``True``: none); ``None`` keeps it.
        paths_per_shot: traced photon paths per shot.
        max_depth: surface interactions per path. Default 1: every BRDF under one model (the
            paper's single bounce), so that common random numbers pair the runs; 2 adds
            multiple scattering; ``"auto"`` lets each run choose (see
            :func:`~lidar_mitsuba.run.simulate`), which may differ between BRDFs.
        progress: print one line per run.
        workers: run the simulations as tasks on a Dask ``LocalCluster`` of this many
            processes (:func:`lidar_mitsuba.sweep.compute_all`); the rows are the same.

    Returns:
        ``len(surfaces) * len(variants)`` rows (surface-major), each a dict with ``variant``,
        ``bsdf`` (the BSDF's plugin type), ``beam``, ``ideal_detector``, ``dead_time_ns``
        [ns], ``kind``, ``slope_deg`` [deg], ``p`` (NaN off fractals), ``relief_m`` [m],
        ``size_m`` [m], ``terrain_seed``, ``seed``, ``max_depth`` (the one used),
        ``time_s`` [s] and the fields of
        :func:`row_of` (``shots``, ``n_photons``, ``photons_per_shot``,
        ``photons_per_shot_se``, ``return_weight``, ``bias_m``, ``bias_se_m``, ``std_m``,
        ``std_se_m``).
    """
    inst = _instrument(beam, ideal_detector)
    if not variants:
        raise ValueError("variants: give at least one BRDF")
    runs = {(i, name): functools.partial(
        simulate, instrument=inst, surface=surface, bsdf=dict(bsdf), shots=shots, seed=seed,
        paths_per_shot=paths_per_shot, max_depth=max_depth, progress=False)
        for i, surface in enumerate(surfaces) for name, bsdf in variants.items()}
    if workers:
        from ..sweep import compute_all
        done = compute_all({k: functools.partial(_row_of_run, fn) for k, fn in runs.items()},
                           workers=workers)
    rows = []
    for (i, name), fn in runs.items():
        surface, bsdf = surfaces[i], variants[name]
        (max_used, summary), seconds = done[(i, name)] if workers else _timed_row(fn)
        row = {"variant": name, "bsdf": str(bsdf.get("type", "")), "beam": inst.beam,
               "ideal_detector": inst.ideal_detector,
               "dead_time_ns": float(inst.effective_dead_time_ns), "kind": surface.kind,
               "slope_deg": float(surface.slope_deg) if surface.kind == "slope" else 0.0,
               "p": float(surface.p) if surface.kind == "fractal" else math.nan,
               "relief_m": float(surface.relief_m) if surface.kind == "fractal" else 0.0,
               "size_m": float(surface.size_m), "terrain_seed": int(surface.terrain_seed),
               "seed": int(seed), "max_depth": max_used, **summary, "time_s": seconds}
        rows.append(row)
        if progress:
            print(f"{surface_label(row):<16}{name:<24}{row['photons_per_shot']:7.3f} ph/shot "
                  f"({row['time_s']:.2f} s)", flush=True)
    return rows


def _row_of_run(run) -> tuple[int, dict]:
    """(max_depth used, :func:`row_of`) of ``run()``: small enough to send back from a worker."""
    res = run()
    return int(res.config["max_depth"]), row_of(res)


def _timed_row(run):
    t0 = time.perf_counter()
    out = _row_of_run(run)
    return out, time.perf_counter() - t0
