"""Stability where methods fail: each model swept to its breaking point.

Every row is either a finite result with its accuracy stated (against a closed form where one
exists) or a status naming why there is no result. ``lidar-mitsuba bench`` runs these and
charts them (``stability.png``); ``tests/test_breaking_points.py`` pins the edges.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..constants import C_M_PER_NS, ParameterError
from ..instrument import Instrument
from ..run import simulate
from ..ground.surface import SurfaceSpec
from ..trace.lazy import mi


#: the shots of each simulated sweep's runs in a smoke run (quick: 100 to 300): ~70 m of
#: track, enough photons for a finite bias and spread in every row that has a result (the
#: sweeps' CPU, 9 s at the quick sizes on the 2-core VM, was a tenth of a smoke bench)
SMOKE_SHOTS = 100
#: the paths of the one-lane row of :func:`sweep_lanes` in a smoke run (else 2000): 200
#: launches of one lane each, still the per-launch overhead's rate (quick: 2.3 CPU-s, the
#: sweep's whole cost)
SMOKE_LANE_PATHS = 200


def _row(value, res=None, *, t0: float, **extra) -> dict:
    row = {"value": value, "seconds": time.perf_counter() - t0, **extra}
    if res is not None:
        st = res.report().overall
        row.update(photons_per_shot=st.photons_per_shot, bias_m=st.bias_m, std_m=st.std_m,
                   bias_se_m=st.bias_se_m, n_photons=st.n_photons)
        if "status" not in row:
            row["status"] = "ok" if st.n_photons > 1 else "no photons detected"
    return row


def _guard(value, fn) -> dict:
    t0 = time.perf_counter()
    try:
        return fn(t0)
    except (ParameterError, ValueError) as e:
        return {"value": value, "seconds": time.perf_counter() - t0, "status": f"refused: {e}"}


def sweep_slope(*, quick: bool, smoke: bool = False) -> list[dict]:
    """Planes up to 89 deg, ideal detector, strong beam. Closed form of the spread:
    sqrt((c sigma_t / 2)^2 + (sigma_fp tan theta)^2), valid while that spread fits the range
    gate (30 m): steeper, the gate truncates the return and the stats describe the gate."""
    shots = SMOKE_SHOTS if smoke else 300 if quick else 3000
    inst = Instrument(beam="strong", ideal_detector=True)
    rows = []
    for deg in (0, 10, 30, 45, 60, 75, 80, 85, 89):
        def run(t0, deg=deg):
            res = simulate(instrument=inst, surface=SurfaceSpec(kind="slope", slope_deg=deg),
                           shots=shots, seed=1, progress=False)
            spread = math.hypot(inst.ranging_sigma_m,
                                inst.footprint_sigma_m * math.tan(math.radians(deg)))
            status = ("ok" if 4 * spread < inst.range_gate_m else
                      f"return ({spread:.1f} m sd) wider than the {inst.range_gate_m:g} m gate: "
                      "truncated")
            return _row(deg, res, t0=t0, expected_std_m=spread, status=status)
        rows.append(_guard(deg, run))
    rows.append(_guard(90, lambda t0: _row(90, simulate(
        surface=SurfaceSpec(kind="slope", slope_deg=90), shots=1, progress=False), t0=t0)))
    return rows


def sweep_ward_alpha(*, quick: bool, smoke: bool = False) -> list[dict]:
    """Ward lobes down to near-mirrors on a flat plate: the return weight at nadir is
    pi (rho_d/pi + rho_s/(4 pi alpha^2)) / 0.9 (exact); 16 channels saturate once the
    photons per shot far exceed 16."""
    shots = SMOKE_SHOTS if smoke else 100 if quick else 500
    rows = []
    for alpha in (0.3, 0.1, 0.03, 0.01, 0.003, 0.001):
        def run(t0, alpha=alpha):
            res = simulate(surface=SurfaceSpec(kind="flat", alpha=alpha), shots=shots, seed=1,
                           progress=False)
            w = math.pi * (0.9 / math.pi + 0.05 / (4 * math.pi * alpha ** 2)) / 0.9
            mean = float(np.mean(res.detections.mean_photons_per_shot))
            return _row(alpha, res, t0=t0, expected_photons_per_shot=8.17 * w,
                        mean_photons_per_shot=mean)
        rows.append(_guard(alpha, run))
    rows.append(_guard(0.0, lambda t0: _row(0.0, simulate(
        surface=SurfaceSpec(kind="flat", alpha=0.0), shots=1, progress=False), t0=t0)))
    return rows


def sweep_signal(*, quick: bool, smoke: bool = False) -> list[dict]:
    """Signal from 1 to 1000 photons per shot on a flat Lambertian-like plate, 16 channels,
    3 ns dead time: the first-photon bias grows as channels saturate."""
    shots = SMOKE_SHOTS if smoke else 200 if quick else 2000
    rows = []
    for sig in (1, 3, 10, 30, 100, 300, 1000):
        def run(t0, sig=sig):
            res = simulate(instrument=Instrument(beam="strong", signal_photons=float(sig)),
                           surface=SurfaceSpec(kind="flat"), shots=shots, seed=1,
                           paths_per_shot=max(128, int(4 * sig)), progress=False)
            return _row(sig, res, t0=t0)
        rows.append(_guard(sig, run))
    return rows


def sweep_dead_time(*, quick: bool, smoke: bool = False) -> list[dict]:
    """Dead time 0-20 ns, strong beam, flat plate: 0 is the ideal detector (unbiased)."""
    shots = SMOKE_SHOTS if smoke else 300 if quick else 5000
    rows = []
    for dt in (0.0, 1.0, 3.0, 6.0, 10.0, 20.0):
        rows.append(_guard(dt, lambda t0, dt=dt: _row(dt, simulate(
            instrument=Instrument(beam="strong", dead_time_ns=dt),
            surface=SurfaceSpec(kind="flat"), shots=shots, seed=1, progress=False), t0=t0)))
    return rows


def sweep_p(*, quick: bool, smoke: bool = False) -> list[dict]:
    """Fractal exponent from 0.5 (rough, white-ish) to 4 (very smooth), 10 m relief."""
    shots = SMOKE_SHOTS if smoke else 300 if quick else 1000
    rows = []
    for p in (0.5, 1.0, 1.5, 2.0, 3.0, 4.0):
        rows.append(_guard(p, lambda t0, p=p: _row(p, simulate(
            surface=SurfaceSpec(kind="fractal", p=p, size_m=256.0), shots=shots, seed=1,
            progress=False), t0=t0)))
    rows.append(_guard(6.0, lambda t0: _row(6.0, simulate(
        surface=SurfaceSpec(kind="fractal", p=6.0), shots=1, progress=False), t0=t0)))
    return rows


def sweep_grid(*, quick: bool, smoke: bool = False) -> list[dict]:
    """Mesh spacing 0.25-16 m against the 10 m footprint (sigma 2.5 m): ONE 512 m terrain made
    at 0.25 m and decimated, so only the resolution changes. The error columns are against the
    finest mesh; spacing coarser than ~sigma/2 no longer resolves what the footprint sees."""
    from ..ground.terrain import Heightfield, fractal
    shots = SMOKE_SHOTS if smoke else 300 if quick else 2000
    fine = fractal(p=1.8, size_m=512.0, grid_m=0.25, relief_m=10.0, seed=0)
    rows = []
    for k in (1, 2, 4, 8, 16, 32, 64):
        hf = Heightfield(z_m=np.ascontiguousarray(fine.z_m[::k, ::k]), grid_m=0.25 * k)
        rows.append(_guard(hf.grid_m, lambda t0, hf=hf: _row(hf.grid_m, simulate(
            surface=hf, shots=shots, seed=1, progress=False), t0=t0)))
    ref = rows[0]
    for r in rows:
        if "std_m" in r and "std_m" in ref:
            r["std_error_vs_finest_m"] = r["std_m"] - ref["std_m"]
            r["bias_error_vs_finest_m"] = r["bias_m"] - ref["bias_m"]
    rows.append(_guard(0.01, lambda t0: _row(0.01, simulate(
        surface=SurfaceSpec(kind="fractal", size_m=1024.0, grid_m=0.01), shots=1,
        progress=False), t0=t0)))
    return rows


def sweep_altitude(*, quick: bool, smoke: bool = False) -> list[dict]:
    """Path-length precision from 1 km to 1000 km: zero pulse width over a plate at z = 1.234 m
    with the 2.5 m footprint; c t / 2 against the float64 distance from the spacecraft to each
    hit point. The row gives the worst error [m]."""
    rows = []
    z0 = 1.234
    scene = mi.load_dict({"type": "scene", "plate": {
        "type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, z0]).scale(100)}})
    xs = np.linspace(-50, 50, 101)
    z_exact = float(np.float32(z0))
    for h in (1e3, 1e4, 1e5, 496e3, 1e6):
        t0 = time.perf_counter()
        integ = mi.load_dict({"type": "pathlength", "altitude_m": h, "pulse_sigma_ns": 0.0})
        out = integ.trace(scene, shot_x_m=xs, shot_y_m=xs[::-1], paths_per_shot=64)
        leg = np.sqrt((out.x_m - xs[out.shot]) ** 2
                      + (out.y_m - xs[::-1][out.shot]) ** 2 + (h - z_exact) ** 2)
        err = float(np.max(np.abs(C_M_PER_NS * out.time_ns / 2 - leg)))
        f = np.float32       # the same leg in float32, as a naive pipeline would compute it
        leg32 = np.sqrt((f(out.x_m) - f(xs[out.shot])) ** 2
                        + (f(out.y_m) - f(xs[::-1][out.shot])) ** 2 + (f(h) - f(z_exact)) ** 2)
        rows.append({"value": h, "seconds": time.perf_counter() - t0, "max_error_m": err,
                     "float32_error_m": float(np.max(np.abs(leg32.astype(np.float64) - leg))),
                     "status": "ok" if err < 1e-3 else "path length error >= 1 mm"})
    return rows


def sweep_lanes(*, quick: bool, smoke: bool = False) -> list[dict]:
    """Photons per Dr.Jit launch from 1 to 10^8 (10^6 in quick mode): paths/s of the
    integrator on a plate; tiny launches are dominated by per-launch overhead."""
    scene = mi.load_dict({"type": "scene", "plate": {
        "type": "rectangle", "to_world": mi.ScalarTransform4f().scale(500),
        "bsdf": {"type": "diffuse", "reflectance": 0.9}}})
    rows = []
    for lanes in (1, 100, 10 ** 4, 10 ** 6) + (() if quick else (10 ** 8,)):
        total = SMOKE_LANE_PATHS if smoke and lanes == 1 else max(lanes, 2000)
        integ = mi.load_dict({"type": "pathlength", "max_lanes": lanes})
        n_shots = total // 1 if lanes == 1 else max(1, total // 100)
        k = 1 if lanes == 1 else 100
        xs = np.zeros(n_shots)
        t0 = time.perf_counter()
        out = integ.trace(scene, shot_x_m=xs, shot_y_m=xs, paths_per_shot=k)
        sec = time.perf_counter() - t0
        ok = len(out) == n_shots * k
        rows.append({"value": lanes, "seconds": sec, "paths": n_shots * k,
                     "paths_per_s": n_shots * k / sec, "status": "ok" if ok else "lost paths"})
    return rows


SWEEPS = {
    "slope_deg": sweep_slope, "ward_alpha": sweep_ward_alpha, "signal_photons": sweep_signal,
    "dead_time_ns": sweep_dead_time, "p": sweep_p, "grid_m": sweep_grid,
    "altitude_m": sweep_altitude, "photons_per_launch": sweep_lanes,
}


def run_all(*, quick: bool, smoke: bool = False) -> dict[str, list[dict]]:
    """Every sweep; a dict of name -> rows. ``smoke`` (the tests' size, ``bench --smoke``;
    implies ``quick``): every sweep's values and rows, each simulated sweep on
    :data:`SMOKE_SHOTS` shots and the one-lane launches on :data:`SMOKE_LANE_PATHS` paths
    (its numbers only show that the sweeps run; the refusals by design are the same)."""
    quick = quick or smoke
    return {name: fn(quick=quick, smoke=smoke) for name, fn in SWEEPS.items()}


def chart(results: dict[str, list[dict]], path):
    """One panel per sweep: the main quantity against the swept value; refused values marked.
    Saved to ``path``; returns the (closed) matplotlib Figure."""
    from ..plotting import plt
    panels = [
        ("slope_deg", "std_m", "expected_std_m", "slope [deg]", "precision [m]", "log"),
        ("ward_alpha", "mean_photons_per_shot", "expected_photons_per_shot", "Ward alpha",
         "photons/shot reaching the detector", "loglog"),
        ("signal_photons", "bias_m", None, "signal photons / shot", "bias [m]", "logx"),
        ("dead_time_ns", "bias_m", None, "dead time [ns]", "bias [m]", ""),
        ("p", "std_m", None, "fractal p", "precision [m]", "log"),
        ("grid_m", "std_m", None, "mesh spacing [m]", "precision [m]", "logx"),
        ("altitude_m", "float32_error_m", "max_error_m", "altitude [m]",
         "path error [m]: float32 legs (dots) vs ours (dashed)", "logx"),
        ("photons_per_launch", "paths_per_s", None, "photons per launch", "paths / s", "loglog"),
    ]
    fig, axes = plt.subplots(2, 4, figsize=(16, 7), dpi=100)
    for ax, (name, key, exp_key, xl, yl, scale) in zip(axes.ravel(), panels):
        rows = results.get(name, [])
        ok = [r for r in rows if key in r and r[key] is not None and np.isfinite(r[key])]
        ax.plot([r["value"] for r in ok], [r[key] for r in ok], "o-",
                label="float32 legs" if name == "altitude_m" else "simulated")
        if exp_key:
            ax.plot([r["value"] for r in ok], [r[exp_key] for r in ok], "k--", lw=1,
                    label="ours (float64 legs)" if name == "altitude_m" else "closed form")
        bad = [r for r in rows if not str(r.get("status", "ok")).startswith("ok")]
        for r in bad:
            ax.axvline(r["value"], color="tab:red", alpha=0.4, lw=1)
        if bad:
            ax.plot([], [], color="tab:red", alpha=0.4, label="refused / degraded")
        if scale in ("log", "loglog"):
            ax.set_yscale("log")
        if scale in ("logx", "loglog"):
            ax.set_xscale("log")
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("stability: each model swept to its breaking point "
                 "(red: refused with a clear error, or degraded as stated in bench.json)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return fig
