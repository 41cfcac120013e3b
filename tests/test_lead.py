"""An open lead in sea ice: the ATL07-like finder (``lidar_mitsuba.products.atl07``) on synthetic
photons with exact answers, and the lead study (``lidar_mitsuba.studies.lead`` on
``scenes/lead.xml``) against closed forms.

Tolerances (all 4 standard errors: a false alarm about once in 16 000 checks):

* glint: the detected signal count over N shots is a sum of independent Poisson counts
  (an ideal detector thins each shot's Poisson photons by fill factor and PDE, which keeps
  them Poisson), so its SE is sqrt(count), and that of the photons per shot sqrt(count) / N.
  The shots' Poisson means are themselves Monte Carlo estimates from the traced paths; the
  path budget keeps their extra variance under 1 % of the Poisson variance (the run reports
  0.03 %), so the SE is inflated by sqrt(1.01).
* bias: the mean of h - truth over the signal photons, its SE clustered by shot (a shot's
  photons share its dead channels): sqrt(sum_s r_s^2) / N, r_s the shot's summed residuals.
* freeboard: the retrieved (median) freeboard differs from the truth by the dead time's
  *differential* first-photon bias: the lead's glint puts more photons into each channel
  (lambda 1.2 against the floe's 0.72 for ATLAS's strong beam), so the first photon of a
  channel sits higher over the water, and the sea surface is read high. The closed form
  (median of the first of Poisson(lambda) Gaussian heights, -1.3 cm here) is exact for a
  Gaussian pulse on flat surfaces; the statistical part is the SE of the floes' median
  freeboard and of the sea surface's mean (from the segments' own scatter).

Runs: about 15 s on 2 cores (11 short simulations, fixed seeds).
"""
import math
import subprocess
import sys

import mitsuba as mi
import numpy as np
import pytest

import lidar_mitsuba  # noqa: F401 (variant, plugins)
from lidar_mitsuba.products import atl07
from lidar_mitsuba.trace import scene as scn
from lidar_mitsuba.instrument import Instrument
from lidar_mitsuba.studies import lead

Z = 4.0
SPACING = 0.7


# ------------------------------------------------------------------ the finder, synthetic
def _region(first_shot, n_shots, per_shot, offsets_m, h_m):
    """Photons of ``n_shots`` shots from ``first_shot``, ``per_shot`` each, at heights
    ``h_m`` (a number, or one per shot) plus the symmetric ``offsets_m``."""
    shots = np.repeat(np.arange(first_shot, first_shot + n_shots), per_shot)
    base = np.broadcast_to(np.asarray(h_m, float), (n_shots,))
    h = np.repeat(base, per_shot) + np.tile(offsets_m, n_shots)
    return shots, h


FLOE_OFF = np.array([-0.02, -0.01, 0.0, 0.01, 0.02])            # 5 photons per shot
LEAD_OFF = np.array([-0.009, -0.007, -0.005, -0.003, -0.001,     # 10 photons per shot
                     0.001, 0.003, 0.005, 0.007, 0.009])


def _synthetic():
    """Floe A (120 shots x 5 photons at 0.40 m: 4 segments of 30 shots), lead B (60 shots x
    10 photons: 4 segments of 15 shots, the first and last at 0.03 m as if they straddled
    the floe edges, the middle two at 0.00 m), floe C (120 x 5 at 0.40), lead D (30 x 10 at
    0.10 m: a sea surface 10 cm higher; 2 segments, too short to trim), floe E (120 x 5 at
    0.45)."""
    edge = np.r_[np.full(15, 0.03), np.zeros(30), np.full(15, 0.03)]
    parts = [_region(0, 120, 5, FLOE_OFF, 0.40), _region(120, 60, 10, LEAD_OFF, edge),
             _region(180, 120, 5, FLOE_OFF, 0.40), _region(300, 30, 10, LEAD_OFF, 0.10),
             _region(330, 120, 5, FLOE_OFF, 0.45)]
    shot = np.concatenate([p[0] for p in parts])
    h = np.concatenate([p[1] for p in parts])
    return shot, h, shot * SPACING


