"""The BRDF comparison sweep: finite rows, the Lambertian closed form, plotting.

The Lambertian 0.9 plate at nadir returns weight exactly 1 per traced path, so with an ideal
detector each shot's detected photons are Poisson with mean signal_photons * fill_factor * pde:
the sweep's photons per shot must match it within Z = 4.5 standard errors.
"""
import json
import math

import matplotlib.figure
import numpy as np
import pytest

from lidar_mitsuba.studies import brdf_variants as compare
from lidar_mitsuba.instrument import Instrument
from lidar_mitsuba.ground.surface import SurfaceSpec

Z = 4.5


@pytest.fixture(scope="module")
def rows():
    surfaces = (compare.slope_surfaces(slopes_deg=(0, 20))
                + compare.fractal_surfaces(ps=(1.8,), size_m=64.0, relief_m=2.0))
    return compare.sweep(variants=compare.BRDF_VARIANTS, surfaces=surfaces, shots=60, seed=3,
                         beam="strong")


def test_rows_complete_and_finite(rows):
    assert len(rows) == 3 * len(compare.BRDF_VARIANTS)
    assert [r["variant"] for r in rows[:len(compare.BRDF_VARIANTS)]] == list(compare.BRDF_VARIANTS)
    for r in rows:
        assert r["shots"] == 60 and r["beam"] == "strong" and not r["ideal_detector"]
        assert r["n_photons"] > 10, r
        for key in compare.ROW_FIELDS:
            assert math.isfinite(r[key]), (key, r)
        for key in ("photons_per_shot_se", "bias_se_m", "std_se_m", "std_m", "return_weight"):
            assert r[key] > 0, (key, r)
    assert {r["kind"] for r in rows} == {"slope", "fractal"}
    assert compare.select(rows, kind="fractal", variant="Lambertian")[0]["p"] == 1.8


def test_nadir_return_weights(rows):
    """Closed forms of the footprint-mean return weight on the flat plate at nadir."""
    flat = {r["variant"]: r for r in compare.select(rows, kind="plane", slope_deg=0.0)}
    assert flat["Lambertian"]["return_weight"] == pytest.approx(1.0, abs=1e-5)
    # Ward at nadir, all normalisations: rho_d + rho_s / (4 alpha^2), over 0.9
    ward = (0.9 + 0.05 / (4 * 0.3 ** 2)) / 0.9
    for name in ("Ward ward1992", "Ward duer", "Ward balanced"):
        assert flat[name]["return_weight"] == pytest.approx(ward, rel=1e-4)
    # perfect conductor x 0.9: the Beckmann lobe peak pi * 0.9 / (4 pi alpha^2) / 0.9
    assert flat["roughconductor"]["return_weight"] == pytest.approx(1 / (4 * 0.3 ** 2), rel=1e-4)
    # on a 20 deg plane the Lambertian weight is cos(20 deg)
    s20 = compare.select(rows, slope_deg=20.0, variant="Lambertian")[0]
    assert s20["return_weight"] == pytest.approx(math.cos(math.radians(20)), rel=1e-4)


def test_lambertian_flat_matches_closed_form():
    inst = Instrument(beam="strong", ideal_detector=True)
    shots = 1500
    (row,) = compare.sweep(variants={"Lambertian": compare.BRDF_VARIANTS["Lambertian"]},
                           surfaces=[SurfaceSpec(kind="flat")], shots=shots, seed=11, beam=inst)
    mean = inst.signal_photons * inst.fill_factor * inst.pde
    poisson_se = math.sqrt(mean / shots)
    assert row["return_weight"] == pytest.approx(1.0, abs=1e-5)
    assert abs(row["photons_per_shot"] - mean) < Z * poisson_se, (row, mean)
    # the per-shot standard error is the Poisson one (to its own sampling error)
    assert row["photons_per_shot_se"] == pytest.approx(poisson_se, rel=0.15)
    # and the ideal detector's elevation statistics: unbiased, spread c sigma_t / 2
    assert abs(row["bias_m"]) < Z * row["bias_se_m"]
    assert abs(row["std_m"] - inst.ranging_sigma_m) < Z * row["std_se_m"]


