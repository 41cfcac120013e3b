"""Longitude and latitude to a polar stereographic grid (the ice sheets' CRSs: EPSG:3413,
EPSG:3031), compiled, with the bits of PROJ's own forward projection.

A granule projects every beam's shots from EPSG:4326 to the DEM's CRS (~0.86 M points a
six-beam 100 km granule); pyproj's ``Transformer.transform`` runs PROJ's pipeline point by
point, ~115 ns each, most of it the pipeline's steps around a few lines of arithmetic. For a
pipeline that PROJ spells ``+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad
+step +proj=stere +lat_0=+-90 +lat_ts=.. +lon_0=.. +x_0=.. +y_0=.. +ellps=WGS84``
(``Transformer.definition``), :class:`Projector` evaluates the same operations in one compiled
loop (:func:`_stere_north_south`), in PROJ 9's order (``src/conversions/unitconvert.cpp``,
``src/fwd.cpp``'s ``fwd_prepare`` and ``fwd_finalize``, ``src/projections/stere.cpp``'s
ellipsoidal forward and set-up, ``src/tsfn.cpp``, ``src/adjlon.cpp``, ``src/dmstor.cpp`` for
the parameters' radians, ``src/ell_set.cpp`` for the WGS84 eccentricity), calling the same C
library's ``sin``, ``cos``, ``exp``, ``atanh`` and ``sqrt``. PROJ's formulas have changed
between versions (``pj_tsfn`` in PROJ 6 was a tangent and a power), so the compiled path is
taken only after a check on first use against the transformer itself (points over the whole
hemisphere, near the pole and the antimeridian, the same bits), and every call checks every
64th point too; anything else (another CRS, another PROJ, input PROJ refuses) is
``to_crs.transform`` itself.
"""
from __future__ import annotations

import math
import re
import threading

import numba
import numpy as np

#: PROJ's constants (``proj_internal.h``, ``units.cpp``: the degree's factor)
DEG_TO_RAD = .017453292519943296
M_HALFPI = 1.5707963267948966
M_PI = 3.14159265358979323846
M_TWOPI = 6.2831853071795864769
#: ``fwd_prepare``'s latitude tolerance (``PJ_EPS_LAT``, ``proj_internal.h``)
PJ_EPS_LAT = 1e-12
#: WGS84 (PROJ's ``ellps`` table: ``a=6378137.0``, ``rf=298.257223563``)
WGS84_A_M = 6378137.0
WGS84_RF = 298.257223563
#: every how many points a call's own check compares with PROJ
CHECK_EVERY = 64

_DEFINITION = re.compile(
    r"^proj=pipeline step proj=unitconvert xy_in=deg xy_out=rad step proj=stere "
    r"lat_0=(?P<lat_0>-?90) lat_ts=(?P<lat_ts>-?[0-9.]+) lon_0=(?P<lon_0>-?[0-9.]+) "
    r"x_0=(?P<x_0>-?[0-9.]+) y_0=(?P<y_0>-?[0-9.]+) ellps=WGS84$")


@numba.njit(cache=True, nogil=True, inline="always")
def _tsfn(phi, sinphi, e):
    """PROJ 9's ``pj_tsfn`` (``src/tsfn.cpp``)."""
    cosphi = math.cos(phi)
    return math.exp(e * math.atanh(e * sinphi)) * (
        cosphi / (1 + sinphi) if sinphi > 0 else (1 - sinphi) / cosphi)


@numba.njit(cache=True, nogil=True, inline="always")
def _adjlon(lam):
    """PROJ's ``adjlon`` (``src/adjlon.cpp``)."""
    if abs(lam) < M_PI + 1e-12:
        return lam
    lam += M_PI
    lam -= M_TWOPI * math.floor(lam / M_TWOPI)
    return lam - M_PI


