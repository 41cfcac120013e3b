"""Issue 41: twins of any ICESat-2 product, every count that makes the night, the epoch's pulse
energy, and the realism matrix (``validate --real``) over the real files in ``../shared/real``.

Closed forms: the air's attenuated backscatter integral (exact when the aerosol's lidar ratio is
Rayleigh's 8 pi / 3), a uniform cloud's integrated backscatter, a Gaussian's mass outside a
span (against seeded sampling, tolerance five binomial standard errors)."""
from __future__ import annotations

import dataclasses
import json
import math
import pathlib

import numpy as np
import pytest

from lidar_mitsuba import night, twin
from lidar_mitsuba.atmosphere import cloud_layer
from lidar_mitsuba.atmosphere.cloud_layer import Cloud
from lidar_mitsuba.cli import main
from lidar_mitsuba.instrument import Instrument, atlas_pulse_energy_uj
from lidar_mitsuba.products import real
from lidar_mitsuba.radiometry import Atmosphere
from lidar_mitsuba.studies import realism

ROOT = pathlib.Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "real"
DAY_S = 86400.0


# ------------------------------------------------------------------------------ night floor
def test_the_airs_backscatter_integral_is_its_closed_form(monkeypatch):
    """With both scatterers' backscatter 3 / 8 pi of their extinction, integral beta T^2 dz =
    (3 / 8 pi) (exp(-2 tau_top) - exp(-2 tau_bottom)) / 2 exactly (d tau = -sigma dz)."""
    monkeypatch.setattr(night, "AEROSOL_LIDAR_RATIO_SR", 8.0 * math.pi / 3.0)
    atm = Atmosphere(aerosol_optical_depth=0.2)
    for lo, hi in ((0.0, 2506.0), (1000.0, 3500.0)):
        tr_lo, ta_lo = atm.optical_depths(lo)
        tr_hi, ta_hi = atm.optical_depths(hi)
        exact = 3.0 / (8.0 * math.pi) * (np.exp(-2 * (tr_hi + ta_hi))
                                         - np.exp(-2 * (tr_lo + ta_lo))) / 2.0
        got = night.air_backscatter_integral_sr(atm, z_lo_m=lo, z_hi_m=hi)
        assert got == pytest.approx(float(exact), rel=1e-4)     # trapezoids on 400 heights


def test_a_clouds_integrated_backscatter_is_its_closed_form():
    c = dataclasses.replace(Cloud.ice(1.3, 800.0, 1800.0), multiple_scattering_eta=0.7)
    z = np.linspace(0.0, 1000.0, 200001)                   # depth into the layer from its top
    sigma = c.optical_depth / 1000.0
    y = sigma / cloud_layer.LIDAR_RATIO_SR["ice"] * np.exp(-2 * 0.7 * sigma * z)
    numeric = float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(z)))
    assert c.integrated_backscatter_sr() == pytest.approx(numeric, rel=1e-8)
    assert night.cloud_backscatter(c) == (c.lidar_two_way_transmission,
                                          c.integrated_backscatter_sr())
    assert c.lidar_two_way_transmission == pytest.approx(math.exp(-2 * 0.7 * 1.3))
    assert c.two_way_transmission == pytest.approx(math.exp(-2 * 1.3))   # a traced run's
    assert "multiple_scattering_eta" not in Cloud.water(1.0, 500, 1500).to_dict()


def test_a_gaussians_mass_outside_a_span_against_sampling():
    rng = np.random.default_rng(41)
    n, sigma = 200_000, 0.1
    x = rng.normal(0.0, sigma, n)
    spans = np.array([0.0, 0.1, 0.3])
    f = night.gaussian_outside_fraction(spans, sigma)
    sampled = realism.outside_fraction(x, spans)
    se = np.sqrt(f * (1 - f) / n) + 1.0 / n                  # binomial standard error
    assert np.all(np.abs(sampled - f) <= 5 * se + 2.0 / n)   # the sample median's offset
    assert f[0] == pytest.approx(1.0)


def test_atl03_removes_exactly_its_high_confidence_photons_and_their_span():
    """What ATL03's background leaves out, read from the shipped night subset: for every
    50-shot row of ``bckgrd_atlas`` whose 50 pulses all lie inside the subset (each row is a
    quarter of a 200-pulse major frame, ``pce_mframe_cnt``; the granule's first frame holds
    only its last three), ``bckgrd_counts - bckgrd_counts_reduced`` is the number of the row's
    photons high confidence for any surface type (``signal_conf_ph``'s maximum over its five
    columns is 4), exactly, and ``bckgrd_int_height - bckgrd_int_height_reduced`` their height
    span, to float32's rounding of the 5 km band (half its spacing there, 2.4e-4 m). The
    sea-ice column alone misses a photon in some rows."""
    import h5py
    with h5py.File(twin.REAL_SUBSET) as f:
        g = f["gt1l"]
        bg = {k: g["bckgrd_atlas"][k][()] for k in (
            "pce_mframe_cnt", "bckgrd_counts", "bckgrd_counts_reduced", "bckgrd_int_height",
            "bckgrd_int_height_reduced")}
        h = g["heights/h_ph"][()].astype(np.float64)
        conf = g["heights/signal_conf_ph"][()]
        pulse = (g["heights/pce_mframe_cnt"][()].astype(np.int64) * 200
                 + g["heights/ph_id_pulse"][()] - 1)
    frame = bg["pce_mframe_cnt"].astype(np.int64)
    frames, first, n_rows = np.unique(frame, return_index=True, return_counts=True)
    k = np.searchsorted(frames, frame)
    quarter = np.arange(frame.size) - first[k] + np.where(k == 0, 4 - n_rows[0], 0)
    row_start = frame * 200 + quarter * 50                         # each row's first pulse
    row = np.searchsorted(row_start, pulse, side="right") - 1
    p = np.unique(pulse)                  # the subset's unbroken stretches of pulses
    cut = np.flatnonzero(np.diff(p) > 50)
    full = np.zeros(row_start.size, bool)
    for lo, hi in zip(p[np.r_[0, cut + 1]], p[np.r_[cut, p.size - 1]]):
        full |= (row_start > lo) & (row_start + night.BCKGRD_SHOTS - 1 < hi)
    rows = np.flatnonzero(full)
    assert rows.size == 21                                   # of the subset's 25 rows
    ok = row >= 0                         # (photons before the granule's first row)
    count, span = night.removed_signal(row=row[ok], h_m=h[ok], high=conf[ok].max(axis=1) == 4,
                                       n_rows=row_start.size)
    removed = (bg["bckgrd_counts"] - bg["bckgrd_counts_reduced"])[rows]
    assert np.array_equal(removed, count[rows]) and removed.min() > 90
    narrowed = (bg["bckgrd_int_height"].astype(np.float64)
                - bg["bckgrd_int_height_reduced"])[rows]
    half_ulp = float(np.spacing(np.float32(5006.5))) / 2
    assert np.all(np.abs(narrowed - span[rows]) <= half_ulp) and span[rows].min() > 0.5
    sea_ice, _ = night.removed_signal(row=row[ok], h_m=h[ok], high=conf[ok, 2] == 4,
                                      n_rows=row_start.size)
    assert np.any(sea_ice[rows] != removed)


