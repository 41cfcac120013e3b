"""The Pareto front helper, and what the accuracy-vs-time study must show on closed forms."""
from lidar_mitsuba.studies.accuracy import pareto_front


def test_pareto_front_keeps_only_undominated_settings():
    rows = [{"seconds": 1.0, "error_m": 0.5}, {"seconds": 2.0, "error_m": 0.6},
            {"seconds": 3.0, "error_m": 0.2}, {"seconds": 0.5, "error_m": 0.9},
            {"seconds": 4.0, "error_m": 0.2}]
    front = pareto_front(rows)
    assert [(r["seconds"], r["error_m"]) for r in front] == [(0.5, 0.9), (1.0, 0.5), (3.0, 0.2)]
    for r in rows:      # nothing off the front beats a front point on both axes
        if r not in front:
            assert any(f["seconds"] <= r["seconds"] and f["error_m"] <= r["error_m"] for f in front)
