"""Real terrain (GeoTIFF DEM), real orbit geometry (six beams, lat/lon tracks) and granules
that third-party ICESat-2 readers read (issue 13)."""
from __future__ import annotations

import json
import subprocess
import sys
import threading

import h5py
import numpy as np
import pytest
from pyproj import Geod, Transformer

from cli_checks import bad_call
from lidar_mitsuba.ground import dem as dems
from lidar_mitsuba import geotrack, granule
from lidar_mitsuba.constants import C_M_PER_NS, ParameterError

TRACK = geotrack.GeoTrack(start_lat_deg=69.97, start_lon_deg=-45.0, azimuth_deg=0.0)


@pytest.fixture(scope="module")
def dem_path(tmp_path_factory):
    """The repository's test DEM: a real GeoTIFF in EPSG:3413 with a nodata hole."""
    return dems.synthetic_ice_sheet(tmp_path_factory.mktemp("dem") / "ice.tif")


@pytest.fixture(scope="module")
def six_beams(dem_path, tmp_path_factory):
    """A six-beam granule (1500 shots per beam) and its ATL03 and ATL06 files."""
    surf = dems.DEMSurface(dems.DEM.open(dem_path), tile_shots=1024)
    g = granule.simulate_granule(surface=surf, track=TRACK, shots=1500, beams="all",
                                 seed=3, progress=False, max_depth=1)
    d = tmp_path_factory.mktemp("granule")
    return g, granule.write_atl03(g, d / "ATL03_sim.h5"), granule.write_atl06(g, d / "ATL06_sim.h5")


# --------------------------------------------------------------------------- the DEM
def test_dem_reads_crs_posting_and_refuses_bad_files(dem_path, tmp_path):
    d = dems.DEM.open(dem_path)
    assert d.crs.to_epsg() == 3413 and d.posting_m == 20.0
    with pytest.raises(ParameterError, match="no such file") as e:
        dems.DEM.open(tmp_path / "missing.tif")
    assert e.value.name == "dem"
    (tmp_path / "junk.tif").write_text("not a tiff")
    with pytest.raises(ParameterError, match="not a raster"):
        dems.DEM.open(tmp_path / "junk.tif")
    z = np.zeros((10, 10))
    dems.write_geotiff(tmp_path / "geo.tif", z, x0_m=-45, y1_m=70, posting_m=0.1, crs="EPSG:4326")
    with pytest.raises(ParameterError, match="not projected"):
        dems.DEM.open(tmp_path / "geo.tif")


def test_dem_heights_are_bilinear_in_the_file_pixels(tmp_path):
    """A plane written to a GeoTIFF comes back exactly (bilinear interpolation of a plane is
    the plane) at arbitrary points, through the north-up row flip and the pixel-centre
    convention; nodata reads as NaN."""
    g, x0, y1 = 10.0, 500_000.0, 7_000_000.0
    rows, cols = 40, 30
    xc = x0 + g * (np.arange(cols) + 0.5)
    yc = y1 - g * (np.arange(rows) + 0.5)
    X, Y = np.meshgrid(xc, yc)
    z = 100.0 + 0.01 * (X - x0) - 0.02 * (y1 - Y)
    z[0, 0] = np.nan
    dems.write_geotiff(tmp_path / "plane.tif", z, x0_m=x0, y1_m=y1, posting_m=g, crs="EPSG:32624")
    surf = dems.DEMSurface(dems.DEM.open(tmp_path / "plane.tif"), origin_m=(x0, y1 - 400))
    rng = np.random.default_rng(0)
    px = x0 + rng.uniform(50, 280, 200)
    py = y1 - rng.uniform(50, 380, 200)
    want = 100.0 + 0.01 * (px - x0) - 0.02 * (y1 - py)
    got = surf.height_m(px - surf.origin_m[0], py - surf.origin_m[1])
    np.testing.assert_allclose(got, want, atol=2e-4)     # float32 file: ~1e-5 relative
    # the footprint-weighted mean of a plane is the plane at the centre
    ref = surf.reference_elevation_m(px - surf.origin_m[0], py - surf.origin_m[1], sigma_m=3.5)
    np.testing.assert_allclose(ref, want, atol=2e-4)
    assert np.isnan(surf.height_m(xc[0] - surf.origin_m[0], yc[0] - surf.origin_m[1]))


def _pixel_tile_numpy(dem, x, y, *, reach_m, origin_m, tolerance_m):
    """``tiles.pixel_tile`` as numpy computed it before issue 43's session 24 (the cells
    from ``_corridor_cells``, the split from ``_split_cells``): the compiled passes' reference."""
    import math
    from lidar_mitsuba.ground.dem import tiles
    z, (wx, wy), i, j, (ox, oy) = tiles._corridor_cells(dem, x, y, reach_m=reach_m,
                                                        origin_m=origin_m)
    P = dem.posting_m
    z00, z10, z01, z11 = z[i, j], z[i, j + 1], z[i + 1, j], z[i + 1, j + 1]
    bad = ~np.isfinite(z00 + z10 + z01 + z11)
    if bad.any():
        k = np.flatnonzero(bad)[0]
        raise tiles.nodata_error(dem, reach_m, wx + (j[k] + 0.5) * P, wy + (i[k] + 0.5) * P)
    twist = float(np.max(np.abs(z00 + z11 - z10 - z01), initial=0.0))
    k = max(1, math.ceil(math.sqrt(twist / (4.0 * tolerance_m))))
    px, py, faces = tiles._split_cells(i, j, k, z.shape, P)
    vertices = np.column_stack([px + wx - origin_m[0] - ox, py + wy - origin_m[1] - oy,
                                tiles.bilinear_nan(z, P, px, py)])
    return vertices, faces, (ox, oy)


