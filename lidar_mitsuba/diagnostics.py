"""A run's modelling choices in words (``lidar-mitsuba simulate --explain``) and the warnings a
finished run deserves: no photons and why, shots with no surface under them, too few paths
per shot. Called by :func:`lidar_mitsuba.run.simulate` once the photons are in."""
from __future__ import annotations

import numpy as np

from .trace import path_budget


def choices_and_warnings(*, instrument, surf, max_depth, pilot, paths_per_shot, crop, triangles,
             det, material, shots=0, timings=None, budget=None,
             facet_m=None) -> tuple[list[str], list[str]]:
    """The modelling choices of a run in words (``lidar-mitsuba simulate --explain``), and
    the ones that deserve a warning. The ``material``
    (:class:`~lidar_mitsuba.ground.materials.Material`) says its own words first; a surface
    that leaves the model to the bounces gets the pilot's."""
    out, warns = [], []
    words = material.choices(max_depth=max_depth, fov_radius_m=instrument.fov_diameter_m / 2,
                             shots=shots, timings_s=timings or {}, facet_m=facet_m)
    if words is not None:
        out += words[0]
        warns += words[1]
    elif surf.exact_single_bounce and max_depth == 1:
        out.append("single bounce (max_depth 1): exact for a plane, where nothing bounces twice")
    elif pilot is not None:
        from .trace import pilot as bounce_pilot
        out.append(bounce_pilot.explain(pilot, max_depth))
    elif max_depth == 1:
        out.append("single bounce (max_depth 1, the paper's model, as asked): each photon's "
                   "first-surface return, which at nadir comes back along its own incident ray; "
                   "it leaves out multiple scattering between terrain facets (--max-depth auto "
                   "checks whether that matters)")
    else:
        out.append(f"{max_depth} bounces per path with shadow-tested returns toward the receiver")
    out += surf.notes(instrument=instrument, max_depth=1 if material.volume else max_depth,
                      crop=crop, triangles=triangles)
    warns += surf.warnings(instrument=instrument)
    peak = float(np.max(det.mean_photons_per_shot)) if det.mean_photons_per_shot.size else 0.0
    kept = peak * instrument.fill_factor * instrument.pde
    if budget is not None:
        out.append(path_budget.explain(budget))
    msg = (("" if budget is not None else f"{paths_per_shot} paths per shot for ")
           + f"up to {peak:.1f} photons per shot ({kept:.1f} after fill factor and PDE); "
           f"{det.run_out_shots.size} of {shots} shots ran out of distinct paths")
    out.append(msg)
    ran_out = path_budget.run_out_warning(int(det.run_out_shots.size), int(shots))
    if ran_out is not None:
        warns.append(ran_out)
    return out, warns


def diagnose(*, surf, scene_of, x_m, y_m, surface_z, n_returns, det,
              instrument) -> list[str]:
    """Warnings for shots with no surface under them and for a run that detected no signal
    photon, with the likely cause. ``scene_of()``: the scene of the shots ``x_m``, ``y_m``
    (called only when a warning needs it)."""
    out = []
    missing = ~np.isfinite(surface_z)
    n = surface_z.size
    if missing.all():
        from .trace import scene as scn
        lo, hi = scn.scene_bounds(scene_of())
        return [f"no surface under any of the {n} footprint centres: the track (x "
                f"{np.min(x_m):g} .. {np.max(x_m):g} m, y {np.min(y_m):g} .. {np.max(y_m):g} m) "
                f"misses the geometry (x {lo[0]:g} .. {hi[0]:g} m, y {lo[1]:g} .. {hi[1]:g} m); "
                "its shots record background noise only"]
    if missing.any():
        out.append(f"{int(missing.sum())} of the {n} shots have no surface under their footprint "
                   "centre: they record background noise only")
    if det.is_signal.any():
        return out
    if n_returns == 0:
        from .trace import scene as scn
        _, nz = scn.cast_down(scene_of(), x_m[~missing], y_m[~missing])
        if np.nanmean(nz < 0) > 0.5:
            out.append("no photon came back: the surfaces under the track face down, away from "
                       "the lidar (a face-down rectangle, or a mesh whose triangles wind the "
                       "other way); Mitsuba's BSDFs are one-sided and return nothing from the "
                       "back: flip the shape (rotate it, or reverse its faces)")
        else:
            out.append("no photon came back: the surfaces' BSDF sends no light back toward the "
                       "receiver (e.g. a smooth conductor or dielectric reflects only in the "
                       "mirror direction); use a rough or diffuse BSDF")
    else:
        mu = float(np.mean(det.mean_photons_per_shot))
        out.append(f"returns were traced but no signal photon was detected: {mu:.3g} photons "
                   f"per shot reach the detector on average ({instrument.signal_photons:g} "
                   f"from the reference plate); raise --signal-photons or the shot count")
    return out
