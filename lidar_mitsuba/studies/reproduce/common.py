"""Shared set-up of the reproduction: sample counts, seeds, the paper's statements, the
tracks and detectors (one trace, several detectors), statistics, trends and formatting."""
from __future__ import annotations

import math
import os
import pathlib
from dataclasses import dataclass

import numpy as np

from ...trace import stream as chunks
from ...products import retrieval
from ...ground import terrain
from ...instrument import Instrument
from ...run import simulate
from ...ground.surface import SurfaceSpec
from ...track import Track as TrackLine
from ...trace.lazy import mi

P_VALUES = (1.5, 1.6, 1.7, 1.8, 1.9, 2.0)
SLOPES_DEG = (0.0, 2.0, 4.0, 6.0, 8.0, 10.0)
ALBEDOS = (0.6, 0.7, 0.8, 0.9)
PIXELS = (16, 4, 1)               # Fig. 7 detectors besides the ideal one
SEGMENT_M = 16                    # Fig. 5: along-track segment length [m], about one footprint
RMS_LENGTHS_M = (16, 64, 256, 1024)
CHUNK_SHOTS = chunks.CHUNK_SHOTS  # simulate()'s shot chunk; redetect() splits the same way
ATM_SPACING_M = 1.68              # the paper's ATM profile: 512 points over ~860 m
ATM_POINTS = 512
SEEDS = {"fig7": 7, "fig9": 9, "fig12": 1200, "fig13": 1300}
"""Photon Monte Carlo seeds. Fractal realisation s of Figs. 10-13 uses seed + s: realisations are
independent in photons as well as terrain (within one, all p or albedos share the photons)."""

PNG = {
    "fig3": "fig03_power_spectra.png", "fig4": "fig04_surfaces.png",
    "fig5": "fig05_rms_height.png", "fig6": "fig06_ward_brdf.png",
    "fig7": "fig07_flat_pixels.png", "fig8": "fig08_slope_histograms.png",
    "fig9": "fig09_slope_bias_std.png", "fig10": "fig10_photon_cloud.png",
    "fig11": "fig11_weak_pixels_vs_p.png", "fig12": "fig12_bias_std_vs_p.png",
    "fig13": "fig13_albedo.png",
}

#: What the paper states for each figure (its figures are images; these are its words).
PAPER = {
    "fig3": "p between 1.5 and 2.0 fits the ATM profile's power spectrum best; the simulated "
            "spectrum is the 1/f^p filter times white noise",
    "fig4": "1024 x 1024 m scenes, total elevation range approximately 10 m; larger p looks "
            "smoother",
    "fig5": "RMS height of sample along-track profiles: a larger p is a less rough surface",
    "fig6": "Ward BRDF, rho_d = 0.9, rho_s = 0.05, alpha_x = alpha_y = 0.3, theta_i = 0 and 20 deg",
    "fig7": "N = 200,000 weak-beam shots on a flat plate: the ideal detector shows no bias; real "
            "detectors are biased high (first-photon bias); more pixels bring the bias closer "
            "to 0",
    "fig8": "N = 50,000 strong-beam shots per slope: the spread grows with slope; fewer photons "
            "arrive as slopes become steeper (Ward BRDF)",
    "fig9": "0-10 deg: the mean elevation bias increases with slope; the standard deviation "
            "keeps going up",
    "fig10": "1000 shots, p = 1.8: photons scatter about the along-track reference profile",
    "fig11": "weak beam, 4 outputs A-D: the standard deviation becomes smaller as p increases",
    "fig12": "bias up to 2 cm and a standard deviation of 10 cm (abstract); bias approximately "
             "similar for weak and strong beams; less rough (larger p) gives higher accuracy",
    "fig13": "strong beam, p = 2.0, rho_d 0.6-0.9: both curves vary slightly; a smaller diffuse "
             "albedo gives a smaller bias, because a decrease in diffuse reflection increases "
             "the quasi-specular reflection",
}


