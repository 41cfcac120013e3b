"""The compiled polar stereographic projection (lidar_mitsuba.polar_stereo): PROJ's bits for
the ice sheets' CRSs, and pyproj itself for any other CRS or when a check finds a bit that
differs. Pure numpy and pyproj: no rendering."""
import numpy as np
import pytest
from pyproj import Transformer

from lidar_mitsuba import polar_stereo


def _bits(a):
    return np.ascontiguousarray(a, np.float64).view(np.int64)


@pytest.mark.parametrize("crs, sign", [("EPSG:3413", 1.0), ("EPSG:3031", -1.0)])
def test_projection_is_projs_to_the_bit(crs, sign):
    """Greenland's and Antarctica's grids: random points over the pole's hemisphere (and
    longitudes past +-180), a granule-like run along a meridian, the pole itself: every x and
    y the same bits as ``Transformer.transform``; the compiled path was taken."""
    to_crs = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    project = polar_stereo.Projector(to_crs)
    rng = np.random.default_rng(1)
    lat = sign * np.concatenate([rng.uniform(0.0, 90.0, 20_000), 65.0 + np.arange(5000) * 6e-6,
                                 [90.0]])
    lon = np.concatenate([rng.uniform(-200.0, 200.0, 20_000), np.full(5000, -45.0), [10.0]])
    got = project(lon, lat)
    want = to_crs.transform(lon, lat)
    assert project.params is not None
    for g, w in zip(got, want):
        assert np.array_equal(_bits(g), _bits(w))


def test_other_crs_and_differing_bits_are_pyprojs(monkeypatch):
    """A UTM grid is not compiled (pyproj's transform); a polar grid whose compiled bits
    differ (a set-up constant off by an ulp) is found out by the first check and left to
    pyproj, as is input PROJ would refuse (a latitude past the pole)."""
    utm = Transformer.from_crs("EPSG:4326", "EPSG:32624", always_xy=True)
    p = polar_stereo.Projector(utm)
    assert p.params is None
    lon, lat = np.array([-39.0, -38.5]), np.array([65.0, 66.0])
    assert np.array_equal(_bits(p(lon, lat)[0]), _bits(utm.transform(lon, lat)[0]))
    to_crs = Transformer.from_crs("EPSG:4326", "EPSG:3413", always_xy=True)
    off = polar_stereo.Projector(to_crs)
    south, lam0, akm1, *rest = off.params
    off.params = (south, lam0, np.nextafter(akm1, 2.0), *rest)
    got = off(lon, lat)
    assert off.params is None
    for g, w in zip(got, to_crs.transform(lon, lat)):
        assert np.array_equal(_bits(g), _bits(w))
    good = polar_stereo.Projector(to_crs)
    x, _ = good(np.array([0.0, 1.0]), np.array([91.0, 60.0]))
    assert np.isinf(x[0]) and good.params is not None
