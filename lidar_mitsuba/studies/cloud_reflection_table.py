"""Makes the cloud's nadir reflectance table
(:mod:`lidar_mitsuba.atmosphere.cloud_reflection_table`) and measures how well it stands for
the Monte Carlo.

``python -m lidar_mitsuba.studies.cloud_reflection_table build`` walks, for each ``g`` (ice
0.75, water 0.85) and optical depth ``tau`` (0.01-20, a factor sqrt(2) apart), one collimated
beam per ``mu0`` (0.02-1, 0.02 apart) through the layer over nothing, scored twice in the
same walk (:func:`~lidar_mitsuba.atmosphere.hg_walk.walk`): the local estimate of ``rho_0``
and the escapes' count of ``t(mu0)``; and one Lambertian beam for the spherical albedo ``s``.
2^15 photons each (as the run-time Monte Carlo), each node its own seed (the nodes' errors
independent). 8 min on two shared cores; writes ``data/cloud_reflection_table.json``.

``... check`` compares the table against fresh Monte Carlo
(:func:`~lidar_mitsuba.atmosphere.cloud_reflection.nadir_reflectance_factor`, 2^17 photons)
between the nodes (mid-way in ``ln tau`` and in ``mu0``) and on them, over sea ice (0.83)
and snow (0.96): the difference and its ratio to the two standard errors combined. Measured
(96 cases, g 0.75 and 0.85, tau 0.028-17, mu0 0.07-0.91): the differences' rms 0.0046
between the nodes and 0.0051 on them, largest 0.014; in units of the combined standard error
rms 0.87 between and 1.09 on the nodes, none beyond 2.1: the interpolation's own error is
below the table's sampling error (0.003-0.01 a node) and not resolved by this check.
"""
from __future__ import annotations

import json
import math
import sys
import time

import numpy as np

from ..atmosphere import cloud_reflection as cr
from ..atmosphere import cloud_reflection_table as table
from ..atmosphere.cloud_layer import ICE_G, WATER_G
from ..atmosphere.hg_walk import Escape, LocalEstimate, collimated, diffuse, walk

GS = (ICE_G, WATER_G)
OPTICAL_DEPTHS = tuple(round(0.01 * 2.0 ** (k / 2.0), 6) for k in range(22)) + (20.0,)
MU0S = tuple(round(0.02 * k, 2) for k in range(1, 51))
PHOTONS = cr.PHOTONS


def node(*, optical_depth: float, g: float, mu0: float, seed: int,
         photons: int = PHOTONS) -> tuple[float, float, float]:
    """``(rho_0, its standard error, t)`` of one node: one walk over nothing, scored two
    ways."""
    local = LocalEstimate(photons, optical_depth=optical_depth, g=g, surface_albedo=0.0,
                          single_scattering_albedo=1.0)
    escape = Escape()
    walk(optical_depth=optical_depth, g=g, d=collimated(photons, mu0),
         rng=np.random.default_rng(seed), scorings=(local, escape), max_events=cr.MAX_EVENTS)
    s = local.score
    return float(s.mean()), float(s.std(ddof=1) / math.sqrt(photons)), escape.bottom / photons


def spherical_albedo(*, optical_depth: float, g: float, seed: int,
                     photons: int = PHOTONS) -> float:
    """The layer's spherical albedo: the share of a Lambertian beam it sends back [1]."""
    rng = np.random.default_rng(seed)
    escape = Escape()
    walk(optical_depth=optical_depth, g=g, d=diffuse(photons, rng), rng=rng,
         scorings=(escape,), max_events=cr.MAX_EVENTS)
    return escape.top / photons


def build(path=table.TABLE) -> dict:
    """Every node (module docstring), written to ``path``."""
    t0 = time.perf_counter()
    shape = (len(GS), len(OPTICAL_DEPTHS), len(MU0S))
    rho0, se, trans = np.zeros(shape), np.zeros(shape), np.zeros(shape)
    sph = np.zeros(shape[:2])
    for a, g in enumerate(GS):
        for b, tau in enumerate(OPTICAL_DEPTHS):
            base = 1_000_000 * (a + 1) + 1000 * b          # a seed of its own per node
            for c, mu0 in enumerate(MU0S):
                rho0[a, b, c], se[a, b, c], trans[a, b, c] = node(
                    optical_depth=tau, g=g, mu0=mu0, seed=base + c + 1)
            sph[a, b] = spherical_albedo(optical_depth=tau, g=g, seed=base + 999)
            print(f"g {g} tau {tau}: rho_0(0.2) {rho0[a, b, 9]:.4f} t(1) {trans[a, b, -1]:.4f}"
                  f" s {sph[a, b]:.4f} ({time.perf_counter() - t0:.0f} s)", flush=True)
    doc = {"about": "The nadir reflectance factor of a plane-parallel Henyey-Greenstein layer "
                    "over nothing (rho_black), its standard error, the layer's total "
                    "transmittance of a collimated beam and its spherical albedo; see "
                    "lidar_mitsuba/atmosphere/cloud_reflection_table.py and "
                    "lidar_mitsuba/studies/cloud_reflection_table.py.",
           "photons": PHOTONS, "max_events": cr.MAX_EVENTS, "single_scattering_albedo": 1.0,
           "seconds": round(time.perf_counter() - t0, 1), "gs": list(GS),
           "optical_depths": list(OPTICAL_DEPTHS), "mu0s": list(MU0S),
           "rho_black": np.round(rho0, 6).tolist(), "rho_black_se": np.round(se, 6).tolist(),
           "transmittance": np.round(trans, 6).tolist(),
           "spherical_albedo": np.round(sph, 6).tolist()}
    with open(path, "w") as f:
        json.dump(doc, f, separators=(",", ":"))
        f.write("\n")
    table.load.cache_clear()
    return doc


def check(*, photons: int = 1 << 17, albedos=(0.83, 0.96)) -> list[dict]:
    """The table against fresh Monte Carlo between and on its nodes (module docstring)."""
    taus = OPTICAL_DEPTHS
    cases = []
    for b in (3, 8, 11, 14, 18, 21):                     # tau 0.028 .. 14.5, mid-way in ln
        mid = math.sqrt(taus[b] * taus[b + 1])
        cases += [(mid, 0.07), (mid, 0.31), (taus[b], 0.2), (mid, 0.91)]
    rows = []
    for g in GS:
        for tau, mu0 in cases:
            for a in albedos:
                mc, mc_se = cr.nadir_reflectance_factor(
                    optical_depth=round(tau, 4), g=g, mu0=mu0, surface_albedo=a,
                    photons=photons, seed=7)
                tb, tb_se = table.rho(optical_depth=round(tau, 4), g=g, mu0=mu0,
                                      surface_albedo=a)
                diff = float(tb) - mc
                rows.append(dict(g=g, tau=round(tau, 4), mu0=mu0, albedo=a, mc=mc,
                                 table=float(tb), diff=diff,
                                 sigmas=diff / math.hypot(mc_se, float(tb_se))))
                print(f"g {g} tau {tau:7.4f} mu0 {mu0:4.2f} A {a}: MC {mc:.4f} table "
                      f"{float(tb):.4f} diff {diff:+.4f} ({rows[-1]['sigmas']:+.1f} sigma)",
                      flush=True)
    d = np.array([r["diff"] for r in rows])
    print(f"max |diff| {np.abs(d).max():.4f}, rms {np.sqrt(np.mean(d * d)):.4f}")
    return rows


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "build"
    build() if what == "build" else check()