@numba.njit(cache=True, nogil=True)
def _stere_north_south(lon_deg, lat_deg, south, lam0, akm1, e, a, x0, y0, x, y):
    """The (n,) points' polar stereographic ``x``, ``y`` [m] (written in place), as PROJ's
    pipeline computes them; returns False (the outputs unfinished) at the first point PROJ
    would refuse or flag (not finite, latitude past a pole, longitude past 10 rad)."""
    for i in range(lon_deg.size):
        lam = lon_deg[i] * DEG_TO_RAD                  # unitconvert: xy *= xy_factor
        phi = lat_deg[i] * DEG_TO_RAD
        if not (math.isfinite(lam) and math.isfinite(phi)):
            return False
        if (-phi if phi < 0 else phi) - M_HALFPI > PJ_EPS_LAT or lam > 10 or lam < -10:
            return False
        if phi > M_HALFPI:                             # fwd_prepare
            phi = M_HALFPI
        if phi < -M_HALFPI:
            phi = -M_HALFPI
        lam = _adjlon(lam)
        lam = _adjlon((lam - 0.0) - lam0)
        coslam = math.cos(lam)                         # stere_e_forward
        sinlam = math.sin(lam)
        sinphi = math.sin(phi)
        if south:
            phi = -phi
            coslam = -coslam
            sinphi = -sinphi
        if abs(phi - M_HALFPI) < 1e-15:
            xx = 0.0
        else:
            xx = akm1 * _tsfn(phi, sinphi, e)
        yy = -xx * coslam
        xx = xx * sinlam
        xx *= a                                        # fwd_finalize (classic units)
        yy *= a
        x[i] = 1.0 * (xx + x0)
        y[i] = 1.0 * (yy + y0)
    return True


def _dms_radians(text: str) -> float:
    """A plain decimal degree parameter in radians as PROJ's ``dmstor`` makes it."""
    v = 0.0 + float(text.lstrip("+-")) * DEG_TO_RAD
    return -v if text.startswith("-") else v


class Projector:
    """A pyproj transformer's projection, compiled where PROJ's bits allow.

    ``project(lon_deg, lat_deg) -> (x_m, y_m)`` is ``to_crs.transform`` (a pyproj
    Transformer from EPSG:4326, longitude first), compiled where its pipeline is a WGS84
    polar stereographic one and a check finds PROJ's bits (see the module docstring)."""

    def __init__(self, to_crs):
        self.to_crs = to_crs
        self.params = None
        self._lock = threading.Lock()
        self._checked = False
        m = _DEFINITION.match(getattr(to_crs, "definition", "") or "")
        if m is None:
            return
        f = 1 / WGS84_RF                               # ell_set.cpp
        es = 2 * f - f * f
        e = math.sqrt(es)
        phits = abs(_dms_radians(m["lat_ts"]))         # stere.cpp's set-up (lat_ts != 90)
        if abs(phits - M_HALFPI) < 1e-10:
            return
        t = math.sin(phits)
        akm1 = math.cos(phits) / _tsfn.py_func(phits, t, e)
        t *= e
        akm1 /= math.sqrt(1. - t * t)
        self.params = (_dms_radians(m["lat_0"]) < 0, _dms_radians(m["lon_0"]), akm1, e,
                       WGS84_A_M, float(m["x_0"]), float(m["y_0"]))

    def _compiled(self, lon, lat):
        x, y = np.empty(lon.shape), np.empty(lon.shape)
        ok = _stere_north_south(lon, lat, *self.params, x, y)
        return (x, y) if ok else None

    def _same(self, lon, lat, got) -> bool:
        want = self.to_crs.transform(lon, lat)
        return all(np.array_equal(np.asarray(w, np.float64).view(np.int64), g.view(np.int64))
                   for w, g in zip(want, got))

    def _first_check(self) -> None:
        """Points over the hemisphere of the projection's pole, the pole itself, the
        antimeridian and the central meridian, against PROJ (once a projector)."""
        with self._lock:
            if self._checked or self.params is None:
                return
            rng = np.random.default_rng(0)
            sign = -1.0 if self.params[0] else 1.0
            lat = sign * np.concatenate([rng.uniform(0.0, 90.0, 4000), [90.0, 89.999999999,
                                                                        45.0, 0.0, 60.0]])
            lon = np.concatenate([rng.uniform(-540.0, 540.0, 4000),
                                  [0.0, 180.0, -180.0, math.degrees(self.params[1]), 179.999]])
            got = self._compiled(lon, lat)
            if got is None or not self._same(lon, lat, got):
                self.params = None
            self._checked = True

    def __call__(self, lon_deg, lat_deg) -> tuple[np.ndarray, np.ndarray]:
        lon = np.ascontiguousarray(lon_deg, np.float64).ravel()
        lat = np.ascontiguousarray(lat_deg, np.float64).ravel()
        self._first_check()
        got = None
        if self.params is not None and lon.shape == lat.shape:
            got = self._compiled(lon, lat)         # (None: input PROJ refuses, its own)
        if got is not None:
            if self._same(lon[::CHECK_EVERY], lat[::CHECK_EVERY],
                          (got[0][::CHECK_EVERY], got[1][::CHECK_EVERY])):
                return got
            self.params = None                     # (PROJ differs: its own from now on)
        x, y = self.to_crs.transform(lon, lat)
        return np.asarray(x, np.float64), np.asarray(y, np.float64)