def test_compiled_pixel_tiles_are_numpys(dem_path):
    """``pixel_tile``'s compiled passes (``pixel_mesh``) against numpy's: the same vertices
    (bytes), faces and origin on tracks along, across and diagonal to the grid, at
    tolerances giving k = 1 to 5 (the diagonal's finest numbering its nodes by np.unique:
    numpy's path), in a frame whose origin is far from the tile; and the same refusal, naming the same nodata
    point, for a track over the DEM's hole."""
    from lidar_mitsuba.ground.dem import tiles
    dem = dems.DEM.open(dem_path)
    x0, x1, y0, y1 = dem.bounds_m
    origin = (float(np.round(x0, -3)), float(np.round(y0, -3)))
    t = np.linspace(0.0, 1.0, 600)
    tracks = [(0.3 * x0 + 0.7 * x1 + 0 * t, y0 + 500 + 1500 * t),          # along y
              (x0 + 500 + 1500 * t, 0.2 * y0 + 0.8 * y1 + 0 * t),           # along x
              (x0 + 2700 + 900 * t, y0 + 2700 + 900 * t)]                   # diagonal
    for x, y in tracks:
        for tol in (1.0, 0.05, 0.01, 0.002):
            kw = dict(reach_m=13.5, origin_m=origin, tolerance_m=tol)
            got = tiles.pixel_tile(dem, x - origin[0], y - origin[1], **kw)
            want = _pixel_tile_numpy(dem, x - origin[0], y - origin[1], **kw)
            assert got[0].tobytes() == want[0].tobytes() and got[0].shape == want[0].shape
            assert got[1].dtype == want[1].dtype and np.array_equal(got[1], want[1])
            assert got[2] == want[2]
    x, y = x0 + 200 + 2000 * t - origin[0], y0 + 500 + 0 * t - origin[1]   # its SW hole
    messages = []
    for f in (tiles.pixel_tile, _pixel_tile_numpy):
        with pytest.raises(ParameterError) as e:
            f(dem, x, y, reach_m=13.5, origin_m=origin, tolerance_m=0.01)
        messages.append(str(e.value))
    assert messages[0] == messages[1]


def test_split_cells_numbers_nodes_as_np_unique():
    """The corridor mesh numbers its sub-grid nodes ascending, each used node once, with a
    mask over the window's sub-grid where the corridor fills much of the window and with
    np.unique where it does not: both give the faces and node positions of the np.unique
    construction exactly, on random windows (either branch taken, k = 1..4)."""
    from lidar_mitsuba.ground.dem.tiles import _split_cells
    rng = np.random.default_rng(7)
    branches = set()
    for _ in range(300):
        ny, nx = (int(v) for v in rng.integers(2, 40, 2))
        k = int(rng.integers(1, 5))
        cells = rng.choice((ny - 1) * (nx - 1), int(rng.integers(1, (ny - 1) * (nx - 1) + 1)),
                           replace=False)
        i, j = np.divmod(cells, nx - 1)
        px, py, faces = _split_cells(i, j, k, (ny, nx), 20.0)
        s = np.arange(k + 1)
        row = (i[:, None, None] * k + s[None, :, None]) * ((nx - 1) * k + 1)
        key = (row + j[:, None, None] * k + s[None, None, :]).reshape(i.size, -1)
        branches.add(((ny - 1) * k + 1) * ((nx - 1) * k + 1) <= 8 * key.size)
        nodes, inv = np.unique(key, return_inverse=True)
        inv = inv.reshape(i.size, k + 1, k + 1)
        a, b, c, d = (inv[:, :-1, :-1].ravel(), inv[:, :-1, 1:].ravel(),
                      inv[:, 1:, :-1].ravel(), inv[:, 1:, 1:].ravel())
        want = np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
        assert faces.dtype == want.dtype and np.array_equal(faces, want)
        gy, gx = np.divmod(nodes, (nx - 1) * k + 1)
        assert np.array_equal(px, np.minimum(gx * (20.0 / k), (nx - 1) * 20.0))
        assert np.array_equal(py, np.minimum(gy * (20.0 / k), (ny - 1) * 20.0))
    assert branches == {True, False}


@pytest.mark.parametrize("posting_m", [20.0, 100.0])
def test_pixel_mesh_is_the_dem_within_its_tolerance(tmp_path, monkeypatch, posting_m):
    """Without roughness a corridor tile is the DEM's own pixels, split until each cell's
    triangles are within MESH_TOLERANCE_M of its bilinear surface (the bound |twist| / 4k^2
    is exact at the cell centre). Vertical rays at random points within the reach of tracks
    in four directions hit it everywhere, at the DEM's bilinear height to the tolerance plus
    the float32 rounding of the hit; a 10x tighter tolerance is met too (more splits); and
    the mesh has fewer triangles than a 1 m grid along the track (here 0.39 of them at 20 m
    posting and 0.14 at 100 m, where the undulations twist the cells; 0.01 on bench's
    smoother 100 m DEM)."""
    from lidar_mitsuba.trace import scene as scn
    d = dems.DEM.open(dems.synthetic_ice_sheet(tmp_path / "d.tif", posting_m=posting_m,
                                               width_m=8000.0, length_m=8000.0, hole=False))
    surf = dems.DEMSurface(d)
    cx, cy = surf.centre_xy_m()
    rng = np.random.default_rng(4)
    for tol in (1e-3, 1e-4):
        monkeypatch.setattr(dems, "MESH_TOLERANCE_M", tol)
        for az in (0.0, 30.0, 90.0, 137.0):
            t = np.arange(2048) * 0.7 - 700.0
            x = cx + t * np.cos(np.radians(az))
            y = cy + t * np.sin(np.radians(az))
            scene, (ox, oy), n_tri = surf.corridor_tile(x, y, reach_m=14.0, bsdf=None)
            k = rng.integers(0, x.size, 5000)
            r, phi = 13.9 * np.sqrt(rng.random(k.size)), rng.uniform(0, 2 * np.pi, k.size)
            px, py = x[k] + r * np.cos(phi), y[k] + r * np.sin(phi)
            z_hit, _ = scn.cast_down(scene, px - ox, py - oy)
            z_dem = surf.height_m(px, py)
            assert not np.isnan(z_hit).any()
            rounding = 2 * np.spacing(np.float32(np.abs(z_dem).max()))
            assert np.max(np.abs(z_hit - z_dem)) <= tol + rounding
            if tol == 1e-3 and az == 30.0:
                grid = dems.DEMSurface(d, mesh_grid_m=1.0).corridor_tile(
                    x, y, reach_m=14.0, bsdf=None)[2]
                assert n_tri < 0.5 * grid, (n_tri, grid)


