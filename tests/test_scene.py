"""lidar_mitsuba.trace.scene: bounds taken from the geometry, one-line XML errors, vertical ray casts."""
import math

import mitsuba as mi
import numpy as np
import pytest

from lidar_mitsuba.trace import scene as scn

SNOW = '<bsdf type="ward" id="snow"/>'


def xml(body: str, head: str = '<scene version="3.0.0">') -> str:
    return f"{head}{body}</scene>"


def write(tmp_path, text: str, name="s.xml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_bounds_of_merged_shapes_cover_every_shape():
    """Shapes sharing a BSDF are merged by Mitsuba into one mesh whose bbox() is the first
    shape's; the bounds must come from the vertices (the roof at 60 m was invisible before)."""
    s = mi.load_string(xml(SNOW + """
        <shape type="cube"><transform name="to_world"><scale x="500" y="500" z="0.1"/>
        </transform><ref id="snow"/></shape>
        <shape type="rectangle"><transform name="to_world"><scale x="20" y="20"/>
        <translate z="60"/></transform><ref id="snow"/></shape>"""))
    assert len(s.shapes()) == 1 and s.shapes()[0].bbox().max.z < 1     # Mitsuba merged them
    lo, hi = scn.scene_bounds(s)
    np.testing.assert_allclose(lo, [-500, -500, -0.1], rtol=1e-6)
    np.testing.assert_allclose(hi, [500, 500, 60], rtol=1e-6)
    z, nz = scn.cast_down(s, [0.0, 100.0], [0.0, 0.0])
    np.testing.assert_allclose(z, [60.0, 0.1], rtol=1e-6)
    np.testing.assert_allclose(nz, [1.0, 1.0])


def test_bounds_refuse_empty_and_non_finite_scenes():
    with pytest.raises(ValueError, match="no shapes"):
        scn.scene_bounds(mi.load_dict({"type": "scene"}))
    nan = mi.load_string(xml('<shape type="rectangle"><transform name="to_world">'
                             '<translate z="nan"/></transform></shape>'))
    with pytest.raises(ValueError, match="non-finite coordinates"):
        scn.scene_bounds(nan)


def test_cast_down_reports_misses_and_face_down_surfaces():
    up = mi.load_string(xml('<shape type="rectangle"><transform name="to_world"><scale value="10"/>'
                            '<translate z="2"/></transform></shape>'))
    down = mi.load_string(xml('<shape type="rectangle"><transform name="to_world">'
                              '<scale value="10"/><rotate x="1" angle="180"/></transform></shape>'))
    z, nz = scn.cast_down(up, [0.0, 50.0], [0.0, 0.0])
    assert z[0] == pytest.approx(2.0) and math.isnan(z[1]) and nz[0] == 1.0 and math.isnan(nz[1])
    assert scn.cast_down(down, 0.0, 0.0)[1] == pytest.approx(-1.0)


def test_raycast_reference_elevation_of_a_plane_is_its_height_at_the_centre():
    """The Gaussian-weighted mean height of a plane is its height at the footprint centre
    (odd moments of the footprint vanish); the midpoint quadrature is symmetric, so exact
    to float32 rounding."""
    t = math.tan(math.radians(10.0))
    s = mi.load_string(xml('<shape type="rectangle"><transform name="to_world"><scale value="200"/>'
                           '<rotate y="1" angle="-10"/></transform></shape>'))
    x = np.array([-30.0, 0.0, 12.5])
    z = scn.raycast_reference_elevation_m(s, x, np.zeros(3), sigma_m=2.5)
    np.testing.assert_allclose(z, t * x, atol=2e-4)


@pytest.mark.parametrize("body,expect", [
    ('<shape type="rectangle"><bsdf type="ward"><float name="rho_d" value="1.2"/></bsdf></shape>',
     r"s\.xml \(line 1, col \d+\): failed to instantiate bsdf plugin of type \"ward\": "
     r"ValueError: ward: rho_d \+ rho_s must be <= 1"),
    ('<shape type="rectangle"><bsdf type="ward"><float name="alpha" value="0"/></bsdf></shape>',
     "ward: alpha must be > 0"),
    ('<shape type="nosuch"/>', 'Plugin "nosuch" not found'),
    ('<shape type="ply"><string name="filename" value="missing.ply"/></shape>', "file not found"),
    ('<shape type="rectangle"><float name="bogus" value="1"/></shape>', "unreferenced property"),
    ('<shape type="rectangle"', "Error parsing"),
])
def test_xml_errors_are_one_line_with_file_and_line(tmp_path, body, expect):
    p = write(tmp_path, xml(body))
    with pytest.raises(ValueError, match=expect) as e:
        scn.load_scene(p)
    assert "\n" not in str(e.value) and "Traceback" not in str(e.value)


@pytest.mark.parametrize("text,expect", [
    ("", "No document element"), ("hello", "No document element"),
    ('<scene><shape type="rectangle"/></scene>', "missing version"),
    (xml(""), "no shapes"),
])
def test_unusable_files_are_refused(tmp_path, text, expect):
    with pytest.raises(ValueError, match=expect):
        scn.load_scene(write(tmp_path, text))


def test_load_scene_sources_and_parameters(tmp_path):
    p = write(tmp_path, xml('<default name="h" value="1"/><shape type="rectangle">'
                            '<transform name="to_world"><translate z="$h"/></transform></shape>'))
    s, label = scn.load_scene(p, params={"h": 7.5})
    assert label == str(p) and scn.scene_bounds(s)[1][2] == pytest.approx(7.5)
    with pytest.raises(ValueError, match=r"unused parameters: - \$nope=1"):
        scn.load_scene(p, params={"nope": 1})
    assert scn.load_scene(s)[0] is s
    assert scn.load_scene({"type": "scene", "r": {"type": "rectangle"}})[1] == "dict"
    with pytest.raises(ValueError, match="only apply to an XML"):
        scn.load_scene(s, params={"h": 1})
    with pytest.raises(ValueError, match="not found"):
        scn.load_scene(tmp_path / "none.xml")
    with pytest.raises(ValueError, match="got int"):
        scn.load_scene(42)
    with pytest.raises(ValueError, match="not a <scene>"):
        scn.load_scene({"type": "rectangle"})


def test_mitsuba_mesh_from_arrays():
    v = np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1]], float)
    s = scn.scene_from_mesh(v, [[0, 1, 2]])
    assert scn.cast_heights_m(s, 0.2, 0.2) == pytest.approx(1.0)
    assert type(s.shapes()[0].bsdf()).__name__ == "WardBSDF"     # the paper's snow by default