def test_table_and_plots(rows, tmp_path):
    text = compare.format_table(rows, title="t")
    assert text.count("\n") == len(rows) + 1 and "roughconductor" in text
    for x in ("slope_deg", "p"):
        fig = compare.plot_sweep(rows, x=x, title=x)
        assert isinstance(fig, matplotlib.figure.Figure) and len(fig.axes) == 6
    assert len(compare.plot_sweep(rows, x="p", reference=None).axes) == 3
    check_sweep_figure(compare.plot_sweep(rows, x="slope_deg"), rows)
    compare.plot_sweep(rows, x="p", path=tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 1000
    with pytest.raises(ValueError):
        compare.plot_sweep(rows, x="alpha")
    with pytest.raises(ValueError):
        compare.plot_sweep(compare.select(rows, kind="fractal"), x="slope_deg")


def check_sweep_figure(fig, rows):
    """What plot_sweep(x="slope_deg") shows: per variant and panel, points at the rows'
    slopes (spread by at most 1 % of the slope span so the error bars do not overlap; not at
    all for the absolute precision) with the rows' values and +-1 standard-error bars; top row
    photons per shot, bias [cm], precision [cm]; bottom row the same against Lambertian
    (relative_to): ratio, difference [cm], relative difference [%]."""
    planes = compare.select(rows, kind="plane")
    rel = compare.relative_to(planes, reference="Lambertian")
    slopes = sorted({r["slope_deg"] for r in planes})
    dodge = 0.01 * (slopes[-1] - slopes[0]) * (len(compare.BRDF_VARIANTS) - 1) / 2
    panels = [[("photons_per_shot", "photons_per_shot_se", 1.0, 0.0, "photons per shot"),
               ("bias_m", "bias_se_m", 100.0, 0.0, "elevation bias [cm]"),
               ("std_m", "std_se_m", 100.0, 0.0, "precision (std) [cm]")],
              [("photons_ratio", "photons_ratio_se", 1.0, 0.0, "÷ Lambertian's"),
               ("bias_diff_m", "bias_diff_se_m", 100.0, 0.0, "− Lambertian's [cm]"),
               ("std_ratio", "std_ratio_se", 100.0, 1.0, "÷ Lambertian's − 1 [%]")]]
    axes = np.array(fig.axes[:6]).reshape(2, 3)
    for i, source in enumerate((planes, rel)):
        for j, (key, err, scale, shift, ylabel) in enumerate(panels[i]):
            ax = axes[i, j]
            assert ylabel in ax.get_ylabel(), (ax.get_ylabel(), ylabel)
            if i == 1:
                assert ax.get_xlabel() == "surface slope [deg]"
            bars = {c.get_label(): c for c in ax.containers}
            assert set(bars) == set(compare.BRDF_VARIANTS)
            for name, c in bars.items():
                rs = sorted((r for r in source if r["variant"] == name), key=lambda r: r["slope_deg"])
                x, y = (np.asarray(v, float) for v in c.lines[0].get_data())
                np.testing.assert_allclose(y, scale * (np.array([r[key] for r in rs]) - shift),
                                           rtol=1e-12)
                dx = x - np.array([r["slope_deg"] for r in rs])
                assert np.all(np.abs(dx) <= dodge + 1e-12) and np.ptp(dx) < 1e-12
                if (i, j) == (0, 2):
                    assert np.all(dx == 0)
                half = [abs(seg[1, 1] - seg[0, 1]) / 2 for seg in c.lines[2][0].get_segments()]
                np.testing.assert_allclose(half, scale * np.array([r[err] for r in rs]),
                                           rtol=1e-9, atol=1e-12)


def test_errors_scale_with_sample():
    """row_of's standard errors: std / sqrt(n), and the std's from the photons' kurtosis
    (std / sqrt(2 (n - 1)) for normal residuals: within a few per cent of it for this flat
    plate's near-Gaussian returns)."""
    (r,) = compare.sweep(variants={"Lambertian": compare.BRDF_VARIANTS["Lambertian"]},
                         surfaces=[SurfaceSpec(kind="flat")], shots=200, seed=5, beam="weak",
                         ideal_detector=True)
    n = r["n_photons"]
    assert r["beam"] == "weak" and r["ideal_detector"]
    assert r["bias_se_m"] == pytest.approx(r["std_m"] / np.sqrt(n))
    assert r["std_se_m"] == pytest.approx(r["std_m"] / np.sqrt(2 * (n - 1)), rel=0.15)
    with pytest.raises(ValueError):
        compare.sweep(variants={}, surfaces=[SurfaceSpec(kind="flat")], shots=10)


def test_relative_and_conclusions(rows):
    rel = compare.relative_to(rows, reference="Lambertian")
    assert len(rel) == len(rows)
    for d in rel:
        if d["variant"] == "Lambertian":
            assert d["photons_ratio"] == 1 and d["bias_diff_m"] == 0 and d["std_ratio"] == 1
        else:
            assert d["photons_ratio_se"] > 0 and d["bias_diff_se_m"] > 0
    ideal = compare.sweep(variants=compare.BRDF_VARIANTS, surfaces=[SurfaceSpec(kind="flat")],
                          shots=60, seed=3, beam="strong", ideal_detector=True)
    text = compare.conclusions(rows, ideal_rows=ideal)
    assert len(text) >= 5 and all(isinstance(s, str) and s for s in text)
    joined = " ".join(text)
    assert "flat plate" in joined and "Ward normalisations" in joined and "Precision" in joined
    assert "×2.778 in return weight" in joined       # the roughconductor's nadir peak
    assert text[-1].startswith("[ideal detector]")


def test_workers_give_the_same_rows():
    """brdf_variants.sweep(workers=2) runs each simulation as a Dask task: the same rows."""
    kw = dict(variants={k: compare.BRDF_VARIANTS[k] for k in ("Ward ward1992", "Lambertian")},
              surfaces=compare.slope_surfaces(slopes_deg=(0, 20)), shots=300, seed=3)
    serial, parallel = compare.sweep(**kw), compare.sweep(**kw, workers=2)
    drop = lambda rows: [{k: v for k, v in r.items() if k != "time_s"} for r in rows]  # noqa: E731
    assert json.dumps(drop(serial)) == json.dumps(drop(parallel))
