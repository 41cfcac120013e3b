"""The sea-ice tails study (lidar_mitsuba/studies/sea_ice.py): the counting, exactly, and one
small run of the flat twin against the floe model."""
import math

import numpy as np
import pytest

from lidar_mitsuba.ground.snow import kernel as snow_kernel
from lidar_mitsuba import twin
from lidar_mitsuba.studies import sea_ice


def test_tails_exact():
    r = np.array([-0.5, -0.21, -0.2, -0.1, 0.0, 0.05, 0.2, 0.2000001, 0.3, 1.0])
    t = sea_ice.tails(r)
    assert t["n"] == 10 and t["below_count"] == 2 and t["above_count"] == 3
    assert t["below"] == pytest.approx(0.2) and t["above"] == pytest.approx(0.3)
    assert t["below_se"] == pytest.approx(math.sqrt(0.2 * 0.8 / 10))
    assert t["above_se"] == pytest.approx(math.sqrt(0.3 * 0.7 / 10))
    assert t["above_far_count"] == 1 and t["above_far"] == pytest.approx(0.1)   # 0.3 is not
    t = sea_ice.tails(r, cut_m=0.4)
    assert (t["below_count"], t["above_count"]) == (1, 1)
    t = sea_ice.tails(np.zeros(5))
    assert t["below"] == 0 and t["above"] == 0 and t["below_se"] == 0


def test_tails_gaussian():
    x = np.random.default_rng(3).normal(0.0, 0.1, 200_000)
    t = sea_ice.tails(x)
    p = 0.5 * math.erfc(2.0 / math.sqrt(2.0))         # P(z > 2)
    assert abs(t["below"] - p) < 4 * t["below_se"] and abs(t["above"] - p) < 4 * t["above_se"]


def test_verdict_within_two_se():
    real = {"below": 0.10, "below_se": 0.006, "above": 0.065, "above_se": 0.005}
    v = sea_ice.verdict({"below": 0.105, "below_se": 0.006, "above": 0.02, "above_se": 0.003},
                        real)
    assert v["below_agrees"] and not v["above_agrees"] and v["above_z"] < -2
    assert "above" in v["verdict"] and len(v["notes"]) == 1


def test_floe_has_a_longer_lower_tail_than_flat(tmp_path, monkeypatch):
    """The floe (rough ice, snow volume) delays photons: more of them sit more than 20 cm
    below their segment's median than over flat Ward snow (a coarse kernel table, built in a
    private cache, keeps this quick)."""
    monkeypatch.setenv("LIDAR_MITSUBA_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(snow_kernel, "PHOTONS", 1 << 12)
    real = twin.read(twin.REAL_SUBSET)
    flat = sea_ice.twin_tails("flat", real=real, shots=600, out_dir=tmp_path)
    floe = sea_ice.twin_tails("floe", real=real, shots=600, out_dir=tmp_path)
    a, b = flat["tails"], floe["tails"]
    assert a["n"] > 500 and b["n"] > 500
    assert b["below"] - a["below"] > 2 * math.hypot(a["below_se"], b["below_se"])
    assert (tmp_path / "floe_0_ATL03.h5").is_file()