def test_raycast_reference_elevation_of_a_paraboloid_bowl():
    """Smooth terrain: z = a r^2 about the footprint centre has the Gaussian mean 2 a sigma^2
    (E[x^2 + y^2] = 2 sigma^2); the midpoint rule on the 0.25 sigma grid within 5 sigma is
    exact to ~1e-6 relative here (what it leaves out of the disc weighs 4e-6)."""
    a, sigma, n = 0.01, 2.5, 64
    r = np.linspace(0.0, 40.0, n)
    th = np.linspace(0.0, 2 * np.pi, 4 * n, endpoint=False)
    R, T = np.meshgrid(r, th)
    v = np.column_stack([(R * np.cos(T)).ravel(), (R * np.sin(T)).ravel(), (a * R ** 2).ravel()])
    idx = np.arange(v.shape[0]).reshape(4 * n, n)
    faces = []
    for i in range(4 * n):
        j = (i + 1) % (4 * n)
        for k in range(n - 1):
            faces += [[idx[i, k], idx[j, k + 1], idx[i, k + 1]], [idx[i, k], idx[j, k], idx[j, k + 1]]]
    s = scn.scene_from_mesh(v, np.array(faces)[:, ::-1])
    assert scn.cast_down(s, 1.0, 1.0)[1] > 0                    # faces up
    z = scn.raycast_reference_elevation_m(s, 0.0, 0.0, sigma_m=sigma)
    # the mesh is a faceted bowl: its chords sit above the paraboloid by a r_step^2 / 4 at most
    assert z == pytest.approx(2 * a * sigma ** 2, abs=a * (40 / (n - 1)) ** 2 / 4 + 1e-4)