def test_reference_elevation_is_the_exact_footprint_mean(tmp_path):
    """The footprint-weighted mean of the bilinear DEM, in closed form, against a fine
    quadrature (trapezoid on a 0.05 sigma grid over +-7 sigma: measured within ~1 um of the
    closed form here) at points along and across a 20 m DEM, within 0.02 mm. (The 7 x 7
    Gauss-Hermite rule it replaced missed by up to 0.7 mm here: the pixel creases are not
    smooth at the footprint's scale.) A point whose footprint reaches nodata is NaN."""
    path = dems.synthetic_ice_sheet(tmp_path / "d.tif", width_m=6000.0, length_m=6000.0)
    surf = dems.DEMSurface(dems.DEM.open(path))
    cx, cy = surf.centre_xy_m()
    rng = np.random.default_rng(8)
    x, y = cx + rng.uniform(-2500, 2500, 40), cy + rng.uniform(-2500, 2500, 40)
    sigma = 2.75
    u = np.arange(-7.0, 7.0 + 1e-9, 0.05)
    w = np.outer(np.exp(-0.5 * u ** 2), np.exp(-0.5 * u ** 2))
    w /= w.sum()
    fine = np.array([np.sum(w * surf.height_m(xi + sigma * u[None, :], yi + sigma * u[:, None]))
                     for xi, yi in zip(x, y)])
    got = surf.reference_elevation_m(x, y, sigma_m=sigma)
    ok = np.isfinite(fine)
    assert ok.sum() >= 30 and np.isfinite(got[ok]).all()
    assert np.max(np.abs(got[ok] - fine[ok])) < 2e-5
    gx, gy = np.meshgrid(cx + np.linspace(-2900, 2900, 150), cy + np.linspace(-2900, 2900, 150))
    hole = np.isnan(surf.height_m(gx.ravel(), gy.ravel()))          # over the nodata hole
    assert hole.any()
    assert np.isnan(surf.reference_elevation_m(gx.ravel()[hole], gy.ravel()[hole],
                                               sigma_m=sigma)).all()


def test_compiled_footprint_sums_and_finite_probes_are_the_numpy_expressions(tmp_path):
    """footprint_mean's stencil sums (a numba kernel) equal the numpy expression they replace
    bit for bit: the (m, n, n) weights and weighted heights, masked where a pixel is off the
    window or nodata, summed over axes (1, 2); stencils of 8 x 8 (the default footprint) and
    20 x 20 (above numpy's 128-value block) pixels, over the DEM's nodata hole and edges.
    And finite_at, fold's test, is heights_at's finiteness without its look-ups."""
    from lidar_mitsuba.ground.dem import heights
    path = dems.synthetic_ice_sheet(tmp_path / "d.tif", width_m=6000.0, length_m=6000.0)
    dem = dems.DEM.open(path)
    x0, x1, y0, y1 = dem.bounds_m
    g = np.linspace(0.0, 1.0, 90)
    x = (x0 - 30 + (x1 - x0 + 60) * g[:, None] + 0 * g[None, :]).ravel()
    y = (y0 - 30 + (y1 - y0 + 60) * g[None, :] + 0 * g[:, None]).ravel()
    for sigma in (2.5, 30.0):
        for s, z, (ox, oy) in dem.windows(x, y, pad_m=heights._stencil(dem.posting_m, sigma)[0],
                                          block=1000):
            if z is None:
                continue
            xs, ys = x[s], y[s]
            j0, a = heights._axis_weights(xs - ox, posting_m=dem.posting_m, sigma_m=sigma)
            i0, b = heights._axis_weights(ys - oy, posting_m=dem.posting_m, sigma_m=sigma)
            n = a.shape[1]
            ny, nx = z.shape
            ii, jj = i0[:, None] + np.arange(n), j0[:, None] + np.arange(n)
            on = ((ii >= 0) & (ii < ny))[:, :, None] & ((jj >= 0) & (jj < nx))[:, None, :]
            zz = z[np.clip(ii, 0, ny - 1)[:, :, None], np.clip(jj, 0, nx - 1)[:, None, :]]
            w = b[:, :, None] * a[:, None, :]
            good = on & np.isfinite(zz)
            present, total = np.empty(xs.size), np.empty(xs.size)
            heights._stencil_sums(z.astype(np.float64), i0, j0, a, b, present, total)
            np.testing.assert_array_equal(present, np.sum(np.where(good, w, 0.0), axis=(1, 2)))
            np.testing.assert_array_equal(
                total, np.sum(np.where(good, w * np.where(good, zz, 0.0), 0.0), axis=(1, 2)))
    probes = [(0, 0), (10, 0), (-10, 0), (0, 10), (0, -10)]
    ok = heights.finite_at(dem, x, y, probes, 1000)
    assert 0 < ok.sum() < ok.size
    np.testing.assert_array_equal(
        ok, np.isfinite(heights.heights_at(dem, x, y, probes, 1000)).all(axis=0))


def test_a_rewritten_dem_is_read_anew(tmp_path):
    """Window reads keep the GeoTIFF open (per thread and file version): writing another DEM
    to the same path gives the new heights, not the open file's."""
    path = tmp_path / "flat.tif"
    for level in (10.0, 20.0):
        dems.write_geotiff(path, np.full((20, 20), level), x0_m=500_000.0, y1_m=7_000_000.0,
                           posting_m=10.0, crs="EPSG:32624")
        surf = dems.DEMSurface(dems.DEM.open(path))
        cx, cy = surf.centre_xy_m()
        assert surf.height_m(cx, cy) == pytest.approx(level)


def test_windows_from_the_whole_dem_are_the_file_reads(dem_path, monkeypatch):
    """A small DEM is read whole once and its windows sliced from memory: the same float64
    windows (NaN over the nodata hole and off the DEM, bit for bit) and origins as rasterio's
    windowed and boundless reads, on windows inside, across the hole and over every edge."""
    dem = dems.DEM.open(dem_path)
    x0, x1, y0, y1 = dem.bounds_m
    rng = np.random.default_rng(7)
    boxes = [(x0 - 500, x0 + 800, y0 - 300, y0 + 900), (x1 - 700, x1 + 400, y1 - 50, y1 + 50),
             (x0 - 1e4, x0 - 9e3, y0, y0 + 100)]
    for _ in range(20):
        a, b = np.sort(rng.uniform(x0 - 300, x1 + 300, 2))
        c, d = np.sort(rng.uniform(y0 - 300, y1 + 300, 2))
        boxes.append((a, b, c, d))
    whole = [dem.read_window(*box) for box in boxes]
    monkeypatch.setattr(dems, "WHOLE_DEM_MAX_BYTES", 0)
    assert any(np.isnan(z).any() and np.isfinite(z).any() for z, _ in whole)
    for box, (z, origin) in zip(boxes, whole):
        zf, of = dem.read_window(*box)
        assert origin == of and z.dtype == zf.dtype and z.flags.c_contiguous
        np.testing.assert_array_equal(z, zf)


def test_roughness_has_no_wavelength_longer_than_the_posting():
    r = dems.roughness(p=1.8, relief_m=0.5, posting_m=16.0, grid_m=1.0, size_m=256.0)
    assert r.relief_m == pytest.approx(0.5)
    spec = np.abs(np.fft.fft2(r.z_m))
    f = np.hypot(*np.meshgrid(np.fft.fftfreq(256), np.fft.fftfreq(256)))
    assert spec[f < 1 / 16.0].max() < 1e-9 * spec.max()
    with pytest.raises(ParameterError, match="finer than the DEM posting"):
        dems.roughness(p=1.8, relief_m=0.5, posting_m=1.0, grid_m=2.0)


