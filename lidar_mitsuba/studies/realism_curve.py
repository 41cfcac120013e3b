"""The realism figure's model curves (:mod:`lidar_mitsuba.studies.realism`,
``realism_background.png``): the background ATLAS's strong and weak beams would report over
clear snow against solar elevation, with the laser's own photons counted into it as the
matrix counts them (:func:`lidar_mitsuba.night.atl03_leak`), not by a fixed span.

The matrix's beams take their laser photons from a short simulation of their file's shots; a
curve has no file, so its photons are drawn from the same physics in closed form (no
rendering, no dead time: :func:`laser_photons`), and go through the same finder, the same
rule and the same band as a beam's (``realism._atl03_leak``): the leak then depends on the
sun only through the finder's background, as a beam's does."""
from __future__ import annotations

import numpy as np

CURVE_SHOTS = 200
"""Shots of laser photons a curve's leak is counted on: the matrix's ``--signal-shots``
default (four 50-shot rows)."""
LEAK_ELEVATIONS_DEG = (-10.0, -5.0, 0.0, 10.0, 35.0)
"""Solar elevations [deg] at which a curve's leak is counted, linear between them (it moves
with the finder's background only: flat at night, by day a hundredth of the sunlight)."""
LEAK_REALIZATIONS = 4
"""Draws of the noise a curve's leak averages (the matrix's 32 average a cloud's thinning
too; a curve has no cloud, and at night its gate holds ~0.02 noise photons in 200 shots)."""


def laser_photons(inst, *, surface: dict, z_m: float, shots: int,
                  rng: np.random.Generator) -> dict:
    """What :func:`~lidar_mitsuba.night.atl03_leak` needs, drawn without a simulation: each
    shot's detected surface photons Poisson with the lidar equation's mean
    (:func:`~lidar_mitsuba.studies.realism.radiometric_signal`; no dead time, which takes
    ~10 % of a strong beam's), their heights [m] from the Gaussian transmit pulse and the
    receiver's response (:mod:`lidar_mitsuba.detector.impulse`: tail and echoes, less its
    calibration) and the snow's volume return
    (:func:`~lidar_mitsuba.ground.snow.delay.delay_heights`, the surface's pack and share,
    :func:`~lidar_mitsuba.studies.realism_inputs.snow_delay`), a flat surface at height 0,
    the gate centred on it; afterpulses as the response's probability."""
    from ..constants import C_M_PER_NS
    from ..detector.impulse import response_of
    from .realism import radiometric_signal
    from .realism_inputs import snow_delay
    resp = response_of(inst)
    mean = radiometric_signal(inst, z_m=z_m, surface=surface)
    shot = np.repeat(np.arange(shots), rng.poisson(mean, shots))
    t_ns = rng.normal(0.0, inst.pulse_sigma_ns, shot.size)
    if resp.adds_delay:
        t_ns += resp.sample_delay_ns(shot.size, rng) - resp.calibration_ns()
    h = -C_M_PER_NS * t_ns / 2.0
    pack, share = snow_delay(surface)
    if pack is not None:
        from ..ground.snow import delay
        h = delay.delay_heights(h, pack, share=share, rng=rng)
    return {"shot": shot, "h_m": h, "is_signal": np.ones(shot.size, bool), "n_shots": shots,
            "gate_center_h_m": np.zeros(shots), "range_gate_m": float(inst.range_gate_m),
            "afterpulse_probability": resp.afterpulse_probability}


def background_curve(*, elevations_deg=None, z_m: float = 0.0, seed: int = 0) -> dict:
    """The model's background [Hz, detected] against solar elevation for ATLAS's strong and
    weak beams over clear snow (albedo 0.9, the ice sheet's snow) at sea level, the 2018
    energy, 18 March (Earth-Sun distance ~1 au), the polar band defaults, the leak counted
    as the matrix counts it on :data:`CURVE_SHOTS` shots of :func:`laser_photons` at
    :data:`LEAK_ELEVATIONS_DEG` (``realism._atl03_leak``): ``{"elevation_deg": [...],
    "strong": [...], "weak": [...], "leak_hz": {"strong": [...], "weak": [...]}}``."""
    from .. import night
    from ..instrument import Instrument
    from .realism import PRODUCT_SURFACES, _atl03_leak
    el = np.linspace(-10.0, 35.0, 46) if elevations_deg is None else np.asarray(elevations_deg)
    t = np.full(1, 6.6e6)                        # 2018-03-18, s since 2018-01-01
    surface = PRODUCT_SURFACES["land ice"]
    out = {"elevation_deg": np.asarray(el, float).tolist(), "leak_hz": {}}
    for k, kind in enumerate(("strong", "weak")):
        inst = Instrument.atlas(kind)
        photons = laser_photons(inst, surface=surface, z_m=z_m, shots=CURVE_SHOTS,
                                rng=np.random.default_rng(seed + k))

        def kw(e):
            return dict(delta_time_s=t, z_m=np.array([z_m]), albedo=0.9,
                        solar_elevation_deg=np.array([e]), solar_azimuth_deg=np.zeros(1))
        leak = [_atl03_leak(inst, photons, band=night.HistogramBand(), seed=seed + 10 * k + j,
                            kw=kw(e), realizations=LEAK_REALIZATIONS)["leak_hz"]
                for j, e in enumerate(LEAK_ELEVATIONS_DEG)]
        at = np.interp(el, LEAK_ELEVATIONS_DEG, leak)
        out["leak_hz"][kind] = at.tolist()
        out[kind] = [night.background_terms(inst, leak_hz=float(lk), **kw(e))["total"]
                     for e, lk in zip(el, at)]
    return out