def test_segments_are_exact_on_synthetic_photons():
    shot, h, along = _synthetic()
    seg = atl07.segments(h_m=h, shot=shot, along_m=along)
    assert len(seg) == 18 and np.all(seg.n_photons == 150)
    shots_per = np.r_[[30] * 4, [15] * 4, [30] * 4, [15] * 2, [30] * 4]
    first = np.concatenate([[0], np.cumsum(shots_per)[:-1]])
    assert np.array_equal(seg.n_shots, shots_per)
    assert np.allclose(seg.photon_rate, 150 / shots_per, rtol=0, atol=1e-12)
    # equal photons per shot: the mean photon position is the mid-shot's
    assert np.allclose(seg.along_m, SPACING * (first + (shots_per - 1) / 2), atol=1e-9)
    expect_h = np.r_[[0.40] * 4, 0.03, 0.0, 0.0, 0.03, [0.40] * 4, 0.10, 0.10, [0.45] * 4]
    assert np.allclose(seg.h_m, expect_h, atol=1e-12)
    # robust spread: the quartiles of 150 photons, 30 at each floe offset
    q25, q75 = np.quantile(np.tile(FLOE_OFF, 30), [0.25, 0.75])
    assert seg.h_sigma_m[0] == pytest.approx((q75 - q25) / atl07.IQR_PER_SIGMA, abs=1e-12)
    assert seg.h_se_m[0] == pytest.approx(
        math.sqrt(math.pi / 2) * seg.h_sigma_m[0] / math.sqrt(150), rel=1e-12)


def test_leads_sea_surface_and_freeboard_are_exact():
    shot, h, along = _synthetic()
    seg = atl07.segments(h_m=h, shot=shot, along_m=along)
    # a 60 m window: each lead's neighbourhood holds floes and that lead only
    lead = atl07.flag_leads(seg, window_m=60.0)
    truth = np.zeros(18, bool)
    truth[4:8] = truth[12:14] = True
    assert np.array_equal(lead, truth)
    assert atl07.lead_runs(lead) == [(4, 8), (12, 14)]
    x, ssh, used = atl07.lead_heights(seg, lead)
    assert np.array_equal(used, [2, 2])                         # B trimmed, D not
    assert np.allclose(ssh, [0.0, 0.10], atol=1e-12)
    assert np.allclose(x, [seg.along_m[5:7].mean(), seg.along_m[12:14].mean()], atol=1e-12)
    fb = atl07.freeboard(seg, lead)
    expect_ssh = np.interp(seg.along_m, x, [0.0, 0.10])         # constant beyond the ends
    assert np.allclose(fb, seg.h_m - expect_ssh, atol=1e-12)
    assert np.allclose(fb[:4], 0.40) and np.allclose(fb[14:], 0.35)
    # without trimming the edge segments lift lead B's sea surface by half their 3 cm
    untrimmed = atl07.lead_heights(seg, lead, trim_ends=False)[1]
    assert untrimmed[0] == pytest.approx(0.015, abs=1e-12)
    # the wide window sees lead B's 0.00 m as the minimum: lead D (0.10 m) is then too high
    assert np.array_equal(atl07.flag_leads(seg), truth & (np.arange(18) < 8))


