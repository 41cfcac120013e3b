"""The ATL08-like product (issue 42): our photon classifier on synthetic photon clouds with a
closed-form truth, the 100 m segments, and the file laid out as the real ATL08 clip is (names,
dtypes, trailing shapes, fill values), opened by the readers that open the real one."""
from __future__ import annotations

import math
import pathlib

import h5py
import numpy as np
import pytest

from lidar_mitsuba.products import atl08
from lidar_mitsuba.products.atl08 import classify as C, fields

REAL_DIR = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "real"
"""The real files beside the repository (as tests/test_realism.py finds them)."""
REAL_ATL08 = REAL_DIR / "ATL08_gt1r_20220401_forest_wyoming.h5"
REAL_ATL03 = REAL_DIR / "ATL03_gt1r_20220401_forest_wyoming.h5"
have_real = pytest.mark.skipif(not REAL_ATL08.exists(),
                               reason="the real forest clip is not on this machine")

SHOT_M = 0.7            # ATLAS's along-track shot spacing [m]


def cloud(*, seed: int, length_m: float = 800.0, slope: float = 0.1, mu_ground: float = 0.3,
          mu_canopy: float = 0.8, canopy_lo_m: float = 0.0, canopy_top_m: float = 15.0,
          rho_per_m2: float = 0.04, band_m: float = 150.0, sigma_ground_m: float = 0.1,
          canopy_mean_m: float | None = None):
    """A photon cloud with a closed-form truth: ground ``h = 100 + slope x`` returning
    Poisson(``mu_ground``) photons a shot with normal scatter ``sigma_ground_m``; canopy
    Poisson(``mu_canopy``) photons a shot uniform between ``canopy_lo_m`` and
    ``canopy_top_m`` above the ground (or, with ``canopy_mean_m``, ``canopy_lo_m`` plus an
    exponential of that mean: a dense understorey thinning upwards); background of ``rho_per_m2`` per m along track per m
    of height, uniform over +-``band_m`` about the ground. Returns ``(x, h, label)`` with
    label 0 background, 1 ground, 2 canopy."""
    rng = np.random.default_rng(seed)
    xs = np.arange(0.0, length_m, SHOT_M)
    xg = np.repeat(xs, rng.poisson(mu_ground, xs.size))
    xc = np.repeat(xs, rng.poisson(mu_canopy, xs.size))
    hg = 100 + slope * xg + rng.normal(0, sigma_ground_m, xg.size)
    hc = 100 + slope * xc + (rng.uniform(canopy_lo_m, canopy_top_m, xc.size)
                             if canopy_mean_m is None else
                             canopy_lo_m + rng.exponential(canopy_mean_m, xc.size))
    nb = rng.poisson(rho_per_m2 * length_m * 2 * band_m)
    xb = rng.uniform(0, length_m, nb)
    hb = 100 + slope * xb + rng.uniform(-band_m, band_m, nb)
    label = np.r_[np.ones(xg.size), np.full(xc.size, 2), np.zeros(nb)].astype(int)
    return np.r_[xg, xc, xb], np.r_[hg, hc, hb], label