TITLES = {
    "fig3": "Fig. 3 — power spectra and the fitted p", "fig4": "Fig. 4 — synthetic surfaces",
    "fig5": "Fig. 5 — RMS height against p", "fig6": "Fig. 6 — Ward BRDF",
    "fig7": "Fig. 7 — flat plate, weak beam, pixels", "fig8": "Fig. 8 — sloped planes: histograms",
    "fig9": "Fig. 9 — bias and precision against slope",
    "fig10": "Fig. 10 — photon cloud over fractal snow",
    "fig11": "Fig. 11 — weak beam outputs A–D against p",
    "fig12": "Fig. 12 — bias and precision against p, weak and strong beams",
    "fig13": "Fig. 13 — bias and precision against diffuse albedo",
}


@dataclass(frozen=True)
class Counts:
    """Sample counts of one reproduction.

    Attributes:
        flat_shots: Fig. 7 shots (paper: 200,000).
        slope_shots: Figs. 8-9 shots per slope (paper: 50,000).
        complex_shots: Figs. 10-13 shots per fractal track (paper: 1000).
        terrain_seeds: fractal realisations per complex-surface configuration (ours; the paper
            ran one). Seed 0 is the primary track.
        resolve_shots: Fig. 13 supplement (ours): shots per albedo on one long track, enough to
            resolve the ~0.1 cm albedo effect that 1000 shots cannot.
        paths_per_shot: photon paths traced per shot.
        p_values, slopes_deg, albedos: the configurations of Figs. 10-13, 8-9 and 13.
    """
    flat_shots: int = 200_000
    slope_shots: int = 50_000
    complex_shots: int = 1000
    terrain_seeds: int = 5
    resolve_shots: int = 20_000
    paths_per_shot: int = 128
    p_values: tuple = P_VALUES
    slopes_deg: tuple = SLOPES_DEG
    albedos: tuple = ALBEDOS


FULL = Counts()


#: The tests' mode: the same code on fewer shots and fewer configurations (each simulate call
#: has ~0.2 s of fixed cost, so the number of configurations sets the run time).
QUICK = Counts(flat_shots=10_000, slope_shots=5_000, complex_shots=300, terrain_seeds=2,
               resolve_shots=2_000, p_values=(1.5, 1.8, 2.0), slopes_deg=(0.0, 4.0, 10.0),
               albedos=(0.6, 0.9))


def counts_for(quick: bool) -> Counts:
    return QUICK if quick else FULL


def elevation_stats(dh_m, *, shots: int) -> dict:
    """Bias and precision of residuals ``dh_m`` [m] with their Monte Carlo standard errors
    (:func:`lidar_mitsuba.products.retrieval.elevation_stats`), as a dict."""
    return retrieval.elevation_stats(dh_m, shots=shots).to_dict()


@dataclass
class Track:
    """Detected signal photons of one track: shot index, channel and h - z_ref [m]."""
    n_shots: int
    n_channels: int
    shot: np.ndarray
    channel: np.ndarray
    dh_m: np.ndarray
    mean_photons_per_shot: float      # the Poisson mean reaching the detector

    def stats(self) -> dict:
        return elevation_stats(self.dh_m, shots=self.n_shots)

    def channel_stats(self) -> list[dict]:
        return [elevation_stats(self.dh_m[self.channel == c], shots=self.n_shots)
                for c in range(self.n_channels)]


def track_of(res) -> Track:
    """The signal photons of a :class:`~lidar_mitsuba.run.SimulationResult`."""
    d = res.detections
    sig = d.is_signal
    return Track(n_shots=res.n_shots, n_channels=res.instrument.channels, shot=d.shot[sig],
                 channel=d.channel[sig], dh_m=res.dh_m[sig],
                 mean_photons_per_shot=float(np.mean(d.mean_photons_per_shot)))


def redetect(res, instrument: Instrument, *, seed: int, chunk_shots: int = CHUNK_SHOTS) -> Track:
    """Run another detector on a simulation's traced returns (``simulate(keep_returns=True)``).

    Only the PMT runs again, through the same chunk loop (:mod:`lidar_mitsuba.trace.stream`) and
    detector streams as :func:`~lidar_mitsuba.run.simulate`, so the result is exactly
    what ``simulate(instrument=instrument, <same surface>, seed=seed, chunk_shots=chunk_shots)``
    gives, at the cost of the detector alone. ``instrument`` must share the run's geometry
    (altitude, footprint, pulse, field of view); signal level, channels, dead time and noise
    may differ.
    """
    if res.returns is None:
        raise ValueError("the result has no traced returns: simulate(..., keep_returns=True)")
    if instrument.integrator_dict() != res.instrument.integrator_dict():
        raise ValueError("the instrument's geometry (altitude, footprint, pulse, field of view) "
                         "differs from the traced run's")
    run = chunks.run(source=chunks.replayed(res.returns), detectors={"redetect": instrument},
                     z_ref_m=res.z_ref_m, seed=seed, chunk_shots=chunk_shots)
    return _track(run.detections["redetect"], instrument, res.z_ref_m)


