"""The first-surface trace's shortcuts give the bits of the long way (issue 43): a scene of
one mesh traced without the shape and BSDF registries' calls, folded shots put back in the
trace's own kernel, a small mesh's bounds read on the host, the kept slots picked on the host
on the CPU backend. Exact comparisons: each shortcut does the same float
operations in the same order, so any difference is a bug, not noise."""
import mitsuba as mi
import numpy as np
import pytest

from lidar_mitsuba.trace import scene as scn
from lidar_mitsuba.ground.brdf import ward_bsdf_dict

pathlength = pytest.importorskip(f"lidar_mitsuba_plugins._{mi.variant()}_pathlength")
scene_utils = pytest.importorskip("lidar_mitsuba_plugins.scene_utils")

import drjit as dr  # noqa: E402


def _rough_tile(rng, n: int = 33, cell_m: float = 1.0):
    """A rough heightfield mesh, n x n nodes ``cell_m`` apart, heights ~0.5 m about 1800 m,
    far from the origin as a corridor tile's first shot is not (float32 at km scale)."""
    from lidar_mitsuba.ground.surface import grid_faces
    x, y = np.meshgrid(np.arange(n) * cell_m, np.arange(n) * cell_m)
    z = 1800.0 + 0.5 * rng.standard_normal(x.shape)
    vertices = np.column_stack([x.ravel() + 700.0, y.ravel() - 300.0, z.ravel()])
    return vertices, grid_faces(n, n)


def _shots(rng, k: int = 48):
    return (700.0 + 8.0 + 16.0 * rng.random(k)).astype(np.float32), \
        (-300.0 + 8.0 + 16.0 * rng.random(k)).astype(np.float32)


def test_a_lone_mesh_traced_in_line_has_the_registry_calls_bits(rng):
    vertices, faces = _rough_tile(rng)
    scene = scn.scene_from_mesh(vertices, faces, bsdf=ward_bsdf_dict())
    mesh = pathlength._lone_mesh(scene)
    assert mesh is not None
    integ = mi.load_dict({"type": "pathlength"})
    sx, sy = _shots(rng)
    args = (scene, mi.Float(sx), mi.Float(sy), 16, dr.opaque(mi.UInt32, 11),
            dr.opaque(mi.Float, 1830.0))
    inline = integ._first_surface(*args)
    # the long way: scene.ray_intersect and si.bsdf() (calls through the registries)
    *_, t_emit, si, leg, wo, seen = integ._first_hit(*args)
    w = integ._return_weight(si, wo, seen)
    t = mi.Float64(t_emit) + (leg + leg) / pathlength.C_M_PER_NS
    registry = (t, w, si.p.x, si.p.y, si.p.z)
    dr.eval(*inline, *registry)
    a, b = [v.numpy() for v in inline], [v.numpy() for v in registry]
    hit = b[1] > 0
    assert hit.mean() > 0.99                         # the footprints are on the tile
    assert np.array_equal(a[1], b[1])
    for u, v in zip(a, b):
        assert u[hit].tobytes() == v[hit].tobytes()
    two = mi.load_dict({"type": "scene", "a": scn.mitsuba_mesh(vertices, faces),
                        "b": {"type": "rectangle"}})
    assert pathlength._lone_mesh(two) is None        # two shapes: the registry's calls


