"""Clouds in every run (lidar_mitsuba.atmosphere.cloud_layer, .cloud_kernel, products.cloud_flags).

Monte Carlo checks compare means over iid shots with their closed form or an independent
trace within four standard errors (the SE from the spread of the per-shot values, or the
binomial formula where a count is binomial). Fixed seeds.
"""
import math
import pathlib

import h5py
import numpy as np
import pytest

import lidar_mitsuba as lm
from lidar_mitsuba.atmosphere import cloud_kernel as ck
from lidar_mitsuba.atmosphere.cloud_layer import Cloud, CloudClimatology
from lidar_mitsuba.constants import ParameterError
from lidar_mitsuba.geotrack import Site
from lidar_mitsuba.products import atl06, cloud_flags, h5write

NIGHT = Site(epoch_utc="2019-12-21T04:00:00Z")       # polar night: no sun
PLATE = {"type": "scene", "ground": {"type": "rectangle",
                                     "to_world": lm.ensure_renderer().ScalarTransform4f()
                                     .scale([5000, 5000, 1]),
                                     "bsdf": {"type": "diffuse", "reflectance":
                                              {"type": "uniform", "value": 0.9}}}}


@pytest.mark.parametrize("kw,name", [
    (dict(optical_depth=-1, base_m=0, top_m=1), "cloud_od"),
    (dict(optical_depth=float("nan"), base_m=0, top_m=1), "cloud_od"),
    (dict(optical_depth=1, base_m=-5, top_m=1), "cloud_base_m"),
    (dict(optical_depth=1, base_m=500, top_m=400), "cloud_top_m"),
    (dict(optical_depth=1, base_m=0, top_m=1, g=1.0), "cloud_g"),
    (dict(optical_depth=1, base_m=0, top_m=1, single_scattering_albedo=0), "cloud_albedo"),
])
def test_a_bad_cloud_is_named(kw, name):
    with pytest.raises(ParameterError) as e:
        Cloud(**kw)
    assert e.value.name == name


def test_closed_forms_of_the_layer():
    c = Cloud.water(1.0, 1000.0, 1500.0)
    assert c.two_way_transmission == pytest.approx(math.exp(-2))
    # two-stream, conservative (Bohren 1987): R + T = 1; R = (1-g) tau / (2 + (1-g) tau)
    assert c.diffuse_reflectance + c.diffuse_transmittance == pytest.approx(1.0)
    assert c.diffuse_reflectance == pytest.approx(0.15 / 2.15)
    assert Cloud.water(0.0, 1, 2).system_albedo(0.3) == pytest.approx(0.3)   # clear: the ground
    thick = Cloud.water(20.0, 1, 2)
    assert thick.system_albedo(0.05) > 0.55 > Cloud.water(1.0, 1, 2).system_albedo(0.05)
    # a white (A = 1) surface under a conservative cloud: the system stays white
    assert Cloud.water(3.0, 1, 2).system_albedo(1.0) == pytest.approx(1.0)
    # backscatter: the lidar equation integrated over the layer, beta = sigma / S
    s = c.extinction_per_m
    whole = math.pi / 0.9 * s / 18.8 * (1 - math.exp(-2)) / (2 * s)
    assert c.backscatter_weight(-1e9, 1e9) == pytest.approx(whole)
    assert c.backscatter_weight(-15, 15) == 0.0               # above a 30 m gate
    z = c.backscatter_heights_m(np.random.default_rng(1).random(200_000), 1000, 1500)
    # the profile exp(-2 s (top - z)): its mean height, in closed form
    a = 2 * s
    mean = 1500 - (1 / a - 500 * math.exp(-a * 500) / (1 - math.exp(-a * 500)))
    assert abs(z.mean() - mean) < 4 * z.std() / math.sqrt(z.size)


def test_the_table_s_unscattered_light_is_two_way_beer_lambert():
    """Each path reaches the ground unscattered with probability exp(-tau) and then weighs
    exp(-tau) (the way up, by Beer-Lambert): a binomial count, SE
    exp(-tau) sqrt(p (1 - p) / N) with p = exp(-tau)."""
    c = Cloud.water(0.7, 200.0, 400.0)
    tab = ck.table(c, altitude_m=496e3, footprint_sigma_m=2.7, fov_radius_m=22.5,
                   shots=400, paths_per_shot=64, seed=3)
    p, n = math.exp(-0.7), 400 * 64
    se = p * math.sqrt(p * (1 - p) / n)
    assert abs(tab.traced_direct - math.exp(-1.4)) < 4 * se, (tab.traced_direct, se)
    assert tab.direct == math.exp(-1.4)
    assert tab.forward > 4 * tab.forward_se                  # light scattered into view
    assert np.all(np.diff(tab.delay_ns) >= 0) and tab.delay_ns[0] >= 0