@pytest.mark.parametrize("slope,mu_ground,mu_canopy,lo,rho", [
    (0.0, 0.3, 0.8, 0.0, 0.04),         # flat, open stand, 4 MHz background
    (0.2, 0.3, 0.8, 0.0, 0.04),         # 20 % slope
    # dense crowns from 3 m, little ground through them, the forest clip's ~1.9 MHz by day
    # (at 4 MHz this stand's ground is lost: a known limit, docs/guide/atl08.md)
    (0.1, 0.15, 1.0, 3.0, 0.018),
])
def test_classifier_finds_the_ground_and_the_canopy_top(slope, mu_ground, mu_canopy, lo, rho):
    """Ground surface and RH98 against the closed-form truth. Tolerances from the sample:
    the ground surface is a smoothing spline through n ~ 100-400 ground photons with scatter
    0.1 m, and the background that passes the filter within the ground buffer adds uniform
    scatter of +-buffer; its median error over the track must be within 0.15 m (the
    0.1 m scatter, plus what a lower envelope's first pick can leave). RH98 of the canopy
    photons above the ground: the truth for uniform canopy is lo + 0.98 (top - lo); its
    sampling error over N ~ 700 photons is sqrt(p(1-p)/N) / density ~ (top-lo)
    sqrt(0.0196 / N) ~ 0.08 m; background inside the canopy band (indistinguishable,
    uniform over it) leaves the percentile of a uniform unchanged, while background just
    above the top that passes the filter biases it up: allowed 0.5 m (~6 sigma)."""
    top = 15.0
    x, h, lab = cloud(seed=3, slope=slope, mu_ground=mu_ground, mu_canopy=mu_canopy,
                      canopy_lo_m=lo, canopy_top_m=top, rho_per_m2=rho)
    c = C.classify_photons(x_m=x, h_m=h, background_per_m2=rho)
    truth = 100 + slope * x
    assert abs(np.nanmedian(c.ground_h_m - truth)) < 0.15
    # more than half the true ground photons are classed ground (measured 0.53-0.99: the
    # noise filter drops stretches of sparse ground), and few background ones are
    assert np.mean(c.classes[lab == 1] == C.GROUND) > 0.5
    assert np.mean(c.classes[lab == 0] == C.GROUND) < 0.01
    rel = (h - truth)[(c.classes == C.CANOPY) | (c.classes == C.TOP_OF_CANOPY)]
    rh98_true = lo + 0.98 * (top - lo)
    assert abs(np.percentile(rel, 98) - rh98_true) < 0.5


@pytest.mark.parametrize("seed", [11, 12])
def test_sparse_ground_under_a_dense_understorey(seed):
    """Sparse ground (0.3 photons a shot, scatter 0.15 m: ATLAS's 0.1 m pulse with some
    roughness) under vegetation beginning 0.5 m above it and densest there (0.8 photons a shot,
    exponential heights of mean 2 m: 0.46 photons a shot per metre of height at its base, more
    than the ground's 0.3 spread over its +-0.15 m), the forest clip's 1.9 MHz background. The
    ground must be found at its centre, not in the understorey. Tolerance: the surface is the
    median of ~9 ground photons per bin (ground.GROUND_PER_BIN) less a known offset, whose
    sampling error is 1.25 x 0.15 / sqrt(9) = 0.06 m a bin; the median over the track's ~40
    bins is within ~0.01 m of the centre, and the background within the fit window (~0.2
    photons a bin, uniform) moves each bin's median by up to ~0.03 m: 0.1 m allowed.
    Vegetation classed ground: the band ends at most 3 x 0.15 = 0.45 m above the surface,
    below the vegetation's base, so only the surface's error lets any in: < 10 %. Ground
    photons kept: the band holds 84 % (-3 to +1 sigma) to 99.7 % of a normal return: > 80 %.
    Measured: ground -0.015 and -0.003 m, vegetation classed ground 0.0 and 0.1 %, ground
    kept 92 and 91 %; the code before the lower-flank fit (session 19): +0.28 and +0.15 m,
    33 and 23 % of the vegetation classed ground."""
    x, h, lab = cloud(seed=seed, slope=0.1, mu_ground=0.3, mu_canopy=0.8, canopy_lo_m=0.5,
                      canopy_mean_m=2.0, rho_per_m2=0.018, sigma_ground_m=0.15)
    c = C.classify_photons(x_m=x, h_m=h, background_per_m2=0.018)
    assert abs(np.nanmedian(c.ground_h_m - (100 + 0.1 * x))) < 0.1
    assert np.mean(c.classes[lab == 2] == C.GROUND) < 0.10
    assert np.mean(c.classes[lab == 1] == C.GROUND) > 0.8


