"""`bench --quick` runs and writes finite numbers and its chart (speed is not asserted here)."""
import json
import math

from lidar_mitsuba.cli import main


def test_bench_quick(tmp_path, capsys):
    assert main(["bench", "--out", str(tmp_path / "b"), "--quick"]) == 0
    doc = json.loads((tmp_path / "b" / "bench.json").read_text())
    assert (tmp_path / "b" / "throughput.png").stat().st_size > 10_000
    assert (tmp_path / "b" / "stability.png").stat().st_size > 10_000
    assert (tmp_path / "b" / "accuracy_vs_time.png").stat().st_size > 10_000
    for name, d in doc["accuracy_vs_time"].items():
        errs = [r["error_m"] for r in d["rows"]]
        assert errs and all(math.isfinite(e) and e >= 0 for e in errs), name
    for name, rows in doc["stability"].items():     # every row: a result or a stated status
        assert rows and all("status" in r for r in rows), name
    for row in doc["detector"]:
        assert math.isfinite(row["events_per_s"]) and row["events_per_s"] > 0
    assert doc["integrator"]["triangles"] > 100_000
    assert 0 < doc["integrator"]["ratio_to_ceiling"] < 10
    assert all(r["shots_per_s"] > 0 for r in doc["end_to_end"])
    out = capsys.readouterr().out
    assert "M events/s" in out and "simplifications of the default run" in out
    simp = doc["simplifications"]
    assert simp["mc_std_m"] > 0 and len(simp["rows"]) == 4
    assert simp["auto_max_depth"] == [2]    # the default p = 1.8 snow needs the second bounce
    crop = simp["rows"][0]        # the corridor crop is exact: photon for photon the same
    assert crop["d_bias_m"] == 0.0 and crop["d_std_m"] == 0.0
    if "rows" in doc["peer"]:     # mitransient installed (the test extra has it)
        assert (tmp_path / "b" / "peer.png").stat().st_size > 10_000
        assert all(math.isfinite(r["error"]) and r["seconds"] > 0 for r in doc["peer"]["rows"])
        assert "peer comparison (mitransient)" in out