def _track(det, instrument: Instrument, z_ref_m: np.ndarray) -> Track:
    """The signal photons of detections ``det`` as a :class:`Track`."""
    sig = det.is_signal
    h = retrieval.photon_heights_m(det.time_ns[sig], altitude_m=instrument.altitude_m)
    shot = det.shot[sig]
    return Track(n_shots=int(z_ref_m.size), n_channels=instrument.channels, shot=shot,
                 channel=det.channel[sig], dh_m=h - z_ref_m[shot],
                 mean_photons_per_shot=float(np.mean(det.mean_photons_per_shot)))


def _simulate(**kw):
    """``simulate`` with the paper's model: single bounce (photons that return along their own
    incident ray; Sec. III), not ``max_depth="auto"``, which adds a second bounce on rough
    fractals."""
    return simulate(progress=False, chunk_shots=CHUNK_SHOTS, keep_returns=True, max_depth=1, **kw)


def return_offset_m(res) -> float:
    """The bias without dead time, estimated from every traced path: the return-weighted mean of
    h - z_ref, sum(w (h - z_ref)) / sum(w). It estimates what an ideal detector measures on
    average (over traces as well as detector draws) from ``paths_per_shot`` paths per shot
    instead of the few photons a shot detects, free of detector noise; runs that share their
    traced paths (same seed) differ here only through the weights, so differences between
    BRDFs are nearly exact."""
    r = res.returns
    h = retrieval.photon_heights_m(r.time_ns, altitude_m=res.instrument.altitude_m)
    w = np.asarray(r.weight, np.float64)
    return float(np.sum(w * (h - res.z_ref_m[r.shot])) / np.sum(w))


def flat_plate_tracks(instruments: dict, *, shots: int, seed: int, paths_per_shot: int = 128,
                      chunk_shots: int = CHUNK_SHOTS) -> dict:
    """Several detectors on ONE trace of a flat plate (the paper's snow), chunk by chunk, without
    keeping the traced returns: ``{name: Track}`` for ``instruments = {name: Instrument}``
    (same geometry). The chunk loop and random streams are :func:`~lidar_mitsuba.run.
    simulate`'s (:mod:`lidar_mitsuba.trace.stream`), so each Track is exactly what
    ``simulate(instrument=..., surface=SurfaceSpec(kind="flat"), shots=shots, seed=seed)``
    detects (a test checks this)."""
    insts = list(instruments.values())
    geom = insts[0].integrator_dict()
    if any(i.integrator_dict() != geom for i in insts):
        raise ValueError("the instruments must share altitude, footprint, pulse and field of view")
    inst0 = insts[0]
    spec = SurfaceSpec(kind="flat")
    plane = spec.build()
    sigma = inst0.footprint_sigma_m
    _, x, y = TrackLine().positions(shots, spacing_m=inst0.shot_spacing_m,
                                    centre_xy_m=plane.centre_xy_m())
    x_loc, y_loc, dz = plane.fold(x, y)
    scene, _ = plane.mitsuba_scene(bsdf=spec.bsdf_dict(), margin_m=5.0 * sigma + 1.0,
                                   bounds_m=None)
    z_ref = plane.reference_elevation_m(x, y, sigma_m=sigma)
    integrator = mi.load_dict(inst0.integrator_dict(max_depth=1))
    run = chunks.run(source=chunks.traced(integrator, scene, x_m=x_loc, y_m=y_loc,
                                          paths_per_shot=paths_per_shot, dz_m=dz),
                     detectors=instruments, z_ref_m=z_ref, seed=seed, chunk_shots=chunk_shots)
    return {name: _track(run.detections[name], instruments[name], z_ref) for name in instruments}


