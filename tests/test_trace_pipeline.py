"""The integrator's launch/fetch split and what it moved onto the device (issue 14):
compaction, per-shot offsets of folded tracks, the field-of-view clip of the last bounce, and
the chunk loop's overlap of tracing and detecting. Every check here is exact: the fast path
against the plain one it replaces (same photons, bit for bit), or geometry against a closed
form."""
import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import lidar_mitsuba_plugins
from lidar_mitsuba.detector import deadtime as _deadtime
from lidar_mitsuba.trace import stream as chunks
from lidar_mitsuba.ground import terrain
from lidar_mitsuba.instrument import Instrument
from lidar_mitsuba.detector.records import Returns
from lidar_mitsuba.trace.scene import scene_from_mesh
from lidar_mitsuba.ground.surface import heightfield_to_trimesh

pathlength = lidar_mitsuba_plugins.module("pathlength")


@pytest.fixture(scope="module")
def rough_scene():
    """A rough 128 m tile (p = 1.5, 20 m relief): plenty of second bounces."""
    hf = terrain.fractal(p=1.5, size_m=128.0, grid_m=1.0, relief_m=20.0, seed=3)
    tm = heightfield_to_trimesh(hf, margin_m=13.5)
    return scene_from_mesh(tm.vertices, tm.faces)


def shots(n=300):
    return (np.arange(n) * 0.3) % 90 + 20, np.full(n, 64.0)


def integ(**kw):
    return mi.load_dict({**Instrument().integrator_dict(), **kw})


def assert_returns_equal(a: Returns, b: Returns):
    assert (a.n_shots, a.paths_per_shot) == (b.n_shots, b.paths_per_shot)
    for name in Returns.ARRAYS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype, name
        np.testing.assert_array_equal(x, y, err_msg=name)


def test_launch_then_result_is_trace_and_times_the_host(rough_scene):
    xs, ys = shots()
    it = integ(max_depth=2, max_lanes=5000)        # several integrator chunks
    pending = it.launch(rough_scene, shot_x_m=xs, shot_y_m=ys, paths_per_shot=32, seed=4)
    out = pending.result()
    assert_returns_equal(out, it.trace(rough_scene, shot_x_m=xs, shot_y_m=ys,
                                       paths_per_shot=32, seed=4))
    assert set(pending.timings_s) == {"launch_s", "wait_s", "fetch_s"}
    assert all(v >= 0 for v in pending.timings_s.values())
    assert np.all(out.weight > 0) and np.all(np.diff(out.shot.astype(np.int64)) >= 0)
    assert np.any(out.depth == 2) and set(np.unique(out.depth)) <= {1, 2}


def test_offsets_on_the_device_equal_moving_on_the_host(rough_scene):
    """offset_m (folded tracks put back on the device) gives exactly Returns.moved."""
    xs, ys = shots()
    rng = np.random.default_rng(1)
    dx, dy, dz = (rng.uniform(-3e3, 3e3, xs.size) for _ in range(3))
    for depth in (1, 2):
        it = integ(max_depth=depth, max_lanes=4000)
        plain = it.trace(rough_scene, shot_x_m=xs, shot_y_m=ys, paths_per_shot=16, seed=9)
        moved = it.trace(rough_scene, shot_x_m=xs, shot_y_m=ys, paths_per_shot=16, seed=9,
                         offset_m=(dx, dy, dz))
        assert_returns_equal(moved, plain.moved(dx_m=dx, dy_m=dy, dz_m=dz))
    with pytest.raises(ValueError, match="offset_m"):
        it.trace(rough_scene, shot_x_m=xs, shot_y_m=ys, offset_m=(dx, dy))