def test_background_estimates_agree():
    """The background density from the cloud (sigma-clipped histogram) against the truth:
    ~0.04 /m^2 x 100 m x 300 m = 1200 photons a block, so a relative error of ~3 %; 10 %."""
    x, h, _ = cloud(seed=5)
    rho = C.background_density(x, h)
    assert abs(np.median(rho) / 0.04 - 1) < 0.1
    # the rate form: 4 MHz at 1/0.7 shots a metre
    assert math.isclose(C.background_density_from_rate(4e6, 1 / SHOT_M),
                        4e6 * 2 / 299792458.0 / SHOT_M, rel_tol=1e-6)


def _segments_of(x, h, lab, **kw):
    c = C.classify_photons(x_m=x, h_m=h, background_per_m2=0.04)
    seg = np.floor(x / 20.0).astype(int)
    n20 = seg.max() + 1
    return c, atl08.land_segments(
        x_m=x, h_m=h, classes=c.classes, ground_h_m=c.ground_h_m, is_signal=c.is_signal,
        photon_segment=seg, delta_time_s=x / 7000.0, seg_id=100 + np.arange(n20),
        seg_x_m=20.0 * np.arange(n20), seg_lat_deg=np.linspace(40, 40.01, n20),
        seg_lon_deg=np.full(n20, -106.0), seg_solar_elevation_deg=np.full(n20, 30.0),
        seg_solar_azimuth_deg=np.full(n20, 200.0), shots_per_m=1 / SHOT_M)


def test_segments_terrain_and_canopy_heights():
    """Per 100 m segment: h_te_best_fit at the mid-point against the true line (n ~ 40-50
    ground photons of 0.1 m scatter: standard error ~0.02 m; the ground buffer lets in
    background photons uniform over +-0.3 m and canopy photons from just above the ground,
    which pull a segment's fit up by up to ~0.2 m (measured 0.195 m): 0.25 m allowed), the
    slope (0.01), and h_canopy (RH98 of ~110 canopy photons a segment: sampling sd ~(15 m)
    sqrt(0.0196 / 110) ~0.2 m, but see the bound below)."""
    x, h, lab = cloud(seed=7, slope=0.1)
    c, s = _segments_of(x, h, lab)
    n = s["land_segments/segment_id_beg"].size
    assert n == 8 and list(s["land_segments/segment_id_beg"][:2]) == [100, 105]
    mid = 50.0 + 100.0 * np.arange(n)
    te = s["land_segments/terrain/h_te_best_fit"]
    # every segment, the track's ends included (measured within 0.13 m; before the ground's
    # lower-flank fit the last 100 m was 0.9 m off)
    assert np.all(np.abs(te - (100 + 0.1 * mid)) < 0.25)
    assert np.all(np.abs(s["land_segments/terrain/terrain_slope"] - 0.1) < 0.01)
    hc = s["land_segments/canopy/h_canopy"]
    # measured: 12.5-16.0 m, median 13.6 m against 14.7 m. NOT within the sampling error
    # (~0.2 m): the noise filter drops canopy-top photons (half their window is empty air)
    # and lets background just above the top in; a systematic of the density filter
    # (docs/guide/atl08.md). This bounds it, so a change that worsens it fails.
    assert np.all(np.abs(hc - 14.7) < 3.0) and abs(np.median(hc) - 14.7) < 1.5
    rh = s["land_segments/canopy/canopy_h_metrics"]
    assert rh.shape == (n, 18) and np.all(np.diff(rh, axis=1) >= 0)
    assert np.all(s["land_segments/canopy/n_ca_photons"] + s["land_segments/canopy/n_toc_photons"]
                  >= atl08.segments.MIN_CANOPY_PHOTONS)
    assert np.all(s["land_segments/night_flag"] == 0)


def _datasets(g) -> dict:
    out = {}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            out[name] = (obj.dtype, obj.shape[1:], obj.fillvalue)
    g.visititems(visit)
    return out


