"""Points along geodesics on the WGS84 ellipsoid: the direct geodesic problem (Karney 2013,
"Algorithms for geodesics", J. Geodesy 87, 43-55), solved by PROJ's own GeographicLib routines,
the very functions pyproj's ``Geod.fwd`` runs, so every result is the same to the bit.

``Geod.fwd`` solves each point with ``geod_direct``, which is ``geod_lineinit`` (the geodesic
through the start point at its azimuth: its series coefficients, half the cost) followed by
``geod_position`` on that line. A granule asks for many points on few lines: the reference
track's shots all lie on one geodesic from its start (a polyline's, on one per vertex), and
its six beams are the reference shots moved 45, 3255 and 3345 m left and right across track,
three beams on each of two lines per shot. :func:`direct` sets a line up once for consecutive
points that share their start and azimuth (bit for bit) and calls ``geod_position`` for each,
in a compiled loop (numba) calling the two C functions of the PROJ library pyproj itself loaded,
with the flags ``geod_direct`` gives them. Where that library cannot be reached (not a Linux
wheel or a different layout), or a check on first use finds a result that differs from
``Geod.fwd``'s, :func:`direct` is ``Geod.fwd`` itself.
"""
from __future__ import annotations

import ctypes
import threading

import numba
import numpy as np

#: GeographicLib's ``geod_mask`` bits (PROJ's ``geodesic.h``): ``geod_direct`` asks
#: ``geod_lineinit`` for latitude, longitude and azimuth, with distance as input
GEOD_LATITUDE = 1 << 7
GEOD_LONGITUDE = 1 << 8 | 1 << 3
GEOD_AZIMUTH = 1 << 9
GEOD_DISTANCE_IN = 1 << 11 | 1 << 0 | 1 << 1
DIRECT_CAPS = GEOD_LATITUDE | GEOD_LONGITUDE | GEOD_AZIMUTH | GEOD_DISTANCE_IN
#: room for ``struct geod_geodesic`` (51 doubles) and ``struct geod_geodesicline`` (63 doubles
#: and an unsigned) in GeographicLib 1.x-2.x, with twice the room to spare [doubles]
STRUCT_DOUBLES = 128


@numba.njit(cache=True, nogil=True)
def direct_lines(lineinit, position, geodesic, lat_deg, lon_deg, azi_deg, s12_m, lat2_deg,
                 lon2_deg, azi2_deg):
    """GeographicLib's direct problem for each of the (n,) start points ``lat_deg``,
    ``lon_deg`` [deg], azimuths ``azi_deg`` [deg clockwise from north] and distances ``s12_m``
    [m], into the (n,) ``lat2_deg``, ``lon2_deg`` and ``azi2_deg`` (the forward azimuth at the
    end point; an empty ``azi2_deg``: not asked for, and ``geod_position`` given a null
    pointer for it, so it skips the azimuth's ``atan2``, ~10 % of a point: the latitude and
    longitude are computed apart from it, the same bits): ``lineinit`` (PROJ's
    ``geod_lineinit``) once for each run of consecutive points whose start and azimuth are
    the same bits, ``position`` (``geod_position``) for each point; ``geodesic``: the address
    of an initialised ``struct geod_geodesic``."""
    line = np.empty(STRUCT_DOUBLES, np.float64)
    lp = line.ctypes.data
    bits_lat, bits_lon, bits_azi = lat_deg.view(np.int64), lon_deg.view(np.int64), \
        azi_deg.view(np.int64)
    p_lat, p_lon, p_azi = lat2_deg.ctypes.data, lon2_deg.ctypes.data, azi2_deg.ctypes.data
    step_azi = 8
    if azi2_deg.size == 0:                # NULL: no azimuth
        p_azi, step_azi = p_azi ^ p_azi, 0
    for i in range(lat_deg.size):
        if (i == 0 or bits_lat[i] != bits_lat[i - 1] or bits_lon[i] != bits_lon[i - 1]
                or bits_azi[i] != bits_azi[i - 1]):
            lineinit(lp, geodesic, lat_deg[i], lon_deg[i], azi_deg[i], DIRECT_CAPS)
        position(lp, s12_m[i], p_lat + 8 * i, p_lon + 8 * i, p_azi + step_azi * i)