def test_fov_exit_against_the_circle_it_leaves():
    """_fov_exit: the distance at which a ray leaves the vertical cylinder for good; checked
    against the closed-form circle crossing in float64 and by stepping along the ray."""
    rng = np.random.default_rng(5)
    n, radius = 2000, 20.0
    o = np.stack([rng.uniform(-40, 40, n), rng.uniform(-40, 40, n), rng.uniform(-5, 5, n)])
    d = rng.standard_normal((3, n))
    d[:, :50] = [[0.0], [0.0], [1.0]]                          # vertical rays
    d /= np.linalg.norm(d, axis=0)
    ray = mi.Ray3f(mi.Point3f(*(mi.Float(a.astype(np.float32)) for a in o)),
                   mi.Vector3f(*(mi.Float(a.astype(np.float32)) for a in d)))
    got = pathlength._fov_exit(ray, mi.Float(np.zeros(n, np.float32)),
                               mi.Float(np.zeros(n, np.float32)), radius).numpy()
    a = d[0] ** 2 + d[1] ** 2
    b = o[0] * d[0] + o[1] * d[1]
    c = o[0] ** 2 + o[1] ** 2 - radius ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        t_out = (np.sqrt(b * b - a * c) - b) / a
    inside = c <= 0
    vertical = a < 1e-12
    assert np.all(np.isinf(got[vertical & inside])) and np.all(got[vertical & ~inside] == 0)
    crossing = ~vertical & (b * b - a * c >= 0) & (t_out > 0)
    np.testing.assert_allclose(got[crossing], t_out[crossing], rtol=1e-4, atol=1e-3)
    assert np.all(got[~vertical & ~crossing] == 0)          # never inside ahead of the origin
    # stepping: inside the cylinder just before the exit, outside just after, for good
    t = got[crossing]
    for s, sign in ((0.999, -1), (1.001, 1), (3.0, 1)):
        p = o[:2, crossing] + s * t * d[:2, crossing]
        r = np.hypot(*p)
        assert np.all(sign * (r - radius) > -1e-3)


def test_fov_clip_of_the_last_bounce_changes_no_photon(rough_scene, monkeypatch):
    """Clipping the last ray where it leaves the field of view only skips hits that would
    not have been seen: the traced returns are bit for bit those of the unclipped rays."""
    xs, ys = shots(200)
    for depth in (2, 3):
        it = integ(max_depth=depth)
        clipped = it.trace(rough_scene, shot_x_m=xs, shot_y_m=ys, paths_per_shot=64, seed=2)
        with monkeypatch.context() as m:
            m.setattr(pathlength, "_fov_exit", lambda ray, *_: dr.full(mi.Float, dr.inf,
                                                                       dr.width(ray.o.x)))
            full = integ(max_depth=depth).trace(rough_scene, shot_x_m=xs, shot_y_m=ys,
                                                paths_per_shot=64, seed=2)
        assert_returns_equal(clipped, full)
        assert np.sum(full.depth == depth) > 100        # the last vertex does return light


def test_overlapped_chunk_loop_detects_what_the_plain_loop_does(rough_scene):
    """chunks.run launches chunk k + 1 before detecting chunk k; the detections equal those
    of a source that cannot launch ahead."""
    xs, ys = shots(900)
    src = chunks.traced(integ(max_depth=2), rough_scene, x_m=xs, y_m=ys, paths_per_shot=32,
                        dz_m=np.linspace(0, 50, xs.size))
    z_ref = np.full(xs.size, 10.0)
    kw = dict(detectors={"run": Instrument(beam="strong", background_mhz=3.0)}, z_ref_m=z_ref,
              seed=11, chunk_shots=250)
    fast = chunks.run(source=src, **kw).detections["run"]
    plain = chunks.run(source=lambda a, b, s: src(a, b, s), **kw).detections["run"]
    for name in fast.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(fast, name), getattr(plain, name), err_msg=name)
    assert len(fast) > 1000


def shot_stats_by_loop(shot, weight, n_shots):
    """The definition of _deadtime.shot_stats, as a plain loop."""
    w_sum = np.zeros(n_shots)
    counts = np.zeros(n_shots + 1, np.int64)
    for s, w in zip(shot.tolist(), weight.tolist()):
        w_sum[s] += w
        counts[s + 1] += 1
    ordered = bool(np.all(np.diff(shot.astype(np.int64)) >= 0))
    return w_sum, np.cumsum(counts), float(weight.max(initial=0.0)), ordered


@pytest.mark.parametrize("n_returns", [0, 1, 7, 5000])
def test_parallel_shot_stats_equals_the_loop(rng, n_returns):
    n_shots = 300
    shot = np.sort(rng.integers(0, n_shots, n_returns)).astype(np.uint32)  # gaps: empty shots
    weight = rng.uniform(0, 2, n_returns).astype(np.float32)
    w_sum, start, w_max, ordered = _deadtime.shot_stats(shot, weight, n_shots)
    ref = shot_stats_by_loop(shot, weight, n_shots)
    np.testing.assert_array_equal(w_sum, ref[0])          # same order of summation: exact
    np.testing.assert_array_equal(start, ref[1])
    assert w_max == ref[2] and ordered and ref[3]
    if n_returns > 1:
        shot[[0, -1]] = shot[[-1, 0]]
        assert not _deadtime.shot_stats(shot, weight, n_shots)[3]


def test_bounds_of_a_mesh_with_a_nan_vertex_are_refused():
    from lidar_mitsuba.trace.scene import scene_bounds
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, math.nan]], float)
    scene = scene_from_mesh(v, np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match="non-finite"):
        scene_bounds(scene)
