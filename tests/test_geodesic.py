"""Geodesics through PROJ's own routines with lines shared (lidar_mitsuba.geodesic): the same
bits as pyproj's ``Geod.fwd``, point by point, and a granule's beams placed together the same
as one at a time. Pure numpy and pyproj: no rendering."""
import numpy as np
import pytest
from pyproj import Geod, Transformer

from lidar_mitsuba import geodesic, geotrack

WGS84 = Geod(ellps="WGS84")


def _bits(a):
    return np.ascontiguousarray(a, np.float64).view(np.int64)


def _fwd(lat, lon, azi, s12):
    """The reference: one ``Geod.fwd`` call (``geod_direct`` a point), forward azimuth."""
    lon2, lat2, azi2 = WGS84.fwd(lon, lat, azi, s12, return_back_azimuth=False)
    return np.asarray(lat2), np.asarray(lon2), np.asarray(azi2)


@pytest.fixture(params=["compiled", "pyproj"])
def path(request, monkeypatch):
    """Both of :func:`geodesic.direct`'s paths: the compiled one (which must be found on
    this machine) and pyproj's, taken where PROJ's functions are not found."""
    if request.param == "compiled":
        assert geodesic._proj() is not None
    else:
        monkeypatch.setattr(geodesic, "_PROJ", [None])
    return request.param


def test_direct_is_geod_fwd_to_the_bit(path, rng):
    """Random starts over the globe (each its own line, and runs of 1-40 points sharing a
    start and azimuth, as a track's shots do), distances from 0 to 20 000 km and negative:
    every latitude, longitude and azimuth the same bits as ``Geod.fwd``'s."""
    n_runs = 3000
    run = rng.integers(1, 40, n_runs)
    lat = np.repeat(rng.uniform(-90.0, 90.0, n_runs), run)
    lon = np.repeat(rng.uniform(-540.0, 540.0, n_runs), run)
    azi = np.repeat(rng.uniform(-360.0, 360.0, n_runs), run)
    s12 = rng.uniform(-2e7, 2e7, lat.size)
    s12[::7] = 0.0
    lat[:3], azi[3:6] = (90.0, -90.0, 0.0), (0.0, 90.0, 180.0)     # poles and meridians
    got, want = geodesic.direct(lat, lon, azi, s12), _fwd(lat, lon, azi, s12)
    for g, w in zip(got, want):
        assert np.array_equal(_bits(g), _bits(w))


def test_fan_and_beams_are_one_point_at_a_time(path, rng):
    """:func:`geodesic.fan` (one line a start for several distances) and
    :func:`geotrack.beams_shots` (six beams, three a side): each beam the same bits as
    ``Geod.fwd`` of that beam alone, as :func:`geotrack.beam_shots` was computed."""
    n = 2000
    lat, lon = rng.uniform(-85, 85, n), rng.uniform(-180, 180, n)
    az = rng.uniform(0, 360, n)
    beams = geotrack.beam_layout(1)
    placed = geotrack.beams_shots(lat, lon, az, beams)
    for b, (blat, blon) in zip(beams, placed):
        side = -90.0 if b.across_m > 0 else 90.0
        wlat, wlon, _ = _fwd(lat, lon, az + side, np.full(n, abs(b.across_m)))
        assert np.array_equal(_bits(blat), _bits(wlat)) and np.array_equal(_bits(blon), _bits(wlon))
        one = geotrack.beam_shots(lat, lon, az, b)
        assert np.array_equal(_bits(one[0]), _bits(wlat))
    flat, flon = geodesic.fan(lat, lon, az, [10.0, 0.0, 5e5])
    for j, d in enumerate((10.0, 0.0, 5e5)):
        wlat, wlon, _ = _fwd(lat, lon, az, np.full(n, d))
        assert np.array_equal(_bits(flat[j]), _bits(wlat)) and np.array_equal(_bits(flon[j]),
                                                                                 _bits(wlon))


@pytest.mark.parametrize("polyline", [None, ((65.0, -45.0), (65.2, -44.7), (65.1, -44.0))])
def test_track_shots_as_geod_fwd_gave_them(polyline):
    """:meth:`GeoTrack.shots` (one line for a run of shots) against the expression it
    replaced: ``Geod.fwd`` of every shot from its line's start, the forward azimuth from
    pyproj's back azimuth."""
    track = (geotrack.GeoTrack(start_lat_deg=65.0, start_lon_deg=-45.0, azimuth_deg=12.5)
             if polyline is None else geotrack.GeoTrack(polyline=polyline))
    lat, lon, az, along = track.shots(3000, spacing_m=7.0, first=1234)
    if polyline is None:
        lat0, lon0, az0, d = (np.full(along.shape, 65.0), np.full(along.shape, -45.0),
                              np.full(along.shape, 12.5), along)
    else:
        pts = np.asarray(polyline)
        az_seg, _, seg_len = WGS84.inv(pts[:-1, 1], pts[:-1, 0], pts[1:, 1], pts[1:, 0])
        ends = np.concatenate([[0.0], np.cumsum(seg_len)])
        k = np.clip(np.searchsorted(ends, along, side="right") - 1, 0, len(seg_len) - 1)
        lat0, lon0, az0, d = pts[k, 0], pts[k, 1], np.asarray(az_seg)[k], along - ends[k]
        assert len(set(k)) == 2                       # (the shots span two segments)
    wlon, wlat, back = WGS84.fwd(lon0, lat0, az0, d)
    for g, w in ((lat, wlat), (lon, wlon), (az, np.mod(np.asarray(back) + 180.0, 360.0))):
        assert np.array_equal(_bits(g), _bits(w))


def test_section_places_together_as_one_beam_at_a_time():
    """A granule's section placed for all six beams on the first beam's call
    (:class:`geotrack.SectionPlaces`) against each beam placed and projected alone: the same
    geolocation, along-track distances and projected positions, to the bit."""
    track = geotrack.GeoTrack(start_lat_deg=70.0, start_lon_deg=-40.0, azimuth_deg=30.0)
    to_crs = Transformer.from_crs("EPSG:4326", "EPSG:3413", always_xy=True)
    beams = geotrack.beam_layout(0)
    places = geotrack.SectionPlaces(track, to_crs, beams=beams, spacing_m=0.7, prf_hz=1e4)
    for b in beams[::-1]:
        geo, along, x, y = places(b, 500, 1500)
        g1, a1 = track.beam_geolocation(b, 500, 1500, spacing_m=0.7, prf_hz=1e4)
        x1, y1 = to_crs.transform(g1.lon_deg, g1.lat_deg)
        for u, v in ((geo.lat_deg, g1.lat_deg), (geo.lon_deg, g1.lon_deg), (along, a1),
                     (geo.azimuth_deg, g1.azimuth_deg), (geo.delta_time_s, g1.delta_time_s),
                     (x, x1), (y, y1)):
            assert u.shape == (1500,) and np.array_equal(_bits(u), _bits(v))