def test_one_rule_for_a_rows_removed_photons_in_any_order():
    """:func:`night.removed_extremes` (the rule our ATL03 writer's rows and
    :func:`night.removed_signal` share): each row's high-confidence count, lowest and highest
    height, against a loop over the rows, for photons in shot order and shuffled; a row
    without one keeps inf / -inf and a span of 0."""
    rng = np.random.default_rng(5)
    row = np.sort(rng.integers(0, 6, 300))
    row[row == 4] = 3                                       # row 4: no photon at all
    h = rng.normal(0.0, 2.0, row.size)
    high = rng.random(row.size) < 0.6
    high[row == 5] = False                                  # row 5: none high
    want_lo = [h[high & (row == r)].min() if np.any(high & (row == r)) else np.inf
               for r in range(6)]
    want_hi = [h[high & (row == r)].max() if np.any(high & (row == r)) else -np.inf
               for r in range(6)]
    for p in (np.arange(row.size), rng.permutation(row.size)):
        count, lo, hi = night.removed_extremes(row=row[p], h_m=h[p], high=high[p], n_rows=6)
        assert np.array_equal(count, np.bincount(row[high], minlength=6))
        assert np.array_equal(lo, want_lo) and np.array_equal(hi, want_hi)
        _, span = night.removed_signal(row=row[p], h_m=h[p], high=high[p], n_rows=6)
        assert np.array_equal(span, np.where(count > 0, hi - lo, 0.0))
    assert count[4] == count[5] == 0 and span[5] == 0.0


def test_the_curves_laser_photons_are_the_lidar_equations_and_the_snows():
    """The figure's curves count the leak on photons drawn in closed form
    (:func:`realism_curve.laser_photons`): over 4000 shots their number a shot is the lidar
    equation's mean (Poisson: tolerance 5 standard errors) and, with the Gaussian pulse alone
    (sigma_h 0.1 m: nothing beyond 0.5 m), the share more than 0.5 m below the surface is the
    snow's volume share times its apparent depth's survival there (binomial, 5 standard
    errors)."""
    from lidar_mitsuba.ground.snow import delay
    from lidar_mitsuba.studies import realism_curve
    surface = realism.PRODUCT_SURFACES["land ice"]
    inst = dataclasses.replace(Instrument.atlas("weak"), pulse_shape="gaussian")
    ph = realism_curve.laser_photons(inst, surface=surface, z_m=0.0, shots=4000,
                                     rng=np.random.default_rng(3))
    mean = realism.radiometric_signal(inst, z_m=0.0, surface=surface)
    assert abs(ph["shot"].size / 4000 - mean) <= 5 * math.sqrt(mean / 4000)
    pack, share = realism.snow_delay(surface)
    p = share * float(delay.apparent_depth_sf(pack, np.array(0.5)))
    n = ph["h_m"].size
    assert abs(np.mean(ph["h_m"] < -0.5) - p) <= 5 * math.sqrt(p * (1 - p) / n)
    assert ph["afterpulse_probability"] == 0.0 and np.all(ph["gate_center_h_m"] == 0)


def test_the_leak_is_the_laser_photons_the_finder_leaves_over_the_band_less_its_span():
    """night.atl03_leak on photons whose confidence is certain: a dense surface (5 photons a
    shot within 0.4 m: high confidence), three lone photons 5-13 m below it in the first row
    (each alone in its bin, against the photon cloud's background, the lone photons
    themselves, 0.008-0.02 a bin: P = 0.017-0.020, noise), two below the gate in the second
    (never tested); no noise drawn. Exactly: those five and 1 % of all the
    laser photons (afterpulses) left, each row's span the surface's, the rate over the band
    less it. Thinned to half, the lone photons left average half (200 draws: binomial
    standard error sqrt(5 / 4 / 200) = 0.079, 4.5 of them)."""
    rng = np.random.default_rng(41)
    n_shots = 100
    s_shot = np.repeat(np.arange(n_shots), 5)
    s_h = rng.uniform(-0.2, 0.2, s_shot.size)
    shot = np.r_[s_shot, 3, 11, 37, 60, 77]
    h = np.r_[s_h, -5.0, -9.0, -13.0, -20.0, -40.0]
    kw = dict(shot=shot, h_m=h, is_signal=np.ones(h.size, bool), n_shots=n_shots,
              gate_center_h_m=np.zeros(n_shots), range_gate_m=30.0, noise_hz=0.0,
              band_rate_hz=1e4, band_height_m=5006.0, afterpulse_probability=0.01)
    leak = night.atl03_leak(**kw, rng=np.random.default_rng(0), realizations=1)
    assert np.array_equal(leak.signal, [253, 252]) and np.array_equal(leak.high, [250, 250])
    assert np.allclose(leak.leftover, [3 + 2.53, 2 + 2.52], rtol=0, atol=1e-12)
    span = [np.ptp(s_h[s_shot < 50]), np.ptp(s_h[s_shot >= 50])]
    assert np.allclose(leak.span_m, span, rtol=0, atol=1e-12)
    c = night.C_M_PER_S
    assert leak.leak_hz == pytest.approx((5 + 5.05) / sum(50 * 2 * (5006.0 - w) / c
                                                         for w in span), rel=1e-12)
    half = night.atl03_leak(**kw, rng=np.random.default_rng(1), keep=0.5, realizations=200,
                            passes=1)
    lone = half.leftover.sum() - 0.01 * half.signal.sum()
    assert abs(lone - 2.5) <= 4.5 * math.sqrt(5 / 4 / 200)
    assert half.summary()["leak_se_hz"] == pytest.approx(
        half.leak_hz * math.sqrt(0.5 / half.leftover.sum()))