#: the paper's weak beam with an ideal, noiseless detector (no link budget: no sun)
IDEAL = lm.Instrument(beam="weak", ideal_detector=True, background_mhz=0.0, dark_count_hz=0.0)


@pytest.fixture
def small_tables(monkeypatch):
    """Kernel tables of 64 000 paths (a quarter of a run's): the tests add their SE."""
    monkeypatch.setattr(ck, "SHOTS", 1000)
    monkeypatch.setattr(ck, "PATHS", 64)


def _night(**kw):
    return lm.simulate(instrument=IDEAL, progress=False, site=NIGHT, keep_returns=False,
                       paths_per_shot=128, **kw)


def _stats(res):
    """Detected signal photons per shot and the mean dh of the signal, with SEs over shots."""
    d = res.detections
    sig = d.is_signal
    n = res.n_shots
    counts = np.bincount(d.shot[sig], minlength=n).astype(float)
    dh = res.dh_m[sig]
    s = np.bincount(d.shot[sig], weights=dh, minlength=n)
    m = s.sum() / counts.sum()
    r = s - m * counts
    return (counts.mean(), counts.std(ddof=1) / math.sqrt(n),
            m, math.sqrt(n / (n - 1) * np.sum(r * r)) / counts.sum())


@pytest.mark.filterwarnings("ignore:.*too few paths")    # (the full trace's shared paths)
def test_the_kernel_matches_the_full_media_trace(small_tables):
    """A low cloud (100-200 m, tau 0.5: a quarter of the ground's light arrives scattered,
    late by up to metres) over a Lambertian 0.9 plate: the run with the cloud as a kernel on
    the clear plate against the run that traces the layer itself (mediapathlength), ideal
    detector, independent seeds: detected signal per shot and mean elevation agree within
    four combined SEs (the kernel's own table error is added: its forward part's SE)."""
    c = Cloud.water(0.5, 100.0, 200.0)
    shots = 800
    full = _night(scene=ck.layer_scene_dict(c), shots=shots, seed=11)
    cheap = _night(scene=PLATE, cloud=c, shots=shots, seed=12)
    assert full.config["integrator"] == "mediapathlength"
    assert cheap.config["integrator"] == "pathlength" and "cloud" in cheap.config
    nf, nf_se, hf, hf_se = _stats(full)
    nc, nc_se, hc, hc_se = _stats(cheap)
    tab = ck.table_for(c, cheap.instrument)
    assert tab.forward / tab.total > 0.15          # forward scattering matters here
    rel = tab.forward_se / tab.total
    assert abs(nc - nf) < 4 * math.hypot(nc_se, nf_se, rel * nf), (nc, nf)
    assert hf < -0.05 and hc < -0.05               # the surface appears lower
    assert abs(hc - hf) < 4 * math.hypot(hc_se, hf_se) + 0.01, (hc, hf)


def test_clear_sky_is_unchanged_to_the_bit():
    """A cloud of optical depth 0 (or none) leaves the run as it was."""
    kw = dict(surface=lm.SurfaceSpec(kind="flat"), shots=300, seed=4)
    a, b = _night(**kw), _night(cloud=Cloud.water(0.0, 1000.0, 1500.0), **kw)
    assert np.array_equal(a.h_m, b.h_m) and np.array_equal(a.detections.shot,
                                                           b.detections.shot)
    assert "cloud" not in a.config and "cloud" not in b.config


