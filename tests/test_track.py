"""The ground track (lidar_mitsuba.track): footprint positions and parameter checks.
Pure numpy; positions are compared to float64 rounding (1e-9 m on km-scale coordinates)."""
import math

import numpy as np
import pytest

from lidar_mitsuba.constants import ParameterError
from lidar_mitsuba.track import Track

ATOL = 1e-9


def test_default_track_runs_along_x_centred_on_the_surface():
    along, x, y = Track().positions(5, spacing_m=0.7, centre_xy_m=(100.0, 50.0))
    for a in (along, x, y):
        assert a.shape == (5,) and a.dtype == np.float64
    np.testing.assert_allclose(along, 0.7 * np.arange(5), rtol=0, atol=ATOL)
    np.testing.assert_allclose(np.diff(x), 0.7, rtol=0, atol=ATOL)       # shot spacing
    np.testing.assert_array_equal(y, 50.0)
    assert x.mean() == pytest.approx(100.0, abs=ATOL)                     # centred
    assert x[2] == pytest.approx(100.0, abs=ATOL)                         # odd count: middle shot
    _, x4, _ = Track().positions(4, spacing_m=2.0, centre_xy_m=(0.0, 0.0))
    np.testing.assert_allclose(x4, [-3.0, -1.0, 1.0, 3.0], rtol=0, atol=ATOL)


def test_single_shot_sits_on_the_centre_and_no_shot_is_empty():
    along, x, y = Track(heading_deg=33.0).positions(1, spacing_m=0.7, centre_xy_m=(7.0, -3.0))
    assert (along[0], x[0], y[0]) == (0.0, 7.0, -3.0)
    along, x, y = Track().positions(0, spacing_m=0.7, centre_xy_m=(0.0, 0.0))
    assert along.size == x.size == y.size == 0


def test_heading_90_runs_along_plus_y():
    along, x, y = Track(heading_deg=90.0).positions(11, spacing_m=0.7, centre_xy_m=(10.0, 20.0))
    np.testing.assert_allclose(x, 10.0, rtol=0, atol=ATOL)
    np.testing.assert_allclose(np.diff(y), 0.7, rtol=0, atol=ATOL)        # increasing y
    assert y[5] == pytest.approx(20.0, abs=ATOL)
    # any heading: consecutive footprints are spacing_m apart along (cos h, sin h)
    h = 123.0
    _, x, y = Track(heading_deg=h).positions(6, spacing_m=1.5, centre_xy_m=(0.0, 0.0))
    u = np.array([math.cos(math.radians(h)), math.sin(math.radians(h))])
    steps = np.stack([np.diff(x), np.diff(y)], axis=1)
    np.testing.assert_allclose(steps, np.tile(1.5 * u, (5, 1)), rtol=0, atol=ATOL)
    assert Track(heading_deg=h).direction == pytest.approx(tuple(u))


@pytest.mark.parametrize("heading", [0.0, 90.0, 200.0])
def test_offset_shifts_to_the_left_of_travel(heading):
    """Left of travel: the direction turned by +90 degrees (counter-clockwise); heading 0
    (along +x) moves the track to +y, heading 90 (along +y) to -x."""
    base = Track(heading_deg=heading).positions(7, spacing_m=0.7, centre_xy_m=(5.0, 5.0))
    off = Track(heading_deg=heading, offset_m=3.0).positions(7, spacing_m=0.7,
                                                             centre_xy_m=(5.0, 5.0))
    h = math.radians(heading)
    left = np.array([-math.sin(h), math.cos(h)])
    np.testing.assert_array_equal(off[0], base[0])          # along-track distances unchanged
    np.testing.assert_allclose(off[1] - base[1], 3.0 * left[0], rtol=0, atol=ATOL)
    np.testing.assert_allclose(off[2] - base[2], 3.0 * left[1], rtol=0, atol=ATOL)
    if heading == 0.0:
        assert np.all(off[2] == base[2] + 3.0)
    if heading == 90.0:
        np.testing.assert_allclose(off[1], base[1] - 3.0, rtol=0, atol=ATOL)


def test_start_xy_puts_the_first_footprint_there():
    t = Track(start_xy_m=(1000.0, -250.0), heading_deg=90.0)
    along, x, y = t.positions(4, spacing_m=0.7, centre_xy_m=(0.0, 0.0))   # centre ignored
    assert (x[0], y[0]) == (1000.0, -250.0)
    np.testing.assert_allclose(y, -250.0 + along, rtol=0, atol=ATOL)
    np.testing.assert_allclose(x, 1000.0, rtol=0, atol=ATOL)
    # with an offset the first footprint moves left of travel (heading 90: toward -x)
    _, x, y = Track(start_xy_m=(1000.0, -250.0), heading_deg=90.0, offset_m=2.0).positions(
        4, spacing_m=0.7, centre_xy_m=(0.0, 0.0))
    assert x[0] == pytest.approx(998.0, abs=ATOL) and y[0] == pytest.approx(-250.0, abs=ATOL)
    assert t.start_xy_m == (1000.0, -250.0) and isinstance(t.start_xy_m, tuple)
    # a list is accepted and stored as a tuple of floats (the dataclass stays hashable)
    assert Track(start_xy_m=[1, 2]).start_xy_m == (1.0, 2.0)
    hash(Track(start_xy_m=[1, 2]))


def test_to_dict():
    assert Track().to_dict() == {"start_xy_m": None, "heading_deg": 0.0, "offset_m": 0.0}
    assert Track(start_xy_m=(1, 2), heading_deg=45, offset_m=-1).to_dict() == {
        "start_xy_m": [1.0, 2.0], "heading_deg": 45.0, "offset_m": -1.0}


@pytest.mark.parametrize("field,kwargs", [
    ("start_xy_m", {"start_xy_m": (1.0,)}),
    ("start_xy_m", {"start_xy_m": (1.0, 2.0, 3.0)}),
    ("start_xy_m", {"start_xy_m": (math.nan, 0.0)}),
    ("start_xy_m", {"start_xy_m": (0.0, math.inf)}),
    ("heading_deg", {"heading_deg": math.nan}),
    ("heading_deg", {"heading_deg": -math.inf}),
    ("offset_m", {"offset_m": math.inf}),
    ("offset_m", {"offset_m": 2e7}),
    ("start_xy_m", {"start_xy_m": 5}),
    ("start_xy_m", {"start_xy_m": ("a", "b")}),
    ("heading_deg", {"heading_deg": "x"}),
    ("offset_m", {"offset_m": None}),
])
def test_bad_values_raise_naming_the_field(field, kwargs):
    with pytest.raises(ParameterError) as e:
        Track(**kwargs)
    assert e.value.name == field and str(e.value).startswith(f"{field}: ")