def test_dark_counts_are_every_anodes_and_the_weak_beam_keeps_its_own():
    strong, weak = Instrument.atlas("strong"), Instrument.atlas("weak")
    assert strong.dark_count_hz * strong.channels == weak.dark_count_hz * weak.channels \
        == 16 * night.DARK_COUNT_PER_ANODE_HZ
    assert weak.dark_count_hz == 100.0                      # earlier versions' weak beam
    assert Instrument.atlas("strong", dark_count_hz=7.0).dark_count_hz == 7.0


def test_the_nights_strong_weak_ratio_follows_from_its_terms():
    """The air and the leak scale with the pulse energy, the dark counts do not: the ratio
    lies strictly between 1 and the energy ratio, and is what the terms say."""
    kw = dict(delta_time_s=np.full(3, 3.1e7), z_m=np.zeros(3), albedo=0.9,
              solar_elevation_deg=np.full(3, -30.0), solar_azimuth_deg=np.zeros(3))
    s = night.background_terms(Instrument.atlas("strong"), signal_per_shot=8.0,
                               outside_fraction=0.05, **kw)
    w = night.background_terms(Instrument.atlas("weak"), signal_per_shot=2.0,
                               outside_fraction=0.05, **kw)
    assert s["solar"] == w["solar"] == 0.0
    assert s["air"] / w["air"] == pytest.approx(4.0, rel=1e-12)
    assert s["dark"] == w["dark"] > 0
    ratio = s["total"] / w["total"]
    assert 1.0 < ratio < 4.0
    assert ratio == pytest.approx((s["air"] + s["leak"] + s["dark"])
                                  / (w["air"] + w["leak"] + w["dark"]))


def test_the_epochs_pulse_energy():
    t = lambda d: (np.datetime64(d) - np.datetime64("2018-01-01")) / np.timedelta64(1, "s")  # noqa: E731
    assert atlas_pulse_energy_uj("weak", t("2018-10-14"))[0] == pytest.approx(27.5)
    assert atlas_pulse_energy_uj("weak", t("2022-04-01"))[0] == pytest.approx(22.8)
    mid = atlas_pulse_energy_uj("weak", t("2020-07-01"))
    assert 22.8 < mid[0] < 27.5 and "ESTIMATE" in mid[1]
    assert atlas_pulse_energy_uj("strong", t("2024-01-01"))[0] == pytest.approx(4 * 27.5)
    assert twin.beam_energy_uj("weak", 22.0, 0.0, "strong") == (88.0, "tx_pulse_energy")