def _fractal(p: float, seed: int) -> terrain.Heightfield:
    """The paper-sized fractal (1024 m, 1 m grid, 10 m relief) of exponent p, cached."""
    key = (float(p), int(seed))
    hf = _FRACTALS.get(key)
    if hf is None:
        if len(_FRACTALS) >= 64:
            _FRACTALS.pop(next(iter(_FRACTALS)))
        hf = _FRACTALS[key] = terrain.fractal(p=p, seed=seed)
    return hf


_FRACTALS: dict = {}


def _trend(x, y_by_seed, se_by_seed=None) -> dict:
    """Slope of y against x with its standard error.

    ``y_by_seed``: (S, len(x)) values on S independent terrain realisations (S = 1 for a plane).
    S >= 3: the mean of the per-seed least-squares slopes, SE from their scatter (terrain and
    photon noise together). S < 3: the slope of the seed-mean curve, SE propagated from the
    per-point Monte Carlo errors ``se_by_seed`` (photon noise only; common random numbers make
    this conservative for differences along x).
    """
    x = np.asarray(x, float)
    y = np.atleast_2d(np.asarray(y_by_seed, float))
    xc = x - x.mean()
    sxx = float((xc ** 2).sum())
    slopes = (y - y.mean(axis=1, keepdims=True)) @ xc / sxx
    s = y.shape[0]
    if s >= 3:
        return {"slope": float(slopes.mean()), "slope_se": float(slopes.std(ddof=1) / math.sqrt(s)),
                "method": f"mean of {s} per-realisation slopes"}
    se = np.atleast_2d(np.asarray(se_by_seed, float))
    se_mean = np.sqrt((se ** 2).mean(axis=0) / s)
    return {"slope": float(slopes.mean()),
            "slope_se": float(math.sqrt(float((xc ** 2 * se_mean ** 2).sum())) / sxx),
            "method": "Monte Carlo errors only" + (" (2 realisations)" if s == 2 else "")}


def _verdict(tr: dict, expected_sign: int | None, *, k: float = 2.0) -> str:
    """'agrees' / 'disagrees' / 'not significant' for a trend against the paper's sign."""
    z = tr["slope"] / tr["slope_se"] if tr["slope_se"] > 0 else math.copysign(math.inf, tr["slope"])
    if abs(z) < k:
        return "no significant trend"
    if expected_sign is None:
        return "significant trend"
    return "agrees" if np.sign(z) == expected_sign else "disagrees"


def _mean_se(values) -> tuple[float, float, float]:
    """(mean, standard error of the mean, standard deviation) over realisations."""
    v = np.asarray(values, float)
    if v.size < 2:
        return float(v.mean()), math.nan, math.nan
    sd = float(v.std(ddof=1))
    return float(v.mean()), sd / math.sqrt(v.size), sd


def _cm(v, se=None, nd=2) -> str:
    if v is None or not math.isfinite(v):
        return "n/a"
    s = f"{100 * v:.{nd}f}"
    if se is not None and math.isfinite(se):
        s += f" ± {100 * se:.{nd}f}"
    return s + " cm"


def _cli_simulate(**kw) -> str:
    parts = ["lidar-mitsuba simulate"]
    for key, v in kw.items():
        flag = "--" + key.replace("_", "-")
        parts.append(flag if v is True else f"{flag} {v:g}" if isinstance(v, float) else f"{flag} {v}")
    if kw.get("surface") == "fractal":
        parts.append("--max-depth 1")       # the paper's single bounce (planes: auto is 1)
    return " ".join(parts + ["--out run.h5"])


def _plt():
    from ...plotting import plt
    return plt


def _save(fig, path):
    if path is not None:
        plt = _plt()
        path = pathlib.Path(path)
        tmp = path.with_name(f".{path.name}.tmp.png")
        fig.savefig(tmp)
        os.replace(tmp, path)
        plt.close(fig)
    return fig


def _row(quantity, ours, paper, agreement, why="", **numbers) -> dict:
    return {"quantity": quantity, "ours": ours, "paper": paper, "agreement": agreement,
            "why": why, **numbers}


def _seq(values) -> str:
    return ", ".join(f"{v:.1f}" for v in values)


def _list_cm(values, nd=1) -> str:
    return ", ".join(f"{100 * v:.{nd}f}" for v in values) + " cm"


def _z(a, b, se_a, se_b=0.0) -> float:
    se = math.hypot(se_a, se_b)
    return (a - b) / se if se > 0 else math.inf