def test_r_eff_is_the_albedo_clear_and_under_a_cloud(small_tables):
    """A Lambertian 0.6 plate, the paper's strong beam, ideal detector, no noise: r_eff
    (ATL06's fpb_n_corr / n_seg_pulses / N1) is 0.6 in clear sky and 0.6 (exp(-2 tau) + F)
    under a cloud 3-3.5 km up (F, its forward light in view, ~1e-3 here), within 4 SE of the
    segments' mean; the flags say clear and cloudy."""
    bsdf = {"type": "diffuse", "reflectance": {"type": "uniform", "value": 0.6}}
    inst = lm.Instrument(ideal_detector=True, background_mhz=0.0, dark_count_hz=0.0)
    out = {}
    for tau in (0.0, 0.5):
        res = lm.simulate(instrument=inst, surface=lm.SurfaceSpec(kind="flat"), bsdf=bsdf,
                          shots=3000, seed=5, progress=False, site=NIGHT,
                          cloud=Cloud.water(tau, 3000.0, 3500.0))
        cols = cloud_flags.atl06_columns(atl06.segments_from_result(res),
                                         cloud_flags.sky_of(res))
        r = cols["r_eff"]
        assert np.all(np.isfinite(r))
        out[tau] = (r.mean(), r.std(ddof=1) / math.sqrt(r.size), cols)
    m0, se0, c0 = out[0.0]
    assert abs(m0 - 0.6) < 4 * se0, (m0, se0)
    tab = ck.table_for(Cloud.water(0.5, 3000.0, 3500.0), inst)
    m1, se1, c1 = out[0.5]
    assert abs(m1 - 0.6 * tab.total) < 4 * se1, (m1, se1, tab.total)
    assert abs(tab.total - math.exp(-1.0)) < 0.01            # exp(-2 tau) + a little
    # expected reflectance 0.9 (no link budget): 0.6 / 0.9 = 0.67 -> "cloudy, low";
    # ratio 0.22 -> "cloudy, high"; atm: the run's cloud layers
    assert np.median(c0["cloud_flg_asr"]) == 3 and np.median(c1["cloud_flg_asr"]) == 5
    assert c0["cloud_flg_atm"].max() == 0 and c1["cloud_flg_atm"].min() == 1


def test_flags_are_written_as_atl06_and_atl07_write_them(tmp_path):
    """Names, types and attributes as in the real files (ATL06 v001-v005, ATL07 v003)."""
    from lidar_mitsuba.products import atl07
    table_cols = {"r_eff": np.array([0.95, 0.4, np.nan]),
                  "cloud_flg_asr": cloud_flags.asr_flag([0.95, 0.4, np.nan], 1.0),
                  "cloud_flg_atm": np.array([0, 1, 1], np.int8)}
    assert list(table_cols["cloud_flg_asr"]) == [0, 4, 127]
    tau = cloud_flags.implied_optical_depth([0.9 * math.exp(-1.0), 1.0, np.nan], 0.9)
    assert tau[0] == pytest.approx(0.5) and tau[1] == 0.0 and np.isnan(tau[2])
    seg = atl07.segments(h_m=np.zeros(300), shot=np.repeat(np.arange(100), 3),
                         along_m=np.repeat(np.arange(100) * 0.7, 3), photons_per_segment=150)
    c7 = cloud_flags.atl07_columns(seg, {"unit_photons": 10.0, "expected_reflectance": 0.9,
                                         "layers": 1})
    assert np.allclose(c7["asr_25"], seg.photon_rate / 10.0)
    with h5py.File(tmp_path / "f.h5", "w") as f:
        cloud_flags.put_atl06(f.create_group("geophysical"), table_cols)
        cloud_flags.put_atl06(f["geophysical"], table_cols)          # a second section
        cloud_flags.put_atl07(f.create_group("stats"), c7)
        h5write.drain(f)                   # (rows are stored in the background)
    with h5py.File(tmp_path / "f.h5") as f:
        g = f["geophysical"]
        assert g["r_eff"].dtype == np.float32 and g["r_eff"].shape == (6,)
        assert g["cloud_flg_asr"].dtype == np.int8 and g["cloud_flg_atm"].dtype == np.int8
        assert g["cloud_flg_asr"].attrs["_FillValue"] == 127
        assert g["r_eff"][2] == np.finfo(np.float32).max
        assert g["cloud_flg_asr"].attrs["flag_meanings"].split()[5] == \
            "cloudy_with_high_confidence"
        s = f["stats"]
        assert s["asr_25"].dtype == np.float32 and s["cloud_flag_asr"].dtype == np.int16
        assert s["cloud_flag_atm"].dtype == np.int8 and s["cloud_flag_atm"][0] == 1


