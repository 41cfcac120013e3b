"""Pressure-ridge sails and other topographic obstacles on sea ice: sparse, linear, positive
features that give the ice's elevations their positive skew (``SurfaceSpec(kind="sea_ice",
surface_ridges=...)``, :func:`~lidar_mitsuba.ground.sea_ice_surface.rough_sea_ice`).

Airborne laser profiles of Arctic sea ice count *obstacles*: local maxima standing more than a
cutoff ``h_c`` above the level ice (and separated by a trough, the Rayleigh criterion). Their
heights above the cutoff are negatively exponential (laser profiles of 4 365 Ross Sea ridges,
Weeks et al. 1989, JGR, authors recalled: "well described by a negative exponential
distribution"; Wadhams: so are ridge keels' drafts; Hibler et al.'s one-parameter model of
Arctic laser profiles); their spacing along a profile has a mean ``D``. A ridge sail is, across its crest, a triangle whose flanks slope
at the sail angle ``alpha`` (Timco & Burden 1997).

The model: straight segments of length ``l`` (sails), centres uniform on the periodic tile,
orientations uniform (isotropic), heights ``H = h_c + X`` with ``X`` exponential of mean
``H_bar - h_c``, each adding ``H (1 - |q| / w)_+`` (``q`` the distance across its crest,
``w = H / tan(alpha)`` its half-width) to the surface along its length. A straight profile
crosses isotropic lines of length ``L_A`` per unit area ``(2 / pi) L_A`` times per unit length
(Buffon), so the published mean spacing fixes

.. math:: L_A = \\frac{\\pi}{2 D}.

The heights are a Poisson shot-noise field (the sails add), whose cumulants are exact
(Campbell's theorem): the n-th is the line density times the n-th power of a sail's
cross-section integrated across it,

.. math:: \\kappa_n = L_A \\, \\mathrm{E}\\!\\int g^n \\, dq
          = \\frac{2 L_A}{(n + 1) \\tan\\alpha} \\, \\mathrm{E}[H^{n+1}],
   \\qquad \\mathrm{E}[H^k] = \\sum_{j=0}^{k} \\binom{k}{j} h_c^{k-j} \\, j! \\, b^j

(``b = H_bar - h_c``): the mean ``kappa_1``, variance ``kappa_2`` and third central moment
``kappa_3`` (:func:`cumulants`), independent of ``l``. The ends of a segment are cut square,
so each sail adds exactly ``l`` times its cross-section.

Sources (:data:`RIDGES`): obstacle mean height 0.45 m and mean spacing ~20 m, Castellani et
al. 2014, J. Geophys. Res. Oceans 119, doi:10.1002/2013JC009712 (airborne laser altimeter,
more than 10 000 km in different regions of the Arctic Ocean, 1995-2011, 10 km sections:
"typical values"); the 0.20 m cutoff of the same obstacle detection as applied to IceBridge
ATM data (Petty et al. 2016, The Cryosphere 10, 1161: ``min_ridge_height = 0.2`` in their
published processing code) and to ICESat-2 (Mchedlishvili et al. 2023, The Cryosphere 17,
4103: obstacles below 20 cm omitted, Rayleigh criterion): Castellani et al.'s own cutoff was
not readable here (ESTIMATE: the same 0.2 m); the sail angle 33 deg, Timco & Burden 1997,
Cold Reg. Sci. Technol. 25, 65 (average sail angle of Beaufort Sea ridges; 21 deg for
temperate ones). The segment length is an ESTIMATE (:data:`RIDGES`).

Pure numpy; no renderer import.
"""
from __future__ import annotations

import math

import numpy as np

from ..constants import ParameterError

#: Published obstacle statistics for :func:`ridge_field`, by name (``none``: no ridges).
RIDGES = {
    "arctic_obstacles": {
        "spacing_m": 20.0, "mean_height_m": 0.45, "cutoff_m": 0.20, "sail_angle_deg": 33.0,
        "length_m": 50.0,
        "source": "mean obstacle height 0.45 m and mean spacing ~20 m: Castellani et al. "
                  "2014, JGR Oceans 119, doi:10.1002/2013JC009712 (airborne laser "
                  "altimeter, >10 000 km, Arctic Ocean, 1995-2011, typical values of 10 km "
                  "sections); cutoff 0.20 m: the obstacle threshold of Petty et al. 2016 "
                  "(TC 10, 1161, their code's min_ridge_height) and Mchedlishvili et al. "
                  "2023 (TC 17, 4103), ESTIMATE for Castellani et al.'s own (not readable "
                  "here); heights above the cutoff negative exponential (Weeks et al. "
                  "1989, Ross Sea laser profiles; Wadhams; Hibler et al.); sail angle 33 "
                  "deg: Timco & Burden 1997, "
                  "CRST 25, 65 (Beaufort Sea ridges' average); length 50 m: ESTIMATE (a "
                  "sail runs continuously for tens of metres to kilometres, the profiles' "
                  "obstacles include shorter rubble; the one-point moments do not depend "
                  "on it)"},
}
NONE = "none"
"""The ``surface_ridges`` value for a surface without ridges."""


def parameters(name: str) -> dict | None:
    """The obstacle statistics called ``name`` (:data:`RIDGES`), ``None`` for ``none``;
    raises :class:`ParameterError` (``surface_ridges``) for an unknown name."""
    if name == NONE:
        return None
    if name not in RIDGES:
        raise ParameterError("surface_ridges", f"must be one of {', '.join([*RIDGES, NONE])} "
                             f"(got {name!r})")
    return RIDGES[name]