def test_track_over_nodata_is_refused_with_its_place(dem_path):
    """The test DEM's nodata square (its south-west kilometre): a track through it is refused
    before anything is traced, naming the track and where."""
    d = dems.DEM.open(dem_path)
    x0, _, y0, _ = d.bounds_m
    to_geo = Transformer.from_crs("EPSG:3413", "EPSG:4326", always_xy=True)
    lon, lat = to_geo.transform(x0 + 500.0, y0 + 100.0)
    az = Geod(ellps="WGS84").inv(lon, lat, *to_geo.transform(x0 + 500.0, y0 + 3000.0))[0]
    track = geotrack.GeoTrack(start_lat_deg=lat, start_lon_deg=lon, azimuth_deg=az)
    with pytest.raises(ParameterError, match="nodata") as e:
        granule.simulate_granule(surface=dems.DEMSurface(d), track=track, shots=2000,
                                 beams="gt2l", progress=False, max_depth=1)
    assert e.value.name == "track" and "gt2l" in e.value.message


# --------------------------------------------------------------------------- orbit geometry
def test_beam_layout_follows_the_spacecraft_orientation():
    back = {b.name: b for b in geotrack.beam_layout(0)}
    fwd = {b.name: b for b in geotrack.beam_layout(1)}
    assert [back[n].spot for n in ("gt1l", "gt1r", "gt2l", "gt2r", "gt3l", "gt3r")] == [1, 2, 3, 4, 5, 6]
    assert [fwd[n].spot for n in ("gt1l", "gt1r", "gt2l", "gt2r", "gt3l", "gt3r")] == [6, 5, 4, 3, 2, 1]
    assert all(back[n].strength == "strong" for n in ("gt1l", "gt2l", "gt3l"))
    assert all(fwd[n].strength == "strong" for n in ("gt1r", "gt2r", "gt3r"))
    assert back["gt1l"].across_m - back["gt1r"].across_m == pytest.approx(90.0)
    assert back["gt1l"].across_m - back["gt2l"].across_m == pytest.approx(3300.0)
    assert [b.name for b in geotrack.select_beams("weak", 0)] == ["gt1r", "gt2r", "gt3r"]
    with pytest.raises(ParameterError, match="unknown beam"):
        geotrack.select_beams("gt4l")


def test_track_shots_are_spaced_along_the_geodesic_and_beams_across_it():
    """Consecutive shots are 0.7 m apart on the ellipsoid (pyproj's geodesic inverse, an
    independent computation), polyline tracks turn at their vertices, and each beam lies its
    across-track offset from the reference track."""
    geod = Geod(ellps="WGS84")
    lat, lon, az, along = TRACK.shots(3000, spacing_m=0.7)
    _, _, d = geod.inv(lon[:-1], lat[:-1], lon[1:], lat[1:])
    np.testing.assert_allclose(d, 0.7, atol=1e-6)
    for beam in geotrack.beam_layout(0):
        blat, blon = geotrack.beam_shots(lat, lon, az, beam)
        _, _, dist = geod.inv(lon, lat, blon, blat)
        np.testing.assert_allclose(dist, abs(beam.across_m), rtol=1e-9)
    # a polyline: 1 km north, then 1 km east
    lon1, lat1, _ = geod.fwd(-45.0, 70.0, 0.0, 1000.0)
    lon2, lat2, _ = geod.fwd(lon1, lat1, 90.0, 1000.0)
    poly = geotrack.GeoTrack(polyline=((70.0, -45.0), (lat1, lon1), (lat2, lon2)))
    plat, plon, paz, palong = poly.shots(2001, spacing_m=1.0)
    assert paz[500] == pytest.approx(0.0, abs=1e-6) and paz[1500] == pytest.approx(90.0, abs=0.05)
    np.testing.assert_allclose([plat[-1], plon[-1]], [lat2, lon2], atol=1e-9)
    with pytest.raises(ParameterError, match="past the end"):
        poly.shots(3000, spacing_m=1.0)


def test_track_file_and_delta_time(tmp_path):
    f = tmp_path / "rgt.csv"
    f.write_text("lat,lon\n70.0,-45.0\n70.1,-45.0\n")
    t = geotrack.GeoTrack.parse(str(f), epoch_utc="2018-01-02T00:00:00Z")
    assert t.polyline == ((70.0, -45.0), (70.1, -45.0))
    dt = geotrack.delta_time_s(t.epoch_utc, 3, prf_hz=1e4)
    np.testing.assert_allclose(dt, 86400.0 + np.array([0, 1e-4, 2e-4]))
    with pytest.raises(ParameterError, match="LAT,LON,AZIMUTH"):
        geotrack.GeoTrack.parse("70,-45")


# --------------------------------------------------------------------------- the granule
def test_photons_lie_on_the_dem_at_their_geolocation(six_beams, dem_path):
    """Done-when of issue 13: every signal photon's (lat_ph, lon_ph, h_ph) matches the DEM at
    that point within the pulse spread. The DEM is read here independently (rasterio, the
    file's own pixels, bilinear) at the photon's lat/lon projected to EPSG:3413; a photon
    scatters within its footprint, so the expected spread of h_ph - DEM is the pulse's
    (c sigma_t / 2, 0.064 m) and the surface's within the footprint (slope 0.5 % and the
    undulations: < 0.02 m over sigma = 3.5 m). Each photon must lie within 6 sigma of that
    spread, and the mean offset (strong beams, ~1e4 photons, standard error ~1 mm) within
    1 cm (the first-photon bias of the dead time is ~0.5 cm)."""
    import rasterio
    g, atl03, _ = six_beams
    to_crs = Transformer.from_crs("EPSG:4326", "EPSG:3413", always_xy=True)
    with rasterio.open(dem_path) as ds, h5py.File(atl03, "r") as f:
        z = ds.read(1).astype(np.float64)
        tr = ds.transform
        for r in g.beams:
            h = f[f"{r.beam.name}/heights"]
            sig = f[f"truth/{r.beam.name}/photons/is_signal"][()] == 1
            x, y = to_crs.transform(h["lon_ph"][()][sig], h["lat_ph"][()][sig])
            col = (np.asarray(x) - tr.c) / tr.a         # pixel coordinates (corner origin)
            row = (np.asarray(y) - tr.f) / tr.e
            c, rr = col - 0.5, row - 0.5
            i, j = np.floor(rr).astype(int), np.floor(c).astype(int)
            tx, ty = c - j, rr - i
            zd = ((1 - ty) * ((1 - tx) * z[i, j] + tx * z[i, j + 1])
                  + ty * ((1 - tx) * z[i + 1, j] + tx * z[i + 1, j + 1]))
            dh = h["h_ph"][()][sig] - zd
            inst = r.result.instrument
            spread = np.hypot(inst.pulse_sigma_ns * C_M_PER_NS / 2, 0.02)
            assert np.all(np.abs(dh) < 6 * spread), (r.beam.name, np.abs(dh).max())
            assert abs(dh.mean()) < 0.01, (r.beam.name, dh.mean())
            assert sig.sum() > 0.5 * r.result.n_shots


