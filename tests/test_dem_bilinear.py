"""The DEM's bilinear look-up, compiled (lidar_mitsuba.ground.dem.heights.bilinear_nan), against
numpy's expression it replaced (kept here as the reference): the same bits on and off the
grid, on its last row and column, beside nodata, for points of any shape. Pure numpy."""
import numpy as np

from lidar_mitsuba.ground.dem import heights


def _numpy_bilinear(z, g, x, y):
    """The look-up as numpy wrote it until session 23."""
    ny, nx = z.shape
    fx, fy = x / g, y / g
    outside = ~((fx >= 0) & (fy >= 0) & (fx <= nx - 1) & (fy <= ny - 1))
    fx = np.where(outside, 0.0, fx)
    fy = np.where(outside, 0.0, fy)
    ix = np.minimum(fx.astype(np.intp), nx - 2)
    iy = np.minimum(fy.astype(np.intp), ny - 2)
    tx, ty = fx - ix, fy - iy
    out = np.zeros(np.shape(fx))
    for w, zz in (((1 - tx) * (1 - ty), z[iy, ix]), (tx * (1 - ty), z[iy, ix + 1]),
                  ((1 - tx) * ty, z[iy + 1, ix]), (tx * ty, z[iy + 1, ix + 1])):
        out += np.where(w > 0, w * zz, 0.0)
    return np.where(outside, np.nan, out)


def test_bilinear_is_numpy_s_expression(rng):
    g = 100.0
    z = rng.normal(1500.0, 300.0, (40, 30))
    z[10:12, 5:8] = np.nan                          # nodata inside
    z[-1, :] = -0.0                                 # a last row of signed zeros
    x = np.concatenate([rng.uniform(-50.0, 3000.0, 20000),
                        np.arange(30) * g,              # on the nodes and the last column
                        [np.nan, -0.0, 29 * g, 29 * g + 1e-9]])
    y = np.concatenate([rng.uniform(-50.0, 4000.0, 20000), np.full(30, 39 * g),
                        [0.0, 0.0, np.nan, 0.0]])
    want, got = _numpy_bilinear(z, g, x, y), heights.bilinear_nan(z, g, x, y)
    assert np.array_equal(got.view(np.int64), want.view(np.int64))
    assert np.isnan(got).sum() > 100 and np.isfinite(got).sum() > 15000   # (both were met)
    grid = heights.bilinear_nan(z, g, x[:600].reshape(20, 30), y[:30])    # broadcast shapes
    assert grid.shape == (20, 30)
    assert np.array_equal(grid.view(np.int64), _numpy_bilinear(
        z, g, x[:600].reshape(20, 30), np.broadcast_to(y[:30], (20, 30))).view(np.int64))


def test_on_grid_is_numpy_s_test_of_the_grid(rng):
    """The fold's probes on a window without nodata (``finite_at``): every shifted point on
    the grid, as numpy's comparisons gave it, on the grid's edges and off it, NaN too."""
    g, nx, ny = 100.0, 30, 40
    px = np.concatenate([rng.uniform(-20.0, 2920.0, 5000), [0.0, 2900.0, -1e-9, np.nan]])
    py = np.concatenate([rng.uniform(-20.0, 3920.0, 5000), [3900.0, 0.0, 5.0, 5.0]])
    offs = np.array([(0.0, 0.0), (13.5, 0.0), (-13.5, 0.0), (0.0, 13.5), (0.0, -13.5)])
    want = np.ones(px.size, bool)
    for dx, dy in offs:
        fx, fy = (px + dx) / g, (py + dy) / g
        want &= (fx >= 0) & (fy >= 0) & (fx <= nx - 1) & (fy <= ny - 1)
    got = heights._on_grid(px, py, offs, g, nx, ny)
    assert np.array_equal(got, want) and 100 < want.sum() < want.size - 100