def test_climatology_draws_are_seeded_and_checked():
    clim = CloudClimatology(cloud_fraction=0.5, optical_depth_median=1.0,
                            optical_depth_log_sigma=0.5)
    draws = [clim.draw(np.random.default_rng([s, 1])) for s in range(400)]
    assert draws == [clim.draw(np.random.default_rng([s, 1])) for s in range(400)]
    cloudy = [d for d in draws if d is not None]
    # binomial(400, 0.5): 4 SE = 40
    assert abs(len(cloudy) - 200) < 40
    assert abs(np.median([d.optical_depth for d in cloudy]) - 1.0) < 0.25
    with pytest.raises(ParameterError) as e:
        CloudClimatology(cloud_fraction=1.5)
    assert e.value.name == "cloud_fraction"


def test_campaign_spec_cloud_section():
    from lidar_mitsuba.campaign.granules import granule_cloud
    from lidar_mitsuba.campaign.spec import _cloud
    from lidar_mitsuba.sweep import SpecError
    assert _cloud({}) is None
    fixed = _cloud({"cloud": {"optical_depth": 0.5, "base_m": 800.0, "top_m": 900.0}})
    assert granule_cloud({"cloud": fixed, "seed": 1}) == Cloud.water(0.5, 800.0, 900.0)
    clim = _cloud({"cloud": {"fraction": 1.0, "optical_depth_median": 2.0,
                             "optical_depth_log_sigma": 0.0, "phase": "ice"}})
    assert granule_cloud({"cloud": clim, "seed": 7}) == Cloud.ice(2.0, 1000.0, 1500.0)
    for bad, key in (({"optical_depth": -1}, "[cloud] optical_depth"),
                     ({"optical_depth": 1, "fraction": 0.5}, "[cloud]"),
                     ({"fraction": 2.0}, "[cloud] fraction"),
                     ({"optical_depth": 1, "colour": 1}, "[cloud] colour")):
        with pytest.raises(SpecError) as e:
            _cloud({"cloud": bad})
        assert str(e.value).startswith(key), str(e.value)


@pytest.mark.parametrize("args,option", [
    (["--cloud-base-m", "100"], "--cloud-base-m"),
    (["--cloud-od", "-1"], "--cloud-od"),
    (["--cloud-od", "1", "--cloud-base-m", "500", "--cloud-top-m", "100"], "--cloud-top-m"),
    (["--cloud-od", "1", "--cloud-g", "1.5"], "--cloud-g"),
])
def test_bad_cloud_options_one_line(tmp_path, capsys, args, option):
    from lidar_mitsuba.cli import main
    try:
        code = main(["simulate", "--shots", "5", "--out", str(tmp_path / "o.h5"), *args,
                     "--no-progress"])
    except SystemExit as e:
        code = e.code
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and option in err, err
    assert not (tmp_path / "o.h5").exists()


def test_cli_cloud_runs(tmp_path, capsys, small_tables):
    """The guide's commands (docs/guide/clouds.md) at 100 shots: a built-in surface and a
    real granule's twin under a cloud, with ATL06's cloud flags written."""
    from lidar_mitsuba.cli import main
    out = tmp_path / "cloudy.h5"
    assert main(["simulate", "--instrument", "atlas", "--surface", "flat", "--cloud-od", "1",
                 "--cloud-base-m", "1000", "--cloud-top-m", "1500", "--shots", "100",
                 "--out", str(out), "--explain", "--no-progress"]) == 0
    assert "cloud: a water cloud 1000-1500 m" in capsys.readouterr().out and out.exists()
    a6 = tmp_path / "twin_cloud_atl06.h5"
    real = pathlib.Path(__file__).resolve().parents[1] / "lidar_mitsuba/data/ATL03_gt1l_20181014.h5"
    assert main(["simulate", "--like", str(real),
                 "--cloud-od", "0.5", "--cloud-base-m", "800", "--cloud-top-m", "1200",
                 "--shots", "100", "--out", str(tmp_path / "twin_cloud.h5"), "--atl06",
                 str(a6), "--no-progress"]) == 0
    with h5py.File(a6) as f:
        g = f["gt1l/land_ice_segments/geophysical"]
        assert np.all(g["cloud_flg_atm"][:] == 1) and g["r_eff"].dtype == np.float32


def test_a_cloud_in_the_range_gate_is_flagged(small_tables):
    """Fog reaching into the gate: the kernel's known limit (the guide's chart) is said."""
    with pytest.warns(lm.SimulationWarning, match="inside the range gate"):
        res = _night(surface=lm.SurfaceSpec(kind="flat"), shots=100, seed=2,
                     cloud=Cloud.water(0.5, 5.0, 60.0))
    assert any("inside the range gate" in w for w in res.config["warnings"])