def test_atl03_fields_names_dtypes_and_geolocation_segments(six_beams):
    g, atl03, _ = six_beams
    with h5py.File(atl03, "r") as f:
        assert f["orbit_info/sc_orient"][0] == 0
        assert f["ancillary_data/atlas_sdp_gps_epoch"][0] == 1198800018.0
        for r in g.beams:
            gt = f[r.beam.name]
            assert gt.attrs["atlas_beam_type"] == r.beam.strength
            assert gt.attrs["atlas_spot_number"] == str(r.beam.spot)
            assert gt.attrs["groundtrack_id"] == r.beam.name
            h, geo = gt["heights"], gt["geolocation"]
            n = h["h_ph"].shape[0]
            assert h["h_ph"].dtype == np.float32 and h["lat_ph"].dtype == np.float64
            assert h["signal_conf_ph"].shape == (n, 5) and h["signal_conf_ph"].dtype == np.int8
            assert h["delta_time"].attrs["units"] == "seconds since 2018-01-01"
            pulse = h["ph_id_pulse"][()]
            assert pulse.min() >= 1 and pulse.max() <= 200
            ch = h["ph_id_channel"][()]
            assert (ch.min(), ch.max()) == ((1, 16) if r.beam.strength == "strong" else (17, 20))
            # the segments partition the photons: counts add up, each segment's photons are
            # contiguous from ph_index_beg, and lie within its 20 m
            cnt, beg = geo["segment_ph_cnt"][()], geo["ph_index_beg"][()]
            assert cnt.sum() == n
            full = cnt > 0
            np.testing.assert_array_equal(beg[full][1:], (beg[full] + cnt[full])[:-1])
            along = h["dist_ph_along"][()]
            assert along.min() >= 0 and along.max() <= 20.0    # (float32 of 19.99999...)
            seg = np.repeat(np.arange(cnt.size), cnt)
            x = geo["segment_dist_x"][()][seg] + along
            np.testing.assert_allclose(x, r.result.along_track_m[f[f"truth/{r.beam.name}/photons/shot"][()]],
                                       atol=1e-3)
            # 2019-06-01 is 516 days after the SDP epoch
            assert h["delta_time"][0] == pytest.approx(516 * 86400.0, abs=1.0)


def test_third_party_readers_read_our_granules(six_beams):
    """read-ICESat-2 (icesat2-toolkit, from PyPI) reads both files with its ATL03 and ATL06
    granule readers, and xarray (h5netcdf engine) opens the beam groups, as users do with
    real granules; what they read equals what we wrote."""
    from icesat2_toolkit.io import ATL03, ATL06
    import xarray as xr
    g, atl03, atl06 = six_beams
    names = [r.beam.name for r in g.beams]
    mds, attrs, beams = ATL03.read_granule(atl03, ATTRIBUTES=True)
    assert sorted(beams) == sorted(names)
    m6, a6, b6 = ATL06.read_granule(atl06, ATTRIBUTES=True)
    assert sorted(b6) == sorted(names)
    for r in g.beams:
        order = np.argsort(r.result.detections.shot, kind="stable")
        np.testing.assert_array_equal(mds[r.beam.name]["heights"]["h_ph"],
                                      r.result.h_m[order].astype(np.float32))
        assert attrs[r.beam.name]["atlas_beam_type"] == r.beam.strength
        h_li = m6[r.beam.name]["land_ice_segments"]["h_li"]
        good = m6[r.beam.name]["land_ice_segments"]["atl06_quality_summary"] == 0
        assert good.sum() > 0.8 * good.size
        ds = xr.open_dataset(atl03, group=f"{r.beam.name}/heights", engine="h5netcdf",
                             phony_dims="access")
        assert ds["h_ph"].size == mds[r.beam.name]["heights"]["h_ph"].size
        assert str(ds["delta_time"].values[0])[:10] == "2019-06-01"
        ds6 = xr.open_dataset(atl06, group=f"{r.beam.name}/land_ice_segments",
                              engine="h5netcdf", phony_dims="access")
        np.testing.assert_array_equal(ds6["h_li"].values[good], h_li[good])
        # ATL06 heights follow the DEM: against the segments' truth (h_ref) within 5 cm
        href = m6[r.beam.name]["land_ice_segments"]["dem"]["h_ref_m"]
        assert np.abs(h_li[good] - href[good]).max() < 0.05
    # both carry a real granule's METADATA (issue 44): the release icepyx parses (001 for a
    # name without one), the file name, an extent holding every position, and "simulated"
    # with the run's configuration where provenance is read
    for path, group in ((atl03, "heights/lat_ph"), (atl06, "land_ice_segments/latitude")):
        with h5py.File(path, "r") as f:
            d = f["METADATA/DatasetIdentification"].attrs
            assert (d["shortName"], d["VersionID"], d["fileName"]) == (
                path.name[:5].encode(), b"001", path.name.encode())
            lat = np.concatenate([f[f"{n}/{group}"][()] for n in names])
            e = f["METADATA/Extent"].attrs
            assert e["southBoundLatitude"] <= lat.min() <= lat.max() <= e["northBoundLatitude"]
            assert f["METADATA/ProcessStep/PGE"].attrs["processDescription"].startswith(
                b"SIMULATED DATA")
            assert f["METADATA/Lineage/SIM"].attrs["runTimeParameters"].decode() == \
                f.attrs["config"]