def test_fractional_shots_dark_leads_and_edge_cases():
    # 4 photons a shot: a segment spans 37.5 shots, its end shots shared by fraction
    shot = np.repeat(np.arange(300), 4)
    seg = atl07.segments(h_m=np.zeros(shot.size), shot=shot, along_m=shot * SPACING)
    assert len(seg) == 8 and np.allclose(seg.n_shots, 37.5, atol=1e-12)
    assert np.allclose(seg.photon_rate, 4.0, atol=1e-12)
    assert seg.n_shots.sum() == pytest.approx(300.0)              # every shot counted once
    # a dark lead: half the floes' rate, at the local minimum; off by default
    s1, h1 = _region(0, 150, 5, FLOE_OFF, 0.3)
    s2, h2 = _region(150, 75, 2, np.array([-0.01, 0.01]), 0.0)
    s3, h3 = _region(225, 150, 5, FLOE_OFF, 0.3)
    shot = np.concatenate([s1, s2, s3])
    seg = atl07.segments(h_m=np.concatenate([h1, h2, h3]), shot=shot, along_m=shot * SPACING)
    assert not atl07.flag_leads(seg).any()
    dark = atl07.flag_leads(seg, dark_ratio=0.6)
    assert dark.sum() == 1 and seg.photon_rate[dark][0] == pytest.approx(2.0)
    assert np.allclose(atl07.freeboard(seg, dark)[~dark], 0.3, atol=1e-12)
    # no lead: NaN; too few photons: no segment; bad input: ValueError naming it
    assert np.all(np.isnan(atl07.freeboard(seg, np.zeros(len(seg), bool))))
    assert len(atl07.segments(h_m=np.zeros(149), shot=np.zeros(149, int),
                              along_m=np.zeros(149))) == 0
    with pytest.raises(ValueError, match="non-decreasing"):
        atl07.segments(h_m=np.zeros(3), shot=[2, 1, 0], along_m=np.zeros(3),
                       photons_per_segment=1)
    with pytest.raises(ValueError, match="photons_per_segment"):
        atl07.segments(h_m=np.zeros(3), shot=np.zeros(3), along_m=np.zeros(3),
                       photons_per_segment=0)