@pytest.fixture(scope="module")
def real_run(tmp_path_factory):
    """Our ATL08 of the real forest ATL03 clip, and the file written."""
    beam = atl08.from_atl03(REAL_ATL03, "gt1r")
    return beam, atl08.write(beam, tmp_path_factory.mktemp("a8") / "ATL08_ours.h5")


@have_real
def test_written_fields_match_the_real_atl08(real_run):
    """Every dataset we write exists in the real clip's gt1r/ with the same dtype, trailing
    shape and HDF5 fill value, and carries units, long_name and _FillValue (the clip's
    subsetter dropped its attributes; the fill values survive in the datasets)."""
    beam, path = real_run
    with h5py.File(REAL_ATL08) as f:
        real = _datasets(f["gt1r"])
    with h5py.File(path) as f:
        ours = _datasets(f["gt1r"])
        attrs = {k: dict(f["gt1r"][k].attrs) for k in ours}
        assert f["METADATA/DatasetIdentification"].attrs["shortName"] == b"ATL08"
    assert len(ours) == sum(len(v) for v in fields.GROUPS.values())
    for name, (dtype, shape, fill) in ours.items():
        assert name in real, name
        assert (dtype, shape) == real[name][:2], (name, dtype, shape, real[name])
        assert fill == real[name][2] or (np.isnan(fill) and np.isnan(real[name][2])), name
        assert attrs[name]["units"] and attrs[name]["long_name"], name
    ph = beam.photons
    assert set(np.unique(ph["classed_pc_flag"])) <= {0, 1, 2, 3}
    assert np.all(ph["classed_pc_indx"] >= 1)


@have_real
def test_h5coro_reads_ours(real_run):
    """SlideRule's h5coro (pure Python) reads our ATL08 to the same values as h5py. (On the
    real clip h5coro 1.0.7 returns garbage for the gzip'd float datasets the clip tool
    rewrote: it is not the reader that opens the real one; h5py is.)"""
    from h5coro import h5coro, filedriver
    path = real_run[1]
    names = ["gt1r/land_segments/terrain/h_te_best_fit", "gt1r/land_segments/canopy/h_canopy",
             "gt1r/land_segments/canopy/canopy_h_metrics", "gt1r/signal_photons/classed_pc_flag",
             "gt1r/land_segments/segment_id_beg"]
    h5 = h5coro.H5Coro(str(path), filedriver.FileDriver, errorChecking=True)
    got = h5.readDatasets(names, block=True)
    with h5py.File(path) as f:
        for n in names:
            assert np.array_equal(np.asarray(got[n]), f[n][()]), n


@have_real
def test_the_real_comparison_study(real_run):
    """studies.atl08_real maps NASA's classes to the clip's ATL03 photons (every mapped photon
    checked on delta_time: 1610 of the 1771 NASA lists; the rest lie beyond the clip's last
    20 m segment), compares the 8 full segments, and prints its table."""
    from lidar_mitsuba.studies import atl08_real
    r = atl08_real.compare(REAL_ATL03, REAL_ATL08, "gt1r", ours=real_run[0])
    assert r["n_segments"] == 8 and r["confusion"]["n_mapped"] == 1610
    cm = np.array(r["confusion"]["matrix_nasa_rows_ours_cols"])
    # the clip's photons inside 20 m segments; NASA's ground, canopy and top of canopy among
    # them (the other 262 mapped it lists as noise)
    assert cm.sum() == 6808 and cm[1:].sum() == 1348
    assert "h_te_best_fit" in atl08_real.table(r)
    assert atl08_real.pairs([REAL_DIR]) == [(str(REAL_ATL03), str(REAL_ATL08))]