class _Proj:
    """PROJ's ``geod_lineinit`` and ``geod_position`` as pyproj's own extension links them,
    and a WGS84 ``struct geod_geodesic`` made by its ``geod_init`` with ``Geod``'s a and f."""

    def __init__(self):
        from pyproj import Geod, _geod
        lib = ctypes.CDLL(_geod.__file__)      # dlsym searches its dependencies: its libproj
        vp, d = ctypes.c_void_p, ctypes.c_double
        init = lib.geod_init
        init.argtypes, init.restype = [vp, d, d], None
        self.lineinit = ctypes.CFUNCTYPE(None, vp, vp, d, d, d, ctypes.c_uint)(
            ("geod_lineinit", lib))
        self.position = ctypes.CFUNCTYPE(d, vp, d, vp, vp, vp)(("geod_position", lib))
        self.geod = Geod(ellps="WGS84")
        self.struct = np.zeros(STRUCT_DOUBLES, np.float64)
        init(self.struct.ctypes.data, self.geod.a, self.geod.f)

    def direct(self, lat, lon, azi, s12, azimuth: bool = True):
        out = (np.empty(lat.shape), np.empty(lat.shape), np.empty(lat.shape if azimuth else 0))
        direct_lines(self.lineinit, self.position, self.struct.ctypes.data, lat, lon, azi,
                     s12, *out)
        return out if azimuth else out[:2] + (None,)


_PROJ: list = []
_LOCK = threading.Lock()


def _proj() -> _Proj | None:
    """The compiled path, once a process, or ``None`` where PROJ's functions are not found
    or a check against ``Geod.fwd`` (points from pole to pole, lines shared and not, zero and
    long distances) finds a bit that differs."""
    with _LOCK:
        if not _PROJ:
            try:
                p = _Proj()
                lat = np.repeat(np.linspace(-89.5, 89.5, 24), 2)
                lon = np.repeat(np.linspace(-180.0, 179.0, 24), 2)
                azi = np.repeat(np.linspace(-270.0, 359.0, 24), 2)
                s12 = np.tile([0.0, 45.0, 3345.0, 1.0e7], 12)
                mine = p.direct(lat, lon, azi, s12)
                lon2, lat2, azi2 = p.geod.fwd(lon, lat, azi, s12, return_back_azimuth=False)
                same = all(np.array_equal(a.view(np.int64), np.asarray(b).view(np.int64))
                           for a, b in zip(mine + p.direct(lat, lon, azi, s12, False)[:2],
                                           (lat2, lon2, azi2, lat2, lon2)))
                _PROJ.append(p if same else None)
            except (OSError, AttributeError, ImportError, numba.core.errors.NumbaError):
                _PROJ.append(None)
        return _PROJ[0]


def direct(lat_deg, lon_deg, azimuth_deg, distance_m, *, azimuth: bool = True
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``(lat2_deg, lon2_deg, azi2_deg)`` (n,) float64 each: the points ``distance_m`` [m]
    along the geodesics from ``lat_deg``, ``lon_deg`` [deg] at ``azimuth_deg`` [deg clockwise
    from north], and the forward azimuth there [deg] (``azimuth=False``: ``None``, not
    computed); arguments (n,) or scalars, broadcast.
    The same bits as ``Geod(ellps="WGS84").fwd(lon, lat, az, s, return_back_azimuth=False)``;
    consecutive points with the same start and azimuth share one line (see the module
    docstring), so order points along their lines."""
    args = np.broadcast_arrays(*(np.asarray(a, np.float64)
                                 for a in (lat_deg, lon_deg, azimuth_deg, distance_m)))
    lat, lon, azi, s12 = (np.ascontiguousarray(a).ravel() for a in args)
    p = _proj()
    if p is not None:
        return p.direct(lat, lon, azi, s12, azimuth)
    from pyproj import Geod
    lon2, lat2, azi2 = Geod(ellps="WGS84").fwd(lon, lat, azi, s12, return_back_azimuth=False)
    return np.asarray(lat2), np.asarray(lon2), np.asarray(azi2) if azimuth else None


def fan(lat_deg, lon_deg, azimuth_deg, distances_m) -> tuple[np.ndarray, np.ndarray]:
    """``(lat2_deg, lon2_deg)``, (m, n) float64 each: row ``j`` the points ``distances_m[j]``
    [m] along the geodesics from each of the (n,) start points ``lat_deg``, ``lon_deg`` [deg]
    at ``azimuth_deg`` [deg]: one line a start point for the m distances (the same bits as m
    calls of ``Geod.fwd``)."""
    lat, lon, azi = (np.asarray(a, np.float64).ravel() for a in (lat_deg, lon_deg, azimuth_deg))
    dist = np.asarray(distances_m, np.float64).ravel()
    m = dist.size
    lat2, lon2, _ = direct(np.repeat(lat, m), np.repeat(lon, m), np.repeat(azi, m),
                           np.tile(dist, lat.size), azimuth=False)
    return (np.ascontiguousarray(lat2.reshape(lat.size, m).T),
            np.ascontiguousarray(lon2.reshape(lat.size, m).T))