def test_atl07_imports_no_mitsuba():
    """lidar_mitsuba/products/atl07.py executed on its own leaves mitsuba and drjit unimported."""
    code = ("import importlib.util, sys\n"
            f"spec = importlib.util.spec_from_file_location('a', {atl07.__file__!r})\n"
            "m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m)\n"
            "print(m.PHOTONS_PER_SEGMENT, 'mitsuba' in sys.modules, 'drjit' in sys.modules)")
    out = subprocess.run([sys.executable, "-I", "-c", code], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["150", "False", "False"]


def test_first_photon_closed_form_against_sampling():
    """The first of Poisson(lam) Gaussian heights: mean and median of the closed form against
    200 000 sampled channel-shots (numpy), within 4 SE."""
    rng = np.random.default_rng(7)
    for lam in (0.4, 1.2):
        k = rng.poisson(lam, 200_000)
        k = k[k > 0]
        z = rng.standard_normal((k.size, k.max()))
        z[np.arange(k.max())[None, :] >= k[:, None]] = -np.inf
        first = z.max(axis=1)
        se = first.std() / math.sqrt(first.size)
        assert abs(first.mean() - lead.first_photon_bias_m(lam, 1.0)) < Z * se
        med = lead.first_photon_bias_m(lam, 1.0, statistic="median")
        assert abs(np.median(first) - med) < Z * 1.26 * se
    assert lead.first_photon_bias_m(0.0, 1.0) == 0.0


# ------------------------------------------------------------------ the scene
def test_scene_geometry():
    """Heights under the track: water at 0 in the lead, the floes at freeboard_m, the edges
    at +-lead_width_m / 2."""
    for width, fb in ((100, 0.3), (240, 0.12)):
        scene = mi.load_file(str(lead.SCENE), lead_width_m=str(width), freeboard_m=str(fb))
        x = np.array([-640.0, -width / 2 - 0.5, -width / 2 + 0.5, 0.0, width / 2 - 0.5,
                      width / 2 + 0.5, 640.0])
        z = scn.cast_heights_m(scene, x, np.zeros_like(x))
        assert np.allclose(z, [fb, fb, 0, 0, 0, fb, fb], atol=1e-5)


# ------------------------------------------------------------------ the study
@pytest.fixture(scope="module")
def glint_rows():
    return lead.glint(shots=1000, seed=1)


@pytest.fixture(scope="module")
def saturation_rows():
    return lead.saturation(shots=1000, seed=2, instruments={
        "atlas": Instrument.atlas("strong", **lead.ATLAS_GAUSSIAN),
        "ideal": Instrument.atlas("strong", ideal_detector=True, **lead.ATLAS_GAUSSIAN)})


@pytest.fixture(scope="module")
def freeboard_rows():
    return lead.freeboard_retrieval(shots=1600, seed=3)


def test_glint_follows_cox_munk(glint_rows):
    assert [r["wind_mps"] for r in glint_rows] == [0.0, 2.0, 5.0, 10.0]
    for r in glint_rows:
        # the shots' Poisson means are the closed form (paths' weights barely vary at nadir)
        assert r["mu_traced"] == pytest.approx(r["mu_closed"], rel=2e-3)
        se = r["detected_se"] * math.sqrt(1.01)
        assert abs(r["detected"] - r["detected_closed"]) < Z * se, r
    mu = [r["mu_traced"] for r in glint_rows]
    assert all(a > b for a, b in zip(mu, mu[1:]))                 # rougher is dimmer
    # calm water outshines the plate (1.9) and the snow; 2 m/s is already darker than both
    assert glint_rows[0]["weight_closed"] == pytest.approx(1.912, abs=2e-3)
    assert glint_rows[1]["weight_closed"] < 1.0


def _row(rows, instrument, surface):
    return next(r for r in rows if r["instrument"] == instrument and r["surface"] == surface)


def test_calm_lead_is_brighter_and_more_biased_than_the_floe(saturation_rows):
    for name in ("atlas", "ideal"):
        w, f = _row(saturation_rows, name, "lead"), _row(saturation_rows, name, "floe")
        assert w["detected_per_shot"] - f["detected_per_shot"] > Z * math.hypot(
            w["detected_se"], f["detected_se"])
    w, f = _row(saturation_rows, "atlas", "lead"), _row(saturation_rows, "atlas", "floe")
    # first-photon bias toward the satellite, larger over the brighter water
    assert w["bias_m"] > Z * w["bias_se_m"] and f["bias_m"] > Z * f["bias_se_m"]
    assert w["bias_m"] - f["bias_m"] > Z * math.hypot(w["bias_se_m"], f["bias_se_m"])
    for r in (w, f):     # ... as the closed form of a dead time longer than the pulse says
        assert abs(r["bias_m"] - r["bias_closed_m"]) < Z * r["bias_se_m"], r
        assert abs(r["detected_per_shot"] - r["detected_closed"]) < Z * r["detected_se"], r
        assert r["channels_fired"] < 1 and r["saturated"] < 0.02
    # the dead time costs the lead ~40 % of its photons; an ideal detector is unbiased
    iw = _row(saturation_rows, "ideal", "lead")
    assert w["detected_per_shot"] < 0.65 * iw["detected_per_shot"]
    for s in ("lead", "floe"):
        r = _row(saturation_rows, "ideal", s)
        assert abs(r["bias_m"]) < Z * r["bias_se_m"], r


def test_freeboard_from_the_photons(freeboard_rows):
    assert [r["freeboard_true_m"] for r in freeboard_rows] == [0.1, 0.3, 0.5]
    for r in freeboard_rows:
        # every flagged segment is over the water, and the lead is found (one run, at most
        # its two edge segments missed)
        assert r["leads"] == r["leads_over_water"] >= r["water_segments"] - 2, r
        assert r["lead_runs"] == 1 and r["error_closed_m"] < 0
        assert abs(r["error_m"] - r["error_closed_m"]) < Z * r["freeboard_se_m"], r
        assert abs(r["error_m"]) < 0.03


def test_plot(glint_rows, saturation_rows, freeboard_rows, tmp_path):
    doc = {"glint": glint_rows, "saturation": saturation_rows, "freeboard": freeboard_rows}
    fig = lead.plot(doc, tmp_path / "lead.png")
    assert (tmp_path / "lead.png").stat().st_size > 10_000 and len(fig.axes) == 3