def test_ground_spread_from_the_slope_and_roughness_from_the_lower_flank():
    """The optional slope-capped ground (``Settings.slope_capped_ground``, ground.py step 6).
    ``slope_spread`` of a plane of slope 0.15 is ``hypot(pulse, 0.15 x 10.9 / 4)`` = 0.42 m
    for a 0.1 m pulse (closed form; the envelope here is the exact plane, so only the bins'
    medians enter: exact to 1e-9). ``lower_flank_gain``: 400 residuals below the surface of a
    half-normal of 0.5 m over no background; tested against its own spread the gain is half a
    chi-square(1) statistic (P(gain > 4.5) = 0.27 %), against 0.2 m it is hundreds (each of
    the 400 photons ~ln(2.5) more likely under the right spread). Then the forest-clip-like
    cloud of the docs (0.4 m ground on a 15 % slope under an understorey from 0.5 m holding
    2.7x the ground's peak density): the cap (0.42 m) keeps the spread from running into the
    understorey; measured over seeds 1-5 the capped ground is 0.19-0.67 m closer to the truth
    than the free fit's (seed 1: +0.46 against +0.65 m), so on seed 1 it must be at least
    0.1 m closer. (It is off by default: on a bare rough ground its test misses four seeds of
    five, docs/guide/atl08.md.)"""
    from lidar_mitsuba.products.atl08 import ground as G
    x = np.linspace(0, 800, 4000)
    h = 100 + 0.15 * x
    assert G.slope_spread(x, h, np.ones(x.size, bool), pulse_sigma_m=0.1,
                          footprint_sigma_m=10.9 / 4) == pytest.approx(
        math.hypot(0.1, 0.15 * 10.9 / 4), rel=1e-9)
    r = -np.abs(np.random.default_rng(4).normal(0, 0.5, 400))
    assert G.lower_flank_gain(r, sigma_m=0.5, background_per_m=0.0) < G.ROUGHNESS_GAIN
    assert G.lower_flank_gain(r, sigma_m=0.2, background_per_m=0.0) > 100
    xc, hc, _ = cloud(seed=1, slope=0.15, mu_ground=0.15, mu_canopy=0.8, canopy_lo_m=0.5,
                      canopy_mean_m=2.0, rho_per_m2=0.019, sigma_ground_m=0.4)
    truth = 100 + 0.15 * xc
    err = {}
    for capped in (False, True):
        c = C.classify_photons(x_m=xc, h_m=hc, background_per_m2=0.019,
                               settings=C.Settings(slope_capped_ground=capped))
        err[capped] = abs(np.nanmedian(c.ground_h_m - truth))
    assert err[True] < err[False] - 0.1


@have_real
def test_cli_atl08_draws_the_classes(tmp_path):
    """``lidar-mitsuba atl08 --plot`` (the gallery's forest picture) on the real clip writes
    the PNG; ``classified_cloud`` draws one point series per class, labelled with its count,
    every photon once, and the classifier's surfaces."""
    import matplotlib
    matplotlib.use("Agg")
    from lidar_mitsuba.cli import main
    from lidar_mitsuba.plotting import classified_cloud
    png = tmp_path / "clip.png"
    assert main(["atl08", str(REAL_ATL03), "--beams", "gt1r", "--out", str(tmp_path / "a.h5"),
                 "--plot", str(png)]) == 0
    assert png.stat().st_size > 10_000
    classes = np.array([0, 1, 1, 2, 3, 3, 3])
    x = np.arange(classes.size, dtype=float)
    fig = classified_cloud(photon_along_m=x, photon_h_m=x, classes=classes, ground_h_m=x * 0,
                           toc_h_m=x + 1, truth_along_m=x, truth_surface_z_m=x * 0)
    lines = fig.axes[0].get_lines()
    assert [ln.get_label() for ln in lines] == [
        "noise (1)", "ground (2)", "canopy (1)", "top of canopy (3)", "classifier's ground",
        "classifier's top of canopy", "true ground"]
    assert sum(len(ln.get_xdata()) for ln in lines[:4]) == classes.size