def line_density_per_m(spacing_m: float) -> float:
    """Sail length per unit area [m / m^2 = 1/m] of isotropic lines that a straight profile
    crosses once per ``spacing_m`` on average: ``pi / (2 spacing_m)`` (Buffon)."""
    return math.pi / (2.0 * float(spacing_m))


def height_moment(k: int, *, mean_height_m: float, cutoff_m: float) -> float:
    """``E[H^k]`` [m^k] of a sail height ``H = cutoff + X``, ``X`` exponential of mean
    ``mean_height_m - cutoff_m``."""
    b = float(mean_height_m) - float(cutoff_m)
    return sum(math.comb(k, j) * cutoff_m ** (k - j) * math.factorial(j) * b ** j
               for j in range(k + 1))


def cumulants(*, spacing_m: float, mean_height_m: float, cutoff_m: float,
              sail_angle_deg: float, **_) -> tuple[float, float, float]:
    """``(kappa_1 [m], kappa_2 [m^2], kappa_3 [m^3])`` of the ridge heights: mean, variance
    and third central moment (the module's closed form; extra keys, e.g. a :data:`RIDGES`
    entry's ``length_m`` and ``source``, are ignored)."""
    la = line_density_per_m(spacing_m)
    t = math.tan(math.radians(sail_angle_deg))
    return tuple(2.0 * la / ((n + 1) * t) * height_moment(n + 1, mean_height_m=mean_height_m,
                                                         cutoff_m=cutoff_m)
                 for n in (1, 2, 3))


def check(params: dict | None, *, rms_m: float, size_m: float) -> None:
    """Raise :class:`ParameterError` where ``params`` cannot stand on a tile of ``size_m``
    [m] whose total rms height is ``rms_m`` [m]: the ridges' own variance must leave room for
    the level ice's, and a sail must fit in half the periodic tile."""
    if params is None:
        return
    k2 = cumulants(**params)[1]
    if k2 >= rms_m ** 2:
        raise ParameterError("surface_ridges", f"these ridges alone have an rms height of "
                             f"{math.sqrt(k2):.3f} m, not less than surface_rms_m = {rms_m:g}:"
                             " choose surface_ridges none or a larger rms")
    if params["length_m"] > size_m / 2.0:
        raise ParameterError("size_m", f"must be at least twice the ridges' length "
                             f"({2 * params['length_m']:g} m) with surface_ridges "
                             f"(got {size_m:g})")


def ridge_field(*, n: int, grid_m: float, spacing_m: float, mean_height_m: float,
                cutoff_m: float, sail_angle_deg: float, length_m: float,
                rng: np.random.Generator, **_) -> np.ndarray:
    """Heights [m] of isotropic ridge sails on a periodic ``n`` x ``n`` grid of spacing
    ``grid_m`` [m] (the module's model; a Poisson number of sails of mean
    ``L_A A / length_m``), drawn from ``rng``. Returns an (n, n) float64 array, >= 0."""
    size = n * grid_m
    la = line_density_per_m(spacing_m)
    count = int(rng.poisson(la * size * size / length_m))
    centre = rng.uniform(0.0, size, (count, 2))
    theta = rng.uniform(0.0, math.pi, count)
    height = cutoff_m + rng.exponential(mean_height_m - cutoff_m, count)
    tan_a = math.tan(math.radians(sail_angle_deg))
    z = np.zeros((n, n))
    for (cx, cy), th, h in zip(centre, theta, height):
        _add_sail(z, grid_m=grid_m, centre_m=(cx, cy), crest=(math.cos(th), math.sin(th)),
                  height_m=h, half_width_m=h / tan_a, length_m=length_m)
    return z


def _add_sail(z: np.ndarray, *, grid_m: float, centre_m: tuple[float, float],
              crest: tuple[float, float], height_m: float, half_width_m: float,
              length_m: float) -> None:
    """Add one sail (centre ``(x, y)`` [m], unit crest direction, height [m], half-width [m]
    and length [m]) to the periodic grid ``z`` (z[iy, ix] at x = ix grid_m, y = iy grid_m)
    in place."""
    (cx, cy), (dx, dy), h, w = centre_m, crest, height_m, half_width_m
    n = z.shape[0]
    size = n * grid_m
    half_x = 0.5 * length_m * abs(dx) + w * abs(dy)      # the sail's bounding box
    half_y = 0.5 * length_m * abs(dy) + w * abs(dx)
    if max(half_x, half_y) >= size / 2.0:
        raise ParameterError("size_m", f"a sail {h:.2f} m high and {length_m:g} m long does "
                             f"not fit in half the {size:g} m tile")
    ix = np.arange(math.floor((cx - half_x) / grid_m), math.ceil((cx + half_x) / grid_m) + 1)
    iy = np.arange(math.floor((cy - half_y) / grid_m), math.ceil((cy + half_y) / grid_m) + 1)
    ex = ix * grid_m - cx
    ey = iy * grid_m - cy
    along = ex[None, :] * dx + ey[:, None] * dy
    across = np.abs(ey[:, None] * dx - ex[None, :] * dy)
    g = h * np.clip(1.0 - across / w, 0.0, None) * (np.abs(along) <= 0.5 * length_m)
    z[np.ix_(np.mod(iy, n), np.mod(ix, n))] += g      # unique: the box is < the tile
