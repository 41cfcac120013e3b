"""lidar_mitsuba.ground.surface: every surface answers the same questions the same way."""
import math

import mitsuba as mi
import numpy as np
import pytest

from lidar_mitsuba.ground import terrain
from lidar_mitsuba.constants import ParameterError
from lidar_mitsuba.ground.surface import (HeightfieldSurface, Plane, SceneSurface, SurfaceSpec,
                                          heightfield_to_trimesh, resolve)


def test_plane_folds_a_long_track_exactly():
    """Folding into the tile and adding dz back gives the plane's own height (float64 exact
    to rounding), wherever the track goes."""
    plane = Plane(slope_deg=7.0, azimuth_deg=30.0, size_m=100.0)
    x = np.linspace(-3000.0, 5000.0, 1001)
    y = 0.3 * x + 17.0
    xl, yl, dz = plane.fold(x, y)
    assert xl.min() >= 0 and xl.max() < 100 and yl.min() >= 0 and yl.max() < 100
    np.testing.assert_allclose(plane.height_m(xl, yl) + dz, plane.height_m(x, y), atol=1e-9)
    gx, gy = plane.gradient
    assert math.hypot(gx, gy) == pytest.approx(math.tan(math.radians(7.0)))
    assert plane.exact_single_bounce and plane.config()["kind"] == "slope"


def test_periodic_heightfield_folds_and_nonperiodic_refuses_a_track_off_its_grid():
    hf = terrain.fractal(p=2.0, size_m=64.0, grid_m=1.0, relief_m=3.0, seed=4)
    periodic = HeightfieldSurface(hf)
    x = np.arange(300) * 0.7 - 40.0
    xl, yl, dz = periodic.fold(x, np.full(300, 10.0), margin_m=13.5)
    assert np.all((xl >= 0) & (xl < 64)) and not dz.any()
    np.testing.assert_allclose(periodic.height_m(xl, yl), periodic.height_m(x, 10.0))
    flat_grid = HeightfieldSurface(terrain.Heightfield(z_m=hf.z_m, grid_m=1.0, periodic=False))
    with pytest.raises(ParameterError, match=r"leaves the non-periodic heightfield .* "
                                             r"(\d+) of its 300 shots") as e:
        flat_grid.fold(x, np.full(300, 31.5), margin_m=13.5)
    assert e.value.name == "shots"
    inside = np.arange(40) * 0.7 + 14.0          # x 14 .. 41.3 m: 13.5 m clear of 0 and 63
    assert flat_grid.fold(inside, np.full(40, 31.5), margin_m=13.5)[0] is not None
    cfg = flat_grid.config()
    assert cfg["kind"] == "heightfield" and cfg["periodic"] is False and cfg["nx"] == 64


def test_heightfield_mesh_covers_the_corridor_and_repeats_the_tile():
    hf = terrain.fractal(p=1.8, size_m=32.0, grid_m=1.0, relief_m=2.0, seed=1)
    tm = heightfield_to_trimesh(hf, bounds_m=(-5.0, 40.0, 3.0, 9.0))
    assert tm.vertices[:, 0].min() == -5 and tm.vertices[:, 0].max() == 40
    v = tm.vertices
    np.testing.assert_allclose(v[:, 2], hf.height_m(v[:, 0], v[:, 1]), atol=1e-12)
    assert len(tm.faces) == 2 * 45 * 6


def test_scene_surface_heights_bounds_and_config():
    s = mi.load_string('<scene version="3.0.0"><shape type="rectangle"><transform name="to_world">'
                       '<scale x="50" y="20"/><translate x="10" z="3"/></transform></shape></scene>')
    surf = SceneSurface(s, source="test")
    assert surf.centre_xy_m() == pytest.approx((10.0, 0.0))
    assert surf.height_m(0.0, 0.0) == pytest.approx(3.0)
    assert surf.reference_elevation_m(0.0, 0.0, sigma_m=2.5) == pytest.approx(3.0)
    with pytest.raises(ParameterError, match="leaves the scene's bounding box"):
        surf.fold(np.array([0.0, 55.0]), np.zeros(2), margin_m=13.5)
    assert surf.config()["kind"] == "scene" and not surf.takes_bsdf


def test_resolve_gives_the_surface_its_bsdf_and_a_true_config():
    surf, bsdf, cfg = resolve(None)
    assert isinstance(surf, HeightfieldSurface) and bsdf["type"] == "ward" and cfg["p"] == 1.8
    hf = terrain.fractal(p=2.2, size_m=32.0, grid_m=1.0, relief_m=1.0, seed=0)
    surf, bsdf, cfg = resolve(hf)
    assert cfg["kind"] == "heightfield" and "p" not in cfg     # not the default fractal's
    assert resolve(Plane())[2]["kind"] == "flat"
    with pytest.raises(ParameterError, match="surface"):
        resolve("fractal")


@pytest.mark.parametrize("kw,name", [
    ({"kind": "hill"}, "surface"), ({"terrain_seed": -1}, "terrain_seed"),
    ({"kind": "fractal", "slope_deg": 3.0}, "slope_deg"), ({"rho_d": 0.99}, "rho_d"),
    ({"alpha": 0.0}, "alpha"), ({"grid_m": 1e-4}, "grid_m"), ({"p": 7.0}, "p"),
])
def test_surface_spec_names_the_bad_field(kw, name):
    with pytest.raises(ParameterError) as e:
        SurfaceSpec(**kw)
    assert e.value.name == name