def test_tiling_changes_no_truth_and_no_statistic(dem_path):
    """Streaming is an implementation detail. The truth per shot (surface height, reference
    elevation) does not depend on the tile size (to rounding: the DEM windows differ), and a
    track traced as one tile or as four gives the same bias and photon rate within their
    Monte Carlo errors (4 combined standard errors; the tilings draw different random
    streams, so the photons themselves differ)."""
    d = dems.DEM.open(dem_path)
    out = []
    for tile in (2000, 500):
        surf = dems.DEMSurface(d, tile_shots=tile)
        g = granule.simulate_granule(surface=surf, track=TRACK, shots=2000, beams="gt2l",
                                     seed=1, progress=False, max_depth=1)
        out.append(g.beams[0].result)
    a, b = out
    assert a.config["surface"]["tiles"] == 1 and b.config["surface"]["tiles"] == 4
    np.testing.assert_allclose(a.z_ref_m, b.z_ref_m, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.surface_z_m, b.surface_z_m, rtol=0, atol=1e-9)
    ra, rb = a.report().overall, b.report().overall
    assert abs(ra.bias_m - rb.bias_m) < 4 * np.hypot(ra.bias_se_m, rb.bias_se_m)
    na, nb = ra.n_photons, rb.n_photons
    assert abs(na - nb) < 4 * np.sqrt(na + nb)


