"""Tests for lidar_mitsuba.ground.terrain (fractal synthesis, heightfield look-ups, roughness).

All seeds are fixed. Statistical tolerances are derived from the sampling error
of the quantity tested (explained next to each assertion); deterministic
properties are tested to floating-point precision.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidar_mitsuba.ground import terrain as T
from lidar_mitsuba.constants import ParameterError

# --------------------------------------------------------------------------- #
# fractal(): relief, mean, determinism, tiling
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("p", [0.5, 1.0, 1.5, 1.8, 2.0, 3.0, 5.0])
def test_relief_exact_and_zero_mean(p: float) -> None:
    h = T.fractal(p=p, size_m=256.0, grid_m=1.0, relief_m=10.0, seed=1)
    assert h.z_m.shape == (256, 256)
    assert h.z_m.dtype == np.float64
    assert h.periodic
    assert h.nx == h.ny == 256
    assert h.size_x_m == h.size_y_m == 256.0
    # Rescaling makes max - min == relief up to rounding (a few ulp of 10 m).
    assert abs((h.z_m.max() - h.z_m.min()) - 10.0) < 1e-9
    assert abs(h.relief_m - 10.0) < 1e-9
    # Mean removed before scaling (and the DC term is zero): only rounding left.
    assert abs(h.z_m.mean()) < 1e-9


def test_relief_zero_gives_flat_and_grid_spacing() -> None:
    h = T.fractal(p=1.8, size_m=64.0, grid_m=0.5, relief_m=0.0, seed=3)
    assert h.z_m.shape == (128, 128)
    assert np.all(h.z_m == 0.0)
    assert h.grid_m == 0.5 and h.size_x_m == 64.0
    f = T.flat(size_m=32.0, grid_m=2.0, z_m=4.5)
    assert f.z_m.shape == (16, 16) and np.all(f.z_m == 4.5) and f.relief_m == 0.0


def test_seed_determinism() -> None:
    a = T.fractal(p=1.7, size_m=128.0, seed=42)
    b = T.fractal(p=1.7, size_m=128.0, seed=42)
    c = T.fractal(p=1.7, size_m=128.0, seed=43)
    assert np.array_equal(a.z_m, b.z_m)
    assert not np.allclose(a.z_m, c.z_m)
    # seed=None draws fresh entropy.
    d = T.fractal(p=1.7, size_m=128.0, seed=None)
    assert not np.allclose(a.z_m, d.z_m)


def test_heightfield_is_read_only() -> None:
    h = T.fractal(p=1.8, size_m=64.0, seed=0)
    with pytest.raises(ValueError):
        h.z_m[0, 0] = 1.0
    # A user array is copied, not frozen in place.
    z = np.zeros((8, 8))
    hf = T.Heightfield(z_m=z, grid_m=1.0)
    z[0, 0] = 5.0
    assert hf.z_m[0, 0] == 0.0 and z.flags.writeable


@pytest.mark.parametrize("p", [1.5, 2.0])
def test_periodic_tiling_seam(p: float) -> None:
    """The surface is continuous across the wrap.

    On the torus the field is stationary, so the column pair (N-1, 0) across the
    seam is statistically exchangeable with every interior pair (i, i+1). The
    seam's mean-squared difference is then just one more draw from the same
    distribution as the N-1 interior per-pair MSDs: its rank is uniform, so it
    lies within [min, max] of the interior values with probability 1 - 2/N
    (> 99.6 % for N = 512). Same along y. A negative control (the seam of a
    cropped, non-periodic half tile) must fall far outside that range.
    """
    n = 512
    z = T.fractal(p=p, size_m=float(n), seed=7).z_m
    for zz in (z, z.T):  # x seam, then y seam
        interior = np.mean(np.diff(zz, axis=1) ** 2, axis=0)  # (N-1,) per column pair
        seam = np.mean((zz[:, 0] - zz[:, -1]) ** 2)
        assert interior.min() <= seam <= interior.max()
        # Negative control: the half tile zz[:, :N/2] is not periodic; its
        # "seam" (column N/2-1 -> 0) spans N/2 - 1 grid steps.
        crop = zz[:, : n // 2]
        fake_seam = np.mean((crop[:, 0] - crop[:, -1]) ** 2)
        assert fake_seam > 10 * interior.max()


# --------------------------------------------------------------------------- #
# RMS height (paper eqs. 5-6)
# --------------------------------------------------------------------------- #
def test_rms_height_definition() -> None:
    rng = np.random.default_rng(0)
    z = rng.normal(3.0, 2.0, 1000)
    # Eqs. 5-6 literally; well conditioned here, so equal to ~1e-12 relative.
    n = z.size
    literal = math.sqrt((np.sum(z**2) - n * z.mean() ** 2) / n)
    assert math.isclose(T.rms_height_m(z), literal, rel_tol=1e-12)
    # Same as the population standard deviation by definition.
    assert math.isclose(T.rms_height_m(z), float(np.std(z)), rel_tol=1e-12)
    # 2-D input is flattened.
    z2 = z.reshape(20, 50)
    assert math.isclose(T.rms_height_m(z2), float(np.std(z2)), rel_tol=1e-12)
    # Sinusoid of amplitude A over whole periods: A / sqrt(2); offset-invariant.
    x = np.arange(400)
    s = 1e4 + 0.7 * np.sin(2 * np.pi * 5 * x / 400)
    assert math.isclose(T.rms_height_m(s), 0.7 / math.sqrt(2), rel_tol=1e-9)


def test_rms_height_decreases_with_p_at_footprint_scale() -> None:
    """Paper Fig. 5: larger p -> smaller RMS height (less rough surface).

    What holds at a FIXED total relief (10 m over 1024 m): raising p moves
    variance from short to long wavelengths. Over along-track profile segments
    short compared with the tile (here 16 m, about one ICESat-2 footprint; mean
    removed per segment, i.e. eq. 5-6 applied to each segment), RMS height
    falls with p, by roughly 20 % per 0.1 step in p -- far beyond the sampling
    scatter of the mean over 64 x 1024 segments (same white noise is used for
    all p, so only p changes). Strict monotonic decrease is asserted.

    Over the whole tile the opposite holds at fixed relief: a steep spectrum
    concentrates variance in a few long waves whose max-min range is only
    ~3 sigma (a pure sine: 2*sqrt(2) sigma), whereas a rough, many-mode
    surface spans more sigmas in the same 10 m. The whole-grid RMS therefore
    grows with p; this is asserted too, to document why the paper's statement
    must be read at short profile lengths.
    """
    ps = [1.5, 1.6, 1.7, 1.8, 1.9, 2.0]
    seg_rms, grid_rms = [], []
    for p in ps:
        z = T.fractal(p=p, size_m=1024.0, relief_m=10.0, seed=0).z_m
        segs = z.reshape(1024, 64, 16)  # along-track (x) segments of 16 m
        seg_rms.append(np.mean([T.rms_height_m(s) for s in segs.reshape(-1, 16)[::7]]))
        grid_rms.append(T.rms_height_m(z))
    seg_rms = np.array(seg_rms)
    assert np.all(np.diff(seg_rms) < 0)
    assert np.all(seg_rms[1:] / seg_rms[:-1] < 0.95)
    assert np.all(np.diff(grid_rms) > 0)


# --------------------------------------------------------------------------- #
# Heightfield.height_m (bilinear)
# --------------------------------------------------------------------------- #
def test_height_exact_at_nodes_and_wraps() -> None:
    h = T.fractal(p=1.8, size_m=64.0, grid_m=0.5, seed=2)  # 128 x 128, tile 64 m
    iy, ix = np.meshgrid(np.arange(128), np.arange(128), indexing="ij")
    assert np.array_equal(h.height_m(ix * 0.5, iy * 0.5), h.z_m)
    # Periodic wrap: shifting by whole tiles (either sign) changes nothing.
    rng = np.random.default_rng(0)
    x = rng.uniform(-100, 100, 500)
    y = rng.uniform(-100, 100, 500)
    base = h.height_m(x, y)
    for sx, sy in ((64.0, 0.0), (0.0, -128.0), (192.0, 64.0)):
        assert np.allclose(h.height_m(x + sx, y + sy), base, atol=1e-9)
    # Between the last node and the wrapped first node: linear between them.
    mid = h.height_m(np.full(128, 63.75), np.arange(128) * 0.5)
    assert np.allclose(mid, 0.5 * (h.z_m[:, -1] + h.z_m[:, 0]), atol=1e-12)
    # Broadcasting: (3, 1) x (1, 4) -> (3, 4); NaN propagates.
    assert h.height_m(np.zeros((3, 1)), np.zeros((1, 4))).shape == (3, 4)
    assert np.isnan(h.height_m(np.nan, 0.0))


def test_height_bilinear_exact_for_plane_and_clamps() -> None:
    a, b, c, g = 0.03, -0.07, 12.0, 2.0
    ny, nx = 40, 50
    y = np.arange(ny)[:, None] * g
    x = np.arange(nx)[None, :] * g
    plane = T.Heightfield(z_m=a * x + b * y + c, grid_m=g, periodic=False)
    rng = np.random.default_rng(1)
    xs = rng.uniform(0, (nx - 1) * g, 1000)
    ys = rng.uniform(0, (ny - 1) * g, 1000)
    assert np.allclose(plane.height_m(xs, ys), a * xs + b * ys + c, rtol=0, atol=1e-12)
    # Non-periodic: points outside clamp to the border value.
    assert math.isclose(float(plane.height_m(-10.0, 0.0)), c)
    xe = (nx - 1) * g
    assert math.isclose(float(plane.height_m(xe + 30.0, 0.0)), a * xe + c)
    # Bilinear exactly reproduces the bilinear interpolant x*y too (not just planes).
    saddle = T.Heightfield(z_m=(x * y).astype(float), grid_m=g, periodic=False)
    assert np.allclose(saddle.height_m(xs, ys), xs * ys, atol=1e-9)


# --------------------------------------------------------------------------- #
# Heightfield.reference_elevation_m (Gaussian footprint mean)
# --------------------------------------------------------------------------- #
def test_reference_elevation_plane() -> None:
    # A symmetric, normalised kernel maps a plane onto itself; away from the
    # edges ('nearest' padding is then never touched) the result is the plane
    # height at the footprint centre up to rounding.
    a, b, c, g, sigma = 0.02, 0.05, 100.0, 1.0, 6.0
    ny = nx = 200
    y = np.arange(ny)[:, None] * g
    x = np.arange(nx)[None, :] * g
    hf = T.Heightfield(z_m=a * x + b * y + c, grid_m=g, periodic=False)
    rng = np.random.default_rng(2)
    margin = 4 * sigma + 2 * g
    xs = rng.uniform(margin, (nx - 1) * g - margin, 200)
    ys = rng.uniform(margin, (ny - 1) * g - margin, 200)
    ref = hf.reference_elevation_m(xs, ys, sigma_m=sigma)
    truth = a * xs + b * ys + c
    assert np.all(np.abs(ref / truth - 1) < 1e-9)
    # Flat terrain: reference elevation is the flat height, everywhere (wraps).
    f = T.flat(size_m=64.0, z_m=3.0)
    assert np.allclose(f.reference_elevation_m([-5.0, 30.0, 100.0], [0.0, 70.0, 3.0], sigma_m=4.0), 3.0)


def test_reference_elevation_matches_bruteforce() -> None:
    """Gaussian-weighted mean over all grid nodes (periodic distances).

    Differences come only from (i) bilinear interpolation of the smoothed grid
    between nodes, error <= grid^2/8 * |curvature| of the smoothed surface
    (~0.2 mm here for 10 m relief over 512 m and sigma = 7 m), and (ii) the 4-sigma
    kernel truncation (tail weight < e^-8 of a field that varies by < 1 m at
    that range): both well below the 1 mm tolerance.
    """
    h = T.fractal(p=1.8, size_m=512.0, relief_m=10.0, seed=3)
    sigma = 7.0
    rng = np.random.default_rng(4)
    pts = np.column_stack([rng.uniform(-50, 560, 6), rng.uniform(0, 512, 6)])
    ref = h.reference_elevation_m(pts[:, 0], pts[:, 1], sigma_m=sigma)
    nodes = np.arange(512.0)
    for (px, py), r in zip(pts, ref):
        dx = (nodes - px + 256.0) % 512.0 - 256.0  # minimum-image distances
        dy = (nodes - py + 256.0) % 512.0 - 256.0
        w = np.exp(-(dy[:, None] ** 2 + dx[None, :] ** 2) / (2 * sigma**2))
        brute = float((w * h.z_m).sum() / w.sum())
        assert abs(r - brute) < 1e-3
    # The reference surface is smoother than the surface itself.
    assert np.std(h.smoothed_grid(sigma_m=sigma)) < np.std(h.z_m)
    # Cached: repeated calls return the same array object.
    assert h.smoothed_grid(sigma_m=sigma) is h.smoothed_grid(sigma_m=sigma)
    assert np.array_equal(h.reference_elevation_m(pts[:, 0], pts[:, 1], sigma_m=0.0),
                          h.height_m(pts[:, 0], pts[:, 1]))


@pytest.mark.parametrize("periodic", [True, False])
def test_reference_elevation_on_few_rows_equals_the_whole_grid_filter(periodic) -> None:
    """A track touching few rows filters only those (simulate's case): the same bits as
    the whole grid's cached filter, for a track folded along x, a narrow band, the
    whole tile (falls back to the full filter) and NaN points; nothing is cached."""
    h = T.fractal(p=1.8, size_m=256.0, relief_m=10.0, seed=5)
    if not periodic:
        h = T.Heightfield(z_m=h.z_m[:200, :230].copy(), grid_m=0.5, periodic=False)
    rng = np.random.default_rng(6)
    cases = [((np.arange(3000) * 0.7) % 900.0 - 50.0, np.full(3000, 61.3)),
             (rng.uniform(-20, 140, 500), 40.0 + rng.uniform(-1.5, 1.5, 500)),
             (rng.uniform(-20, 140, 500), rng.uniform(-20, 140, 500)),
             (np.array([1.0, np.nan, 5.0]), np.array([np.nan, 3.0, 99.0]))]
    full = h._interp(h.smoothed_grid(sigma_m=2.5), *cases[0])
    for xs, ys in cases:
        h._cache.clear()
        got = h.reference_elevation_m(xs, ys, sigma_m=2.5)
        if xs is cases[0][0]:
            assert not h._cache
        want = h._interp(h.smoothed_grid(sigma_m=2.5), xs, ys)
        assert np.array_equal(got, want, equal_nan=True)
    assert np.array_equal(full, h.reference_elevation_m(*cases[0], sigma_m=2.5))


# --------------------------------------------------------------------------- #
# Validation
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"p": -1.0}, "p"),
        ({"p": 0.0}, "p"),
        ({"p": 5.5}, "p"),
        ({"p": float("nan")}, "p"),
        ({"size_m": 0.0}, "size_m"),
        ({"size_m": -5.0}, "size_m"),
        ({"grid_m": 0.0}, "grid_m"),
        ({"grid_m": -1.0}, "grid_m"),
        ({"size_m": 7.0, "grid_m": 1.0}, "grid_m"),  # N = 7 < 8: the grid count is grid_m's
        ({"size_m": 8193.0, "grid_m": 1.0}, "grid_m"),  # N > 8192
        ({"relief_m": -0.1}, "relief_m"),
        ({"seed": 1.5}, "seed"),
    ],
)
def test_fractal_validation(kwargs, name) -> None:
    """Each bad value raises ParameterError naming the parameter (the CLI names the option)."""
    with pytest.raises(ParameterError, match=f"^{name}: ") as e:
        T.fractal(**kwargs)
    assert e.value.name == name


def test_validation_messages_and_heightfield_checks() -> None:
    with pytest.raises(ParameterError, match=r"^p: must be in \(0, 5\] \(got -1\)"):
        T.fractal(p=-1)
    with pytest.raises(ParameterError, match="^size_m: "):
        T.flat(size_m=-1.0)
    with pytest.raises(ParameterError, match="^z_m: "):
        T.Heightfield(z_m=np.zeros(5), grid_m=1.0)
    with pytest.raises(ParameterError, match="^grid_m: "):
        T.Heightfield(z_m=np.zeros((4, 4)), grid_m=0.0)
    with pytest.raises(ParameterError, match="^sigma_m: "):
        T.flat(size_m=16.0).reference_elevation_m(0.0, 0.0, sigma_m=-1.0)