def test_folded_shots_put_back_in_the_kernel_are_returns_moved(rng):
    vertices, faces = _rough_tile(rng)
    scene = scn.scene_from_mesh(vertices, faces, bsdf=ward_bsdf_dict())
    integ = mi.load_dict({"type": "pathlength"})
    sx, sy = _shots(rng)
    k = sx.size
    plain = integ.trace(scene, shot_x_m=sx, shot_y_m=sy, paths_per_shot=8, seed=5)
    # a corridor tile's offsets (one value for every shot) and per-shot ones
    for d in ((np.full(k, -3456.25), np.full(k, 1.2e5), np.zeros(k)),
              (np.full(k, 12.5), np.full(k, -7.25), np.full(k, 0.3711)),   # one dt, one value
              (rng.normal(0, 1e3, k), np.full(k, 7.0), rng.normal(0, 2.0, k))):
        moved = integ.trace(scene, shot_x_m=sx, shot_y_m=sy, paths_per_shot=8, seed=5,
                            offset_m=d)
        ref = plain.moved(dx_m=d[0], dy_m=d[1], dz_m=d[2])
        for name in ref.ARRAYS:
            assert getattr(moved, name).tobytes() == getattr(ref, name).tobytes(), name


def test_small_mesh_bounds_on_the_host_are_the_device_s(rng, monkeypatch):
    vertices, faces = _rough_tile(rng, n=9)
    mesh = scn.mitsuba_mesh(vertices, faces)
    host = scene_utils._vertex_bounds(mesh)
    monkeypatch.setattr(scene_utils, "HOST_BOUNDS_MAX_VERTICES", 0)
    device = scene_utils._vertex_bounds(mesh)
    for h, d in zip(host, device):
        assert h.dtype == d.dtype == np.float64 and h.tobytes() == d.tobytes()
    assert np.array_equal(host[0], vertices.astype(np.float32).min(axis=0))
    vertices[3, 2] = np.nan
    monkeypatch.setattr(scene_utils, "HOST_BOUNDS_MAX_VERTICES", 2 ** 20)
    assert np.isnan(scene_utils._vertex_bounds(scn.mitsuba_mesh(vertices, faces))[1]).all()