def test_cli_granule_and_its_errors(dem_path, tmp_path, capsys):
    """The command in its own process; its refusals in this one (tests/cli_checks.py: one
    line naming the option, exit 2, no traceback; a process each cost seconds of start-up)."""
    exe = [sys.executable, "-m", "lidar_mitsuba_cli", "simulate"]
    out, a6, png = tmp_path / "ATL03.h5", tmp_path / "ATL06.h5", tmp_path / "cloud.png"
    p = subprocess.run(exe + ["--dem", str(dem_path), "--track", "69.97,-45,0", "--beams",
                              "gt2l,gt2r", "--shots", "800", "--out", str(out), "--atl06",
                              str(a6), "--plot", str(png), "--no-progress"],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert "gt2l" in p.stdout and out.exists() and a6.exists() and png.stat().st_size > 0
    with h5py.File(out, "r") as f:
        assert sorted(k for k in f if k.startswith("gt")) == ["gt2l", "gt2r"]
        assert json.loads(f.attrs["config"])["beams"] == ["gt2l", "gt2r"]
    for args, option in ((["--track", "69.97,-45"], "--track"),
                         (["--track", "69.97,-45,0", "--beams", "gt7"], "--beams"),
                         (["--track", "69.97,-45,0", "--surface", "flat"], "--surface"),
                         (["--track", "80,-45,0"], "--track"),
                         (["--track", "69.97,-45,0", "--epoch", "soon"], "--epoch"),
                         (["--track", "69.97,-45,0", "--beam", "weak"], "--beam")):
        bad = tmp_path / "bad.h5"
        err = bad_call(["simulate", "--dem", str(dem_path), "--shots", "50", "--out", str(bad),
                        "--no-progress"] + args, capsys)
        assert f"error: {option}:" in err and not bad.exists(), (args, err)
    err = bad_call(["simulate", "--track", "69.97,-45,0", "--out", str(tmp_path / "b.h5")],
                   capsys)
    assert "--track: only applies to --dem" in err


def test_streamed_granule_sections_join_exactly(dem_path, tmp_path):
    """A granule streamed in four sections: the ATL03 geolocation indices run on across the
    sections (segment ids 1..n with no gap or repeat, ph_index_beg continuing the photon
    count, global shot numbers), and the streamed ATL06 segments, fitted section by section
    with a 40 m tail, equal a fit of the whole track's photons read back from the file (the
    same photons: every segment is fitted once, with all its photons, on the same grid)."""
    from lidar_mitsuba.products import atl06
    surf = dems.DEMSurface(dems.DEM.open(dem_path), tile_shots=512)
    a3, a6 = tmp_path / "s3.h5", tmp_path / "s6.h5"
    out = granule.stream_granule(surface=surf, track=TRACK, shots=2400, beams="gt2l,gt2r",
                                 atl03_path=a3, atl06_path=a6, seed=5, progress=False,
                                 max_depth=1, section_shots=700)
    assert [s.shots for s in out] == [2400, 2400]
    assert granule.section_bounds(2400, spacing_m=0.7, section_shots=700)[1][0] == 686
    with h5py.File(a3, "r") as f3, h5py.File(a6, "r") as f6:
        assert json.loads(f3.attrs["config"])["sections"] == 4
        for s in out:
            name = s.beam.name
            geo, t = f3[f"{name}/geolocation"], f3[f"truth/{name}"]
            sid = geo["segment_id"][()]
            np.testing.assert_array_equal(sid, np.arange(1, sid.size + 1))
            assert sid.size == int(np.floor(2399 * 0.7 / 20)) + 1
            cnt, beg = geo["segment_ph_cnt"][()], geo["ph_index_beg"][()]
            full = cnt > 0
            np.testing.assert_array_equal(beg[full], np.cumsum(cnt)[full] - cnt[full] + 1)
            shot = t["photons/shot"][()]
            assert np.all(np.diff(shot) >= 0) and shot.max() > 1700
            sig = t["photons/is_signal"][()] == 1
            assert sig.sum() == s.photons
            along = t["shots/along_track_m"][()]
            zref = t["shots/z_ref_m"][()]
            inst = granule.Instrument(beam=s.beam.strength)
            whole = atl06.fit_segments(
                photon_along_m=along[shot], h_m=t["photons/h_m"][()], shot=shot,
                channel=t["photons/channel"][()], n_shots=along.size, shot_along_m=along,
                n_channels=inst.channels, dead_time_ns=inst.effective_dead_time_ns,
                paralyzable=inst.paralyzable, pulse_sigma_ns=inst.pulse_sigma_ns,
                range_gate_m=inst.range_gate_m, z_ref_m=zref, gate_center_h_m=zref,
                footprint_sigma_m=inst.footprint_sigma_m)
            li = f6[f"{name}/land_ice_segments"]
            np.testing.assert_array_equal(li["segment_id"][()], whole.segment_id)
            np.testing.assert_array_equal(li["h_li"][()], np.where(
                np.isfinite(whole.h_li), whole.h_li, np.finfo(np.float32).max).astype(np.float32))
            np.testing.assert_array_equal(li["fit_statistics/n_fit_photons"][()],
                                          whole.n_fit_photons)


def test_a_failed_fit_leaves_neither_file(dem_path, tmp_path, monkeypatch):
    """The ATL06 fits run on a thread of their own beside the simulation: a fit that fails
    (here the third) stops the granule with its error, and neither file is left (written
    in this process, where the failing fit is patched in)."""
    from lidar_mitsuba import granule_products
    calls = []
    real = granule_products._SegmentStream.fit

    def failing(self, run, *, last):
        calls.append(run.beam.name)
        if len(calls) == 3:
            raise RuntimeError("fit failed")
        return real(self, run, last=last)
    monkeypatch.setattr(granule_products._SegmentStream, "fit", failing)
    surf = dems.DEMSurface(dems.DEM.open(dem_path), tile_shots=512)
    a3, a6 = tmp_path / "f3.h5", tmp_path / "f6.h5"
    with pytest.raises(RuntimeError, match="fit failed"):
        granule.stream_granule(surface=surf, track=TRACK, shots=2400, beams="gt2l,gt2r",
                               atl03_path=a3, atl06_path=a6, seed=5, progress=False,
                               max_depth=1, section_shots=700, writer="inline")
    assert len(calls) >= 3        # (a fit already under way may finish first)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def _h5_objects(path) -> dict:
    """Every group and dataset of an HDF5 file: its attributes and, for a dataset, dtype,
    shape, chunks, filters, fill value and bytes (object references as the names they name)."""
    out, names = {}, {}
    with h5py.File(path, "r") as f:
        def address(obj):
            names[h5py.h5o.get_info(obj.id).addr] = obj.name
        f.visititems(lambda _, obj: address(obj))

        def named(ref):       # (h5py's name of an object opened by reference searches the
            return names[h5py.h5o.get_info(h5py.h5r.dereference(ref, f.id)).addr]  # file)

        def attrs(obj):
            return {k: repr([[named(r) for r in row] for row in v] if k == "DIMENSION_LIST"
                            else [(named(r), int(i)) for r, i in v] if k == "REFERENCE_LIST"
                            else v) for k, v in obj.attrs.items()}

        def visit(name, obj):
            if isinstance(obj, h5py.Dataset):
                out[name] = (attrs(obj), obj.dtype.str, obj.shape, obj.chunks, obj.compression,
                             obj.compression_opts, obj.shuffle, repr(obj.fillvalue),
                             obj[()].tobytes())
            else:
                out[name] = attrs(obj)
        f.visititems(visit)
        out["/"] = attrs(f)
    return out


#: a fresh process that starts its writer as ``simulate --dem`` does (forked: right after
#: the imports, before the renderer) and streams :func:`test_the_writer_process_writes_the_same
#: _files_and_reports_failures`' granule into ``folder``/forked (argv: the DEM, the folder),
#: then one whose ATL06 path it cannot create, into ``folder``/forked_bad
_FORKED = """
import json, pathlib, sys
from lidar_mitsuba import geotrack, granule, granule_writer
w = granule_writer.writer("process")
from lidar_mitsuba.ground import dem as dems
folder = pathlib.Path(sys.argv[2])
kw = dict(surface=dems.DEMSurface(dems.DEM.open(sys.argv[1]), tile_shots=512),
          track=geotrack.GeoTrack(start_lat_deg=69.97, start_lon_deg=-45.0, azimuth_deg=0.0),
          shots=400, beams="gt2l,gt3r", seed=5, progress=False, max_depth=1,
          paths_per_shot=16, section_shots=200, writer="process")
for name in ("forked", "forked_bad"):
    (folder / name).mkdir()
granule.stream_granule(**kw, atl03_path=folder / "forked" / "a3.h5",
                       atl06_path=folder / "forked" / "a6.h5")
try:
    granule.stream_granule(**kw, atl03_path=folder / "forked_bad" / "a3.h5",
                           atl06_path=folder / "missing" / "a6.h5")
    error = ""
except Exception as e:
    error = str(e)
print(json.dumps({"forked": w.forked, "refusal": w.refusal, "error": "missing" in error,
                  "left": sorted(p.name for p in (folder / "forked_bad").iterdir()),
                  "reused": granule_writer._WRITER[0] is w and w.alive()}))
"""


def test_the_writer_process_writes_the_same_files_and_reports_failures(dem_path, tmp_path):
    """A granule written by the writer process (the default) and in the simulating thread:
    the same objects, attributes, dataset bytes, dtypes, chunks, filters and fill values;
    and by a writer process forked from a fresh process (as ``simulate --dem`` starts it:
    it must have forked, in a process of its own beside this test's, started first).
    A failure in the writer (an ATL06 path it cannot create) stops the granule with its
    error and leaves no file, and the same process writes the next granule (forked or not)."""
    (tmp_path / "forked.py").write_text(_FORKED)
    forked = subprocess.Popen([sys.executable, str(tmp_path / "forked.py"), str(dem_path),
                               str(tmp_path)], stdout=subprocess.PIPE, text=True)
    surf = dems.DEMSurface(dems.DEM.open(dem_path), tile_shots=512)
    kw = dict(surface=surf, track=TRACK, shots=400, beams="gt2l,gt3r", seed=5,
              progress=False, max_depth=1, paths_per_shot=16, section_shots=200)
    for mode in ("inline", "process"):
        (tmp_path / mode).mkdir()
        granule.stream_granule(**kw, atl03_path=tmp_path / mode / "a3.h5",
                               atl06_path=tmp_path / mode / "a6.h5", writer=mode)
    assert json.loads(forked.communicate(timeout=120)[0].splitlines()[-1]) == {
        "forked": True, "refusal": None, "error": True, "left": [], "reused": True}
    for name in ("a3.h5", "a6.h5"):
        a, b, c = (_h5_objects(tmp_path / m / name) for m in ("inline", "process", "forked"))
        assert a.keys() == b.keys() == c.keys() and len(a) > 100
        assert [k for k in a if a[k] != b[k]] == []
        assert [k for k in a if a[k] != c[k]] == []
        if name == "a3.h5":
            h_ph = a["gt2l/heights/h_ph"]
            assert h_ph[2][0] > 1000          # (its shape: photons were written)
    (tmp_path / "bad").mkdir()
    with pytest.raises(Exception, match="missing"):
        granule.stream_granule(**kw, atl03_path=tmp_path / "bad" / "a3.h5",
                               atl06_path=tmp_path / "missing" / "a6.h5", writer="process")
    assert list((tmp_path / "bad").iterdir()) == []
    granule.stream_granule(**kw, atl03_path=tmp_path / "bad" / "a3.h5", writer="process")
    assert _h5_objects(tmp_path / "bad" / "a3.h5")["gt2l/heights/h_ph"] == \
        _h5_objects(tmp_path / "inline" / "a3.h5")["gt2l/heights/h_ph"]


def test_the_writer_is_not_forked_beside_another_thread():
    """A writer process is forked only where nothing makes a fork unsafe: with another
    thread alive (as in a Dask worker) it is a fresh interpreter instead, which serves the
    same pipes; the refusal names the thread (and, in this process, Dr.Jit)."""
    from lidar_mitsuba import forking, granule_writer
    stop = threading.Event()
    other = threading.Thread(target=stop.wait, name="another-thread", daemon=True)
    other.start()
    try:
        w = granule_writer.WriterProcess()
        try:
            assert not w.forked and "another-thread" in w.refusal
            assert "Dr.Jit" in w.refusal and w.alive()
            assert w.proc.args[1:3] == ["-m", "lidar_mitsuba.granule_writer"]
        finally:
            w.proc.terminate()           # (not waiting for its imports)
            w.stop()
    finally:
        stop.set()
        other.join()
    assert "another-thread" not in (forking.refusal() or "")


def test_groups_from_templates_write_the_same_files(six_beams, tmp_path, monkeypatch):
    """ATL03 and ATL06 of two beams of a granule with every beam's groups copied from
    templates (products.h5template, the default: the second beam's from the first's) and
    with every object made in place: the same objects, attributes, dataset bytes, dtypes,
    chunks, filters and fill values."""
    from dataclasses import replace
    from lidar_mitsuba.products import h5template
    g = replace(six_beams[0], beams=six_beams[0].beams[:2])
    for templates in (False, True):
        monkeypatch.setattr(h5template, "TEMPLATES", templates)
        (tmp_path / str(templates)).mkdir()
        granule.write_atl03(g, tmp_path / str(templates) / "ATL03_sim.h5")
        granule.write_atl06(g, tmp_path / str(templates) / "ATL06_sim.h5")
    for name in ("ATL03_sim.h5", "ATL06_sim.h5"):
        a, b = (_h5_objects(tmp_path / str(m) / name) for m in (False, True))
        assert a.keys() == b.keys() and len(a) > 100
        assert [k for k in a if a[k] != b[k]] == []


def test_the_atl03_writer_reuses_simulate_s_histogram_test(six_beams):
    """The histogram test runs once: ATL03's writer takes the one that gave the run's
    signal_conf (the same object), which equals the test run afresh on the section; a result
    whose signal_conf was replaced has the test run again."""
    from dataclasses import replace
    from lidar_mitsuba.products import classify
    from lidar_mitsuba.products.atl03 import beam as atl03_beam
    run = six_beams[0].beams[0]
    res = run.result
    s = atl03_beam._Section(run, 0)
    assert res.signal_test.conf is res.signal_conf and s.test is res.signal_test
    fresh = classify.histogram_test(shot=res.detections.shot, h_m=res.h_m,
                                    gate_center_h_m=s.gate, range_gate_m=res.instrument.range_gate_m)
    for name in ("conf", "tail_p", "noise_per_bin"):
        np.testing.assert_array_equal(getattr(s.test, name), getattr(fresh, name))
    other = atl03_beam._Section(replace(run, result=replace(res, signal_conf=res.signal_conf.copy())), 0)
    assert other.test is not res.signal_test
    np.testing.assert_array_equal(other.test.tail_p, fresh.tail_p)


def test_trace_threads_narrows_dr_jit_s_pool_and_restores_it():
    """A granule's sections run with Dr.Jit's pool one thread short (at least one), the host
    pool keeping its count; nested scopes keep the outer one's; the count comes back after."""
    import drjit as dr
    from lidar_mitsuba import machine
    from lidar_mitsuba.trace.variant import ensure_renderer
    ensure_renderer()
    before = dr.thread_count()
    with machine.trace_threads(keep=1):
        assert dr.thread_count() == max(1, before - 1)
        assert machine.host_threads() == before
        with machine.trace_threads(keep=5):
            assert dr.thread_count() == max(1, before - 1)
    assert dr.thread_count() == before and machine.host_threads() == before


def test_make_dem_writes_a_dem_that_opens_and_refuses_bad_sizes(tmp_path, capsys):
    exe = [sys.executable, "-m", "lidar_mitsuba_cli", "make-dem"]
    out = tmp_path / "d.tif"
    p = subprocess.run(exe + ["--out", str(out), "--width-m", "2000", "--length-m", "3000",
                              "--posting-m", "25", "--no-hole"], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    d = dems.DEM.open(out)
    assert d.crs.to_epsg() == 3413 and (d.width, d.height) == (81, 121)
    surf = dems.DEMSurface(d)
    x0, x1, y0, y1 = d.bounds_m
    xs, ys = np.meshgrid(np.linspace(x0, x1, 7), np.linspace(y0, y1, 7))
    assert np.isfinite(surf.height_m(xs, ys)).all()          # no hole asked for
    for args, option in ((["--posting-m", "0"], "--posting-m"), (["--lat", "89"], "--lat"),
                         (["--width-m", "1e9"], "--width-m")):
        bad = tmp_path / "bad.tif"           # (in process: tests/cli_checks.py)
        err = bad_call(["make-dem", "--out", str(bad)] + args, capsys)
        assert f"error: {option}:" in err and not bad.exists()


def test_a_corridor_tile_from_its_prepared_mesh_is_the_tile(dem_path):
    """A granule's stream makes the next corridor tile's mesh on its own thread
    (:meth:`~lidar_mitsuba.ground.dem.CorridorTiles.prepare`) and the trace launcher loads
    it: the tile is the one built from the shots alone, buffer for buffer (vertices, faces,
    the shots' local positions and offsets), for the pixel mesh and the grid mesh."""
    from lidar_mitsuba.ground.brdf import ward_bsdf_dict
    d = dems.DEM.open(dem_path)
    for surf in (dems.DEMSurface(d), dems.DEMSurface(d, mesh_grid_m=2.0)):
        cx, cy = surf.centre_xy_m()
        t = np.arange(600) * 0.7 - 200.0
        x, y = cx + 0.3 * t, cy + t
        tiles = dems.CorridorTiles(surf, x, y, reach_m=14.0, bsdf=ward_bsdf_dict(),
                                   chunk_shots=200)
        mesh = tiles.prepare(200, 400)
        ahead, plain = tiles.tile(200, 400, mesh), tiles.tile(200, 400)
        assert ahead[0] is not plain[0]
        for a, b in zip(ahead[1:3] + ahead[3], plain[1:3] + plain[3]):
            np.testing.assert_array_equal(a, b)
        (ma,), (mb,) = ahead[0].shapes(), plain[0].shapes()
        for buf in ("vertex_positions_buffer", "faces_buffer"):
            np.testing.assert_array_equal(getattr(ma, buf)().numpy(), getattr(mb, buf)().numpy())
        assert ma.vertex_count() > 100 and ma.face_count() == mb.face_count()
    assert tiles.stats()["tiles"] == 2