# ------------------------------------------------------------------------------ any product
def _atl06(path, *, beam_type: str | None, sc_orient: int = 0, n: int = 30):
    """A small ATL06-like file: two beams of ``n`` 20 m segments north from 70 N."""
    import h5py
    with h5py.File(path, "w") as f:
        f["orbit_info/sc_orient"] = np.array([sc_orient], np.int8)
        for k, name in enumerate(("gt1l", "gt1r")):
            g = f.create_group(name)
            if beam_type is not None:
                g.attrs["atlas_beam_type"] = np.array(
                    [(beam_type if k == 0 else ("weak" if beam_type == "strong" else "strong"))],
                    dtype=object).astype(h5py.string_dtype())
            s = g.create_group("land_ice_segments")
            s["delta_time"] = 4.1e7 + np.arange(n) * 20.0 / 7000.0
            s["latitude"] = 70.0 + np.arange(n) * 20.0 / 111_000.0
            s["longitude"] = np.full(n, -45.0)
            h = np.full(n, 2000.0, np.float32)
            h[3] = 3.4028235e38                              # a fill value
            s["h_li"] = h
            s["geophysical/solar_elevation"] = np.full(n, 10.0, np.float32)
            s["geophysical/solar_azimuth"] = np.full(n, 90.0, np.float32)
            s["geophysical/bckgrd"] = np.full(n, 1e6, np.float32)
            s["geophysical/r_eff"] = np.where(np.arange(n) < n // 2, 0.9, 0.1).astype(np.float32)
            s["fit_statistics/n_fit_photons"] = np.full(n, 500, np.int32)
            s["fit_statistics/n_seg_pulses"] = np.full(n, 57.0, np.float32)
            s["fit_statistics/w_surface_window_final"] = np.full(n, 3.0, np.float32)
    return path


def test_strength_comes_from_atlas_beam_type_over_sc_orient(tmp_path):
    # sc_orient 0 says gt1l is strong; the attribute (a clip tool's object array) says weak
    f = real.read_product(_atl06(tmp_path / "a.h5", beam_type="weak", sc_orient=0))
    assert f.product == "ATL06"
    assert {b.name: (b.strength, b.strength_from) for b in f.beams} == {
        "gt1l": ("weak", "atlas_beam_type"), "gt1r": ("strong", "atlas_beam_type")}
    b = f.beams[0]
    assert np.isnan(b.surface_h_m[3]) and b.surface_h_m[0] == 2000.0
    expected = (500 - 1e6 * 3.0 * 2 / 299792458.0 * 57) / 57
    assert np.allclose(b.signal_per_shot, expected, rtol=1e-5)
    assert b.clear.tolist() == [True] * 15 + [False] * 15      # r_eff 0.9 / 0.1
    line = f.missing_line()
    assert "\n" not in line and "altitude_sc" in line and "tx_pulse_energy" in line
    # without the attribute: sc_orient decides, and the line says so
    g = real.read_product(_atl06(tmp_path / "b.h5", beam_type=None, sc_orient=1))
    assert {b.name: b.strength for b in g.beams} == {"gt1l": "weak", "gt1r": "strong"}
    assert "atlas_beam_type on gt1l, gt1r" in g.missing_line()


def test_a_twin_of_an_atl06_file(tmp_path):
    g = twin.read(_atl06(tmp_path / "a.h5", beam_type="strong"))
    assert g.product == "ATL06" and [b.beam.strength for b in g.beams] == ["strong", "weak"]
    b = g.beams[0]
    assert b.n_shots == pytest.approx(29 * 20 / 0.7, rel=0.05)
    assert np.all(np.isfinite(b.surface_h_m))               # the fill interpolated over
    assert g.median_range_m() == pytest.approx(496e3)       # no altitude_sc: nominal range
    e, where = b.energy_uj()
    assert "ESTIMATE" in where and 4 * 22.8 < e < 4 * 27.5


def test_the_real_files_every_product_and_their_trimmed_copies(tmp_path):
    if not SHARED.is_dir():
        pytest.skip(f"no real files at {SHARED} (the shared data folder beside the repo)")
    seen = {}
    for p in sorted(SHARED.glob("*.h5")):
        f = real.read_product(p)
        seen.setdefault(f.product, []).append(p.name)
        assert all(b.strength_from == "atlas_beam_type" for b in f.beams)
        assert "\n" not in f.missing_line()
        if f.product == "ATL03":     # the product's rate: reduced counts over 50 shots' band
            import h5py
            for b in f.beams:
                with h5py.File(p) as h:
                    g = h[b.name]["bckgrd_atlas"]
                    rate = g["bckgrd_counts_reduced"][()] / (
                        50 * 2 * g["bckgrd_int_height_reduced"][()] / 299792458.0)
                    assert np.allclose(rate, g["bckgrd_rate"][()], rtol=1e-6)
        else:                                        # trimmed: the same numbers
            t = real.read_product(real.trim(p, tmp_path / p.name))
            assert t.missing == f.missing and len(t.beams) == len(f.beams)
            for a, b in zip(f.beams, t.beams):
                for k in ("surface_h_m", "background_hz", "signal_per_shot", "clear"):
                    u, v = getattr(a, k), getattr(b, k)
                    assert (u is None and v is None) or np.array_equal(u, v, equal_nan=True)
    assert set(seen) == {"ATL03", "ATL06", "ATL07", "ATL08"}


# ------------------------------------------------------------------------------ the matrix
def test_validate_real_over_every_real_file(tmp_path, capsys):
    """The realism matrix over ../shared/real by the lidar equation (no rendering): every beam
    of every file has a row, its verdict follows from its ratios, the figure is drawn."""
    if not SHARED.is_dir():
        pytest.skip(f"no real files at {SHARED} (the shared data folder beside the repo)")
    assert main(["validate", "--real", str(SHARED), "--signal-shots", "0",
                 "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "realism.json").read_text())
    files = sorted(p.name for p in SHARED.glob("*.h5"))
    assert sorted(f["file"] for f in doc["files"]) == files
    by_file = {}
    for r in doc["rows"]:
        by_file.setdefault(r["file"], []).append(r)
        lo, hi = realism.BACKGROUND_AGREES
        if r["verdict"] == "agrees":      # clear segments', or with the cloud the cloudy ones'
            ratio = r["background_ratio"]
            assert lo <= (ratio if ratio is not None else r["background_cloudy_ratio"]) <= hi
        if "forest" in r["file"]:        # the forest twin's rows: only with --signal-shots > 0
            assert r["verdict"] == "not simulated" and "--signal-shots" in r["reason"]
        assert r["predicted"]["background_hz"] == pytest.approx(
            sum(v for k, v in r["predicted"]["background_terms_hz"].items() if k != "total"))
    assert set(by_file) == set(files)
    # every segment cloudy: the cloud the file's own r_eff implies, where it gives one
    pine = [r for r in doc["rows"] if "pine_island" in r["file"]]
    assert pine and all(r["measured"]["clear_fraction"] == 0 for r in pine)
    for r in pine:
        if r["cloud"] is None:            # gt3l: neither r_eff nor a background on any segment
            assert r["verdict"] == "not measured"
        else:
            assert r["cloud"]["from"] == "the file's reflectance" and r["cloud"]["optical_depth"] > 0
    assert sum(r["cloud"] is not None for r in pine) >= 4
    assert (tmp_path / "realism_background.png").stat().st_size > 10_000
    md = (tmp_path / "realism.md").read_text()
    assert all(f in md for f in files) and "MISSING" not in md
    # the forest clip's ATL03 and NASA's ATL08: our ATL08 beside it (studies.atl08_real)
    assert "h_te_best_fit" in (tmp_path / "atl08_real.md").read_text()
    out = capsys.readouterr().out
    assert "ATL06_20190420093051" in out and "wrote" in out


def test_validate_real_runs_over_the_shipped_files_and_simulates_a_beam(tmp_path):
    """With no file: the package's own real files (every product); a beam's signal through a
    short simulation."""
    shipped = realism.real_files(None)
    assert shipped == sorted(realism.PACKAGE_DATA.glob("*.h5")) and len(shipped) == 7
    assert {real.read_product(p).product for p in shipped} == {"ATL03", "ATL06", "ATL07",
                                                                "ATL08"}
    doc = realism.run([twin.REAL_SUBSET], tmp_path, signal_shots=60)
    (row,) = doc["rows"]
    assert row["file"] == twin.REAL_SUBSET.name and row["strength"] == "weak"
    p = row["predicted"]
    assert p["shots"] == 60 and p["signal_per_shot"] > 0 and "spread_robust_m" in p
    assert p["energy_source"] == "tx_pulse_energy"
    assert row["measured"]["spread_robust_m"] > 0
    # the central Arctic subset over validate's rough sea ice (twin.sea_ice_surface), its
    # shape judged by issue 41's rule, the ratios and their SEs from the counted tails
    assert "rough: 16 cm rms" in p["surface"] and "Fram Strait" in p["surface_why"]
    sv, m = row["shape"], row["measured"]
    assert sv["spread_ratio"] == p["spread_robust_m"] / m["spread_robust_m"]
    for side in ("below", "above"):
        f, n = p[f"tail_{side}"], p["shape_photons"]
        assert p[f"tail_{side}_se"] == pytest.approx(math.sqrt(f * (1 - f) / n))
        assert sv[f"tail_{side}_agrees"] == (0.5 <= sv[f"tail_{side}_ratio"] <= 2.0)
    assert sv["verdict"] in ("agrees", "disagrees") and "without_snow_delay" in p
    md = (tmp_path / "realism.md").read_text()
    assert "rough: 16 cm rms" in md and f"**{sv['verdict']}**" in md
    # the leak: ATL03 gives its finder's span, so the laser photons outside it and their
    # afterpulses; without the span (ATL06, ATL07), those our finder leaves in two 50-shot
    # rows (the second of 10 shots) of the same simulation
    assert p["leak_from"] == "the file's span" and "leak" not in p
    rb = real.read_product(twin.REAL_SUBSET).beams[0]
    band_s = 2 * np.nanmedian(rb.band_height_m) / night.C_M_PER_S
    assert p["background_terms_hz"]["leak"] == pytest.approx(
        p["signal_per_shot"] * p["outside_fraction"] / band_s, rel=1e-12)
    rb.signal_span_m = None
    rb.lat_deg = rb.lat_deg - 18.0      # seasonal ice's latitude: flat snow (and no rough tile)
    q = realism.predicted(rb, twin.read(twin.REAL_SUBSET), signal_shots=60, seed=0)
    assert "(flat" in q["surface"] and "first-year" in q["surface_why"]
    leak = q["leak"]
    assert q["leak_from"].startswith("our signal finder") and leak["rows"] == 2
    assert q["background_terms_hz"]["leak"] == leak["leak_hz"] > 0
    assert 0 < leak["leftover_photons"] < leak["signal_photons"]
    assert leak["gate_noise_hz"] > 0 and leak["band_rate_hz"] > 0


def test_a_files_rows_do_not_depend_on_the_other_files_of_the_run(tmp_path):
    """A file's simulated rows are seeded from its own name (``realism.file_seed``), so the
    same file gives the same prediction alone and after another file (the seed was its
    place in the run's list: the third hold-out round saw one beam's background predicted
    at 15.5-18.0 kHz by the folder it was run from)."""
    night = SHARED / "ATL06_20181226035130_13520105_001_01_greenland_night.h5"
    if not night.exists():
        pytest.skip("the real files are not here")
    alone = realism.run([twin.REAL_SUBSET], signal_shots=30)["rows"]
    both = realism.run([night, twin.REAL_SUBSET], signal_shots=30)["rows"]
    (after,) = [r for r in both if r["file"] == twin.REAL_SUBSET.name]
    assert [r["file"] for r in both][-1] == twin.REAL_SUBSET.name      # read after the other
    assert after["predicted"] == alone[0]["predicted"]
    assert realism.file_seed(night) != realism.file_seed(twin.REAL_SUBSET)
    assert realism.file_seed(tmp_path / twin.REAL_SUBSET.name) == realism.file_seed(
        twin.REAL_SUBSET)                                       # any folder


def test_open_water_twin_and_option_refusals(tmp_path, capsys):
    g = twin.read(twin.REAL_SUBSET)
    snow = twin.simulate_over_surface(g, shots=40, progress=False, seed=3)
    water = twin.simulate_over_surface(g, shots=40, progress=False, seed=3, water_wind_mps=5.0)
    assert water.config["water_wind_mps"] == 5.0
    # nadir weight of 5 m/s water ~0.2 against Ward snow's 1.15 (ground.water): ~80 signal
    # photons over snow in 40 weak shots, ~20 over water (Poisson sd ~9 and ~4.5)
    n = [r.beams[0].result.detections.is_signal.sum() for r in (snow, water)]
    assert n[1] < 0.5 * n[0]
    assert main(["validate", "--out", str(tmp_path), "--signal-shots", "10"]) == 2
    assert "--signal-shots" in capsys.readouterr().err
    assert main(["simulate", "--dem", "x.tif", "--water-wind-mps", "5",
                 "--out", str(tmp_path / "o.h5")]) == 2
    assert "--water-wind-mps" in capsys.readouterr().err


def test_a_subset_without_photons_or_attributes_is_still_read(tmp_path):
    """A subsetter that drops the photons and rewrites sc_orient: the twin still has its
    shots (at the ellipsoid), its strength from atlas_beam_type, and the line says so."""
    import shutil
    import h5py
    p = shutil.copy(twin.REAL_SUBSET, tmp_path / "cut.h5")
    with h5py.File(p, "a") as f:
        del f["gt1l/heights"]
        f["gt1l"].attrs["sc_orientation"] = "Backward"   # gt1l strong; atlas_beam_type: weak
    g = twin.read(p)
    assert g.beams[0].beam.strength == "weak" and g.beams[0].n_shots > 1000
    assert "surface heights" in g.missing_line()
    assert g.beams[0].pulse_energy_uj == pytest.approx(27.65, abs=0.01)


def test_a_cloud_given_predicts_the_cloudy_segments(tmp_path, capsys):
    night_file = realism.PACKAGE_DATA / "ATL06_20181226035130_13520105_001_01_greenland_night.h5"
    bare = realism.run([night_file], None, signal_shots=0)
    for r in bare["rows"]:       # the file's own cloud: r_eff's depth, msw_flag 1 (above 3 km)
        assert r["cloud"]["from"] == "the file's reflectance" and r["cloud"]["base_m"] == 4000.0
        assert "reflectance implies" in r["reason"]
        assert r["predicted"]["background_cloudy_terms_hz"]["cloud"] == 0.0   # above the band
    layer = Cloud.water(1.0, 500.0, 1500.0)
    doc = realism.run([night_file], None, signal_shots=0, cloud=layer)
    for r, b in zip(doc["rows"], bare["rows"]):
        assert r["verdict"] in ("agrees", "disagrees") and "cloud given" in r["reason"]
        p = r["predicted"]
        assert p["background_cloudy_terms_hz"]["cloud"] > 0
        assert p["signal_cloudy"] == pytest.approx(p["signal_per_shot"] * math.exp(-2.0))
        # the air below the cloud dimmed, the air above it kept: less air than clear sky
        assert p["background_cloudy_terms_hz"]["air"] < b["predicted"]["background_terms_hz"]["air"]
    assert main(["validate", "--real", str(night_file), "--cloud", "1,1500,500",
                 "--out", str(tmp_path)]) == 2
    assert "--cloud" in capsys.readouterr().err


def _beam(reflectance, clear, layer_class=None):
    n = len(reflectance)
    return real.RealBeam(name="gt1l", spot=1, strength="strong", strength_from="test",
                         delta_time_s=np.arange(n, dtype=float), lat_deg=np.zeros(n),
                         lon_deg=np.zeros(n), surface_h_m=np.zeros(n),
                         reflectance=np.asarray(reflectance, float), clear=np.asarray(clear),
                         layer_class=None if layer_class is None else np.asarray(layer_class))


def test_the_cloud_a_files_reflectance_and_layer_flag_imply():
    """tau = -ln(r / r_clear) / 2 with the beam's clear segments as r_clear (snow's 0.9
    without any), the layer's height from msw_flag's most frequent class."""
    r_clear, tau = 0.8, 0.7
    b = _beam([r_clear, r_clear * math.exp(-2 * tau), r_clear * math.exp(-2 * tau)],
              [True, False, False], [0, 2, 2])
    c = realism.implied_cloud(b)
    assert c.optical_depth == pytest.approx(tau, abs=1e-3) and (c.base_m, c.top_m) == (
        2000.0, 3000.0)
    c = realism.implied_cloud(_beam([0.9 * math.exp(-2.0)] * 2, [False, False]))
    assert c.optical_depth == pytest.approx(1.0, abs=1e-3) and c.base_m == 500.0   # no flag
    assert realism.layer_heights_m([1, 1, 3]) == (4000.0, 5000.0)
    assert realism.layer_heights_m([5, 4, 4, 0]) == (0.0, realism.BLOWING_SNOW_TOP_M)
    assert realism.implied_cloud(_beam([0.9, 0.9], [True, True])) is None    # all clear
    assert realism.implied_cloud(_beam([0.9, 0.95], [True, False])) is None  # not dimmed


def test_the_sun_sees_the_files_ice_concentration():
    """On sea ice the sunlit albedo is the area mean c 0.9 + (1 - c) 0.06 with c ATL07's
    ice_conc (the median over the beam's segments); elsewhere the surface's own."""
    b = _beam([0.9] * 3, [True] * 3)
    b.ice_fraction = np.array([0.92, 0.90, np.nan])
    sea, ice = realism.PRODUCT_SURFACES["sea ice"], realism.PRODUCT_SURFACES["land ice"]
    assert realism.sunlit_albedo(b, sea) == pytest.approx(0.91 * 0.9 + 0.09 * 0.06)
    assert realism.sunlit_albedo(b, ice) == 0.9
    b.ice_fraction = None
    assert realism.sunlit_albedo(b, sea) == 0.9


def test_the_files_solar_elevation_is_the_apparent_one_and_the_model_uses_the_geometric():
    """Above the horizon a real file's ``solar_elevation`` is the NREL SPA's geometric
    elevation at its time and place plus Saemundsson's refraction (closed form), to 0.01 deg
    (measured 0.003), though its attribute says refraction is not included: so the twin lights
    its shots with SPA's geometric sun (the sky model refracts it once), not the file's."""
    from lidar_mitsuba.radiometry import solar_angles
    from lidar_mitsuba.sky import saemundsson_refraction_deg
    path = SHARED / "ATL07-01_20190225115500_09020201_003_02_baffin_lowsun.h5"
    if not path.is_file():
        pytest.skip(f"no {path.name} in {SHARED}")
    rb = real.read_product(path).beams[0]
    ok = np.isfinite(rb.solar_elevation_deg) & np.isfinite(rb.delta_time_s)
    geometric, _ = solar_angles(rb.lat_deg[ok], rb.lon_deg[ok], rb.delta_time_s[ok], every=1)
    assert np.all(geometric > 3.5)                                    # the sun at +4 deg
    offset = rb.solar_elevation_deg[ok] - geometric
    np.testing.assert_allclose(offset, saemundsson_refraction_deg(geometric), atol=0.01)
    assert offset.min() > 0.15                                        # 0.19 deg: not noise
    b = twin.read(path, beams=rb.name).beams[0]
    geo = b.geolocation
    ours, _ = solar_angles(geo.lat_deg, geo.lon_deg, geo.delta_time_s, every=1)
    np.testing.assert_allclose(geo.solar_elevation_deg, ours, atol=0.01)


def test_a_pairs_weak_beam_takes_its_strong_partners_cloud():
    """ATL09 profiles the strong beams only and the pair's beams are 90 m apart: the weak beam
    of a pair gets its strong partner's implied cloud (Baffin night: gt3r's own flags put it
    at 1-3 km, gt3l's below 1 km); a beam without a partner keeps its own."""
    from lidar_mitsuba.studies.realism_inputs import implied_cloud, pair_clouds
    path = SHARED / "ATL07-01_20190222003738_08490201_003_02_baffin_night.h5"
    if not path.is_file():
        pytest.skip(f"no {path.name} in {SHARED}")
    beams = {rb.name: rb for rb in real.read_product(path).beams}
    clouds = pair_clouds(beams.values())
    assert implied_cloud(beams["gt3r"]).base_m != implied_cloud(beams["gt3l"]).base_m
    assert clouds["gt3r"] == clouds["gt3l"] == implied_cloud(beams["gt3l"])
    assert clouds["gt1r"] == implied_cloud(beams["gt1l"])
    assert clouds["gt2l"] == implied_cloud(beams["gt2l"])          # gt2r is not in the file


def test_json_safe_writes_plain_json_with_no_nan():
    """The studies' one JSON cleaner (realism.json, validate's and reproduce's report.json):
    NumPy values as Python ones, every non-finite float (Python's or NumPy's) as null, keys as
    strings, the keys a study leaves out dropped."""
    from lidar_mitsuba.studies import json_safe
    doc = {"nan": np.float64("nan"), "row": [np.float32(1.5), np.int64(3), np.bool_(True),
                                           float("inf"), (np.array([1.0, np.nan]),)],
           "_own": 1, 2: "two"}
    out = json_safe(doc, skip=lambda key: key.startswith("_"))
    assert json.loads(json.dumps(out, allow_nan=False)) == {
        "nan": None, "row": [1.5, 3, True, None, [[1.0, None]]], "2": "two"}
    assert type(out["row"][1]) is int and type(out["row"][2]) is bool


def _forest_doc(a03, a08) -> dict:
    """A forest twin's doc (studies.forest_twin.compare) with round numbers."""
    return {"atl03": a03.name, "atl08": a08.name, "beam": "gt1r", "floor": "litter",
            "shots": 1000, "stand": {"trees": 9, "mean_height_m": 6.0, "cover": 0.8,
                                     "lai": 3.0, "representation": "gap"},
            "nasa": {"ground_per_shot": 0.2, "canopy_per_shot": 0.8},
            "ours_twin": {"ground_per_shot": 0.1, "canopy_per_shot": 0.1},
            "like_with_like": {"real": {"ground": 0.25, "understorey": 0.25, "canopy": 0.5},
                               "twin": {"ground": 0.5, "understorey": 0.0, "canopy": 0.4}},
            "twin_truth": {"signal_per_shot": 0.3}}


def test_the_forest_pairs_rows_are_judged_against_its_twin(monkeypatch, tmp_path):
    """With signal shots the forest clip's ATL03 and ATL08 rows take their surface, signal and
    verdict from the pair's forest twin (studies.realism_forest); a doc of round numbers stands
    in for the rendering (forest_twin.twins), so each row's signal is exactly the doc's: ATL03
    the like-with-like layers' sums (1.0 real, 0.9 twin: x0.9), ATL08 NASA's ground + canopy
    against ours on the twin (1.0, 0.2: x0.2), the verdict by the matrix's ranges, the leak
    term from the twin's true signal (0.3 a shot). An ATL08 without its ATL03 beside it:
    surface missing."""
    import shutil
    from lidar_mitsuba.studies import forest_twin
    a03 = SHARED / "ATL03_gt1r_20220401_forest_wyoming.h5"
    a08 = SHARED / "ATL08_gt1r_20220401_forest_wyoming.h5"
    if not (a03.exists() and a08.exists()):
        pytest.skip(f"no forest clip at {SHARED}")
    monkeypatch.setattr(forest_twin, "twins", lambda paths, **kw: [_forest_doc(a03, a08)])
    monkeypatch.setattr(realism, "background_curve", dict)      # the figure's curve: not here
    doc = realism.run([a03, a08], None, signal_shots=1)
    assert [d["beam"] for d in doc["forest_twin"]] == ["gt1r"]
    by = {r["product"]: r for r in doc["rows"]}
    for product, real_sig, twin_sig in (("ATL03", 1.0, 0.9), ("ATL08", 1.0, 0.2)):
        r, lo, hi = by[product], *realism.SIGNAL_AGREES
        p = r["predicted"]
        assert p["surface"].startswith("forest twin (9 conifers") and not p["surface_missing"]
        assert r["measured"]["signal_forest"] == pytest.approx(real_sig)
        assert p["signal_per_shot"] == pytest.approx(twin_sig)
        assert r["signal_ratio"] == pytest.approx(twin_sig / real_sig)
        bg = r["background_ratio"]
        ok = lo <= r["signal_ratio"] <= hi and (bg is None or 0.5 <= bg <= 2.0)
        assert r["verdict"] == ("agrees" if ok else "disagrees")
        assert "shots" not in p                      # no flat-surface simulation under it
    assert by["ATL08"]["verdict"] == "disagrees" and "signal x0.20" in by["ATL08"]["reason"]
    # the leak term, S f_out / (2 H / c), takes the twin's true signal S: twice S, twice it
    twice = _forest_doc(a03, a08)
    twice["twin_truth"]["signal_per_shot"] = 0.6
    monkeypatch.setattr(forest_twin, "twins", lambda paths, **kw: [twice])
    again = {r["product"]: r for r in realism.run([a03, a08], None, signal_shots=1)["rows"]}
    leak = [d["ATL08"]["predicted"]["background_terms_hz"]["leak"] for d in (by, again)]
    assert leak[0] > 0 and leak[1] == pytest.approx(2 * leak[0], rel=1e-9)
    assert again["ATL08"]["predicted"]["signal_per_shot"] == pytest.approx(0.2)
    # the background over the twin's floor, whatever the product's surface: a snow floor
    # (a clip whose ATL08 says snow) lights the row's background with snow's albedo
    assert by["ATL03"]["predicted"]["sunlit_albedo"] == pytest.approx(0.10)     # litter
    snowy = _forest_doc(a03, a08)
    snowy["floor"] = "snow"
    monkeypatch.setattr(forest_twin, "twins", lambda paths, **kw: [snowy])
    lit = {r["product"]: r for r in realism.run([a03, a08], None, signal_shots=1)["rows"]}
    from lidar_mitsuba.vegetation.optics import snow_optics
    assert lit["ATL03"]["predicted"]["sunlit_albedo"] == pytest.approx(snow_optics().albedo)
    assert (lit["ATL03"]["predicted"]["background_terms_hz"]["solar"]
            > 5 * by["ATL03"]["predicted"]["background_terms_hz"]["solar"])
    lone = realism.run([shutil.copy(a08, tmp_path)], None, signal_shots=0)["rows"][0]
    assert lone["verdict"] == "surface missing" and "pair" in lone["reason"]


# ------------------------------------------------------------------------------ cloudy verdicts
def test_a_layers_backscatter_inside_the_band_is_its_share_below_the_top():
    """The share of a uniform layer's attenuated backscatter below a height: the closed form
    against the lidar equation's integral of beta exp(-2 eta s (top - z)) on 20 001 heights
    (trapezoids: error ~1e-9 here), 0 and 1 at the layer's ends; night's cloud term takes it."""
    c = Cloud(1.5, 500.0, 1500.0, multiple_scattering_eta=0.7)
    s, eta = c.extinction_per_m, c.multiple_scattering_eta
    z = np.linspace(c.base_m, c.top_m, 20001)
    y = np.exp(-2.0 * eta * s * (c.top_m - z))
    for cut in (600.0, 1000.0, 1400.0):
        k = z <= cut
        share = np.trapezoid(y[k], z[k]) / np.trapezoid(y, z)
        assert c.backscatter_share_below(cut) == pytest.approx(share, rel=1e-6)
    assert c.backscatter_share_below(400.0) == 0.0 and c.backscatter_share_below(2e3) == 1.0
    # its lower half: (exp(-eta tau) - exp(-2 eta tau)) / (1 - exp(-2 eta tau)), not 1/2
    e = math.exp(-eta * c.optical_depth)
    assert c.backscatter_share_below(1000.0) == pytest.approx(e / (1.0 + e), rel=1e-12)
    inst = Instrument.atlas()
    kw = dict(delta_time_s=np.array([3.5e7]), z_m=np.zeros(1), albedo=0.9,
              solar_elevation_deg=np.array([-30.0]), solar_azimuth_deg=np.zeros(1), leak_hz=0.0)
    whole = night.background_terms(inst, cloud=c, band=night.HistogramBand(
        top_above_surface_m=2500.0), **kw)["cloud"]
    part = night.background_terms(inst, cloud=c, band=night.HistogramBand(
        top_above_surface_m=1000.0), **kw)["cloud"]
    assert part == pytest.approx(whole * c.backscatter_share_below(1000.0), rel=1e-9)


def test_the_clouds_a_files_inputs_allow():
    """Each reflectance's depth -ln(r / 0.9) / 2 (no clear segment), the signal's from the
    segments that measure it, the layer above the band only where ATL09 found several layers
    and the lowest lies inside the band; a weak beam's layers are its flags' beam's."""
    from lidar_mitsuba.studies.realism_inputs import cloud_alternatives
    t_a, t_b, t_s = 1.5, 1.0, 0.6
    r = np.full(4, 0.9 * math.exp(-2 * t_a))
    r[0] = 0.9 * math.exp(-2 * t_s)                 # the one segment with a signal
    b = _beam(r, [False] * 4, [3] * 4)
    b.reflectance_photons = np.full(4, 0.9 * math.exp(-2 * t_b))
    b.signal_per_shot = np.array([1.0, np.nan, np.nan, np.nan])
    b.layer_count = np.array([2, 2, 2, 1.0])
    alts = cloud_alternatives(b, realism.implied_cloud(b), product="ATL07", band_top_m=2500.0)
    assert [(a["dataset"], a["above_band"]) for a in alts] == [
        ("asr_25", False), ("height_segment_asr_calc", False), ("asr_25", True),
        ("height_segment_asr_calc", True)]
    assert [a["circular"] for a in alts] == [False, True, False, True]
    assert alts[0]["cloud"].optical_depth == pytest.approx(t_a, abs=1e-3)
    assert alts[0]["signal_cloud"].optical_depth == pytest.approx(t_s, abs=1e-3)
    assert alts[1]["cloud"].optical_depth == pytest.approx(t_b, abs=1e-3)
    assert (alts[0]["cloud"].base_m, alts[0]["cloud"].top_m) == (500.0, 1500.0)
    assert (alts[2]["cloud"].base_m, alts[3]["cloud"].base_m) == (2500.0, 2500.0)
    assert alts[2]["cloud"].optical_depth == alts[0]["cloud"].optical_depth
    one = _beam(r, [False] * 4, [3] * 4)
    one.layer_count = np.ones(4)
    assert len(cloud_alternatives(one, realism.implied_cloud(one), product="ATL07",
                                  band_top_m=2500.0)) == 1
    # the weak beam's layers are its flags' beam's; a layer above the band stays one
    assert len(cloud_alternatives(one, realism.implied_cloud(one), product="ATL07",
                                  band_top_m=2500.0, flags=b)) == 2
    high = _beam(r, [False] * 4, [1] * 4)
    high.layer_count = np.full(4, 2.0)
    assert len(cloud_alternatives(high, realism.implied_cloud(high), product="ATL07",
                                  band_top_m=2500.0)) == 1


def _cloudy_row(preds, measured, *, circular=(False, True), above=None):
    """A row of a beam all cloudy: ``preds`` [(signal, background Hz)] over its clouds (the
    matrix's first), ``measured`` (signal, background Hz)."""
    above = above or [False] * len(preds)
    alts = [{"dataset": ("asr_25", "height_segment_asr_calc")[k % 2], "from": "test",
             "circular": circular[k % 2], "above_band": above[k], "optical_depth": 1.0 + k,
             "base_m": 500.0 if not above[k] else 2500.0, "top_m": 1500.0,
             "signal": s, "background_hz": bg} for k, (s, bg) in enumerate(preds)]
    return {"product": "ATL07", "cloud": {"from": "the file's reflectance", "optical_depth": 1.0},
            "measured": {"signal_cloudy": measured[0], "background_cloudy_hz": measured[1]},
            "predicted": {"signal_cloudy": preds[0][0], "background_cloudy_hz": preds[0][1],
                          "cloud_alternatives": alts}}


def test_a_cloudy_beams_verdict_brackets_the_clouds_its_file_allows():
    """agrees with the matrix's cloud; cloud uncertain where the clouds' predictions are
    further apart than the agreement range tells apart and the measurement lies in their
    bracket; disagrees where no cloud of the bracket can agree, or where they pin it down."""
    from lidar_mitsuba.studies.realism_cloudy import cloudy_verdict, judge, spread_limit
    assert spread_limit(realism.BACKGROUND_AGREES) == 2.0
    assert spread_limit(realism.SIGNAL_AGREES) == 1.4
    j = judge([0.5, 1.2], 1.0, realism.SIGNAL_AGREES)
    assert (j["ratio"], j["lo"], j["hi"], j["agrees"], j["reaches"], j["wide"]) == (
        0.5, 0.5, 1.2, False, True, True)
    assert judge([1.0], None, realism.SIGNAL_AGREES) is None
    v, why = cloudy_verdict(_cloudy_row([(1.0, 1e4), (1.9, 1e4)], (1.1, 1e4)))
    assert v == "agrees" and "signal x0.91" in why and "signal x0.91-1.73" in why
    v, why = cloudy_verdict(_cloudy_row([(0.5, 1e4), (1.1, 1e4)], (1.0, 1e4)))
    assert v == "cloud uncertain" and "asr_25" in why and "height_segment_asr_calc" in why
    assert "tau 1" in why and "tau 2" in why and "signal x0.50-1.10" in why
    v, why = cloudy_verdict(_cloudy_row([(0.5, 1e4), (0.6, 1e4)], (1.0, 1e4)))
    assert v == "disagrees" and "signal x0.50" in why          # pinned down (1.2 apart)
    v, why = cloudy_verdict(_cloudy_row([(0.2, 1e4), (0.5, 1e4)], (1.0, 1e4)))
    assert v == "disagrees"                                     # no cloud reaches 0.7
    # the background: all in the lowest layer or above the band (not in the file)
    v, why = cloudy_verdict(_cloudy_row([(1.0, 3e4), (1.0, 2e3)], (1.0, 5e3),
                                        circular=(False, False), above=[False, True]))
    assert v == "cloud uncertain" and "background x0.40-6.00" in why and "above it" in why
    v, why = cloudy_verdict(_cloudy_row([(1.0, 3e4), (1.0, 2e4)], (1.0, 5e3),
                                        circular=(False, False), above=[False, True]))
    assert v == "disagrees" and "background x6.00" in why