def test_mesh_buffers_set_without_the_parameter_map_are_traverse_s(rng):
    """``mitsuba_mesh`` sets its buffers and calls the mesh's ``parameters_changed`` itself
    (``_set_buffers``): the same mesh as ``mi.traverse`` and ``SceneParameters.update`` give
    (buffers, counts, bounding box), and the same hits traced through it."""
    vertices, faces = _rough_tile(rng, n=9)
    lean = scn.mitsuba_mesh(vertices, faces, bsdf=ward_bsdf_dict())
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(ward_bsdf_dict())
    mapped = mi.Mesh("terrain", len(vertices), len(faces), props=props)
    params = mi.traverse(mapped)
    params["vertex_positions"] = mi.Float(vertices.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(faces.astype(np.uint32).ravel())
    params.update()
    for get in (lambda m: m.vertex_positions_buffer().numpy(),
                lambda m: m.faces_buffer().numpy(),
                lambda m: (m.vertex_count(), m.face_count(), str(m.bbox()))):
        a, b = get(lean), get(mapped)
        assert (a.tobytes() == b.tobytes()) if isinstance(a, np.ndarray) else a == b
    sx, sy = _shots(rng, k=8)
    integ = mi.load_dict({"type": "pathlength"})
    got = [integ.trace(mi.load_dict({"type": "scene", "t": m}), shot_x_m=sx, shot_y_m=sy,
                       paths_per_shot=8, seed=2) for m in (lean, mapped)]
    for name in got[0].ARRAYS:
        assert getattr(got[0], name).tobytes() == getattr(got[1], name).tobytes(), name


@pytest.mark.parametrize("max_depth", [1, 2])
def test_slots_kept_in_the_trace_kernel_are_the_fetch_s(rng, max_depth):
    """The trace's own kernel writes each slot's keep mask and shot (``_kept_slots``): the
    fetched returns are the core's slots of non-zero weight in slot order, with shot =
    slot // (paths x bounces) and depth = slot % bounces + 1, computed here on the host
    from the core's raw output. Some footprints lie off the tile (slots of zero weight), so
    the fetch's partial path (gathers by the compressed index) is taken too."""
    vertices, faces = _rough_tile(rng)
    scene = scn.scene_from_mesh(vertices, faces, bsdf=ward_bsdf_dict())
    integ = mi.load_dict({"type": "pathlength", "max_depth": max_depth})
    sx, sy = _shots(rng, k=24)
    sx[:6] -= 40.0                                   # off the tile: nothing returns
    ppp, seed = 8, 9
    got = integ.trace(scene, shot_x_m=sx, shot_y_m=sy, paths_per_shot=ppp, seed=seed)
    core, slots = integ._core(scene)
    lo, hi = scene_utils.scene_bounds(scene)
    z_start = float(hi[2]) + 1e-3 * max(float(hi[2] - lo[2]), 1.0) + 1e-2
    raw = core(scene, mi.Float(sx), mi.Float(sy), ppp,
               dr.opaque(mi.UInt32, pathlength._mix_seed(seed, 0)),
               dr.opaque(mi.Float, z_start))
    dr.eval(*raw)
    t, w, x, y, z = (a.numpy() for a in raw[:5])
    idx = np.flatnonzero(w > 0.0)
    assert 0 < idx.size < w.size
    want = dict(shot=idx // (ppp * slots), time_ns=t[idx], weight=w[idx], x_m=x[idx],
                y_m=y[idx], z_m=z[idx], depth=idx % slots + 1)
    for name, value in want.items():
        arr = getattr(got, name)
        assert np.array_equal(arr, value) and arr.tobytes() == value.astype(arr.dtype).tobytes()


def _device_kept(out, slots_per_shot):
    """``_kept_slots`` as off the CPU backend: the keep mask from the trace's kernel, so the
    fetch compacts on the device (``dr.compress`` and gathers)."""
    w = out[1]
    kept = (w > 0.0, pathlength._quotient(dr.arange(mi.UInt32, dr.width(w)), slots_per_shot))
    dr.eval(*out, *kept)
    return kept


@pytest.mark.parametrize("max_depth", [1, 2])
@pytest.mark.parametrize("off_tile", [False, True])
def test_the_host_fetch_is_the_device_fetch(rng, monkeypatch, max_depth, off_tile):
    """On the CPU backend the fetch picks the slots of non-zero weight with numpy (no keep
    mask in the kernel, no compress kernel): the same returns, to the bit, as the device's
    compress and gathers, whether every slot returns (single bounce on terrain) or not."""
    vertices, faces = _rough_tile(rng)
    scene = scn.scene_from_mesh(vertices, faces, bsdf=ward_bsdf_dict())
    integ = mi.load_dict({"type": "pathlength", "max_depth": max_depth})
    sx, sy = _shots(rng, k=24)
    if off_tile:
        sx[:6] -= 40.0                               # nothing returns from these
    host = integ.trace(scene, shot_x_m=sx, shot_y_m=sy, paths_per_shot=8, seed=4)
    monkeypatch.setattr(pathlength, "_kept_slots", _device_kept)
    device = integ.trace(scene, shot_x_m=sx, shot_y_m=sy, paths_per_shot=8, seed=4)
    assert len(host) > 0 and (len(host) < 24 * 8 * max_depth) == (off_tile or max_depth > 1)
    for name in host.ARRAYS:
        a, b = getattr(host, name), getattr(device, name)
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), name


def test_one_mesh_s_bounds_are_its_vertices_extremes(rng):
    """A scene of one mesh is bounded by its vertex buffer's float32 extremes directly (the
    general loop's union of one); a non-finite vertex still refuses the scene."""
    vertices, faces = _rough_tile(rng, n=9)
    lo, hi = scene_utils.scene_bounds(scn.scene_from_mesh(vertices, faces))
    v32 = vertices.astype(np.float32)
    assert lo.dtype == hi.dtype == np.float64
    assert lo.tobytes() == v32.min(axis=0).astype(np.float64).tobytes()
    assert hi.tobytes() == v32.max(axis=0).astype(np.float64).tobytes()
    vertices[5, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        scene_utils.scene_bounds(scn.scene_from_mesh(vertices, faces))
