"""The granule timeline study's summary (lidar_mitsuba.studies.granule_timeline) on events
whose answers are worked out by hand."""
import pytest

from lidar_mitsuba.studies import granule_timeline as gt


def _span(label, t0, t1, cpu, pid=1, thread="MainThread"):
    return [(label, "b", t0, 0.0, pid, thread), (label, "e", t1, cpu, pid, thread)]


def test_summary_finds_the_head_the_gaps_and_the_tail():
    """Two beams' sections (10.0-10.5-11.0 s), three traces on the launcher thread, the
    writer process's wait, section and close: the head is the first trace's start (0.1 s),
    the boundary's gap the launcher's idle across 10.5 s (10.45 -> 10.6), its busy and idle
    time within its first and last trace, the tail the last hand-off to the close's end."""
    launcher = dict(thread="lidar-trace_0")
    events = (_span("section:0:gt1l", 10.0, 10.5, 0.1) + _span("section:0:gt1r", 10.5, 11.0, 0.2)
              + _span("trace", 10.1, 10.2, 0.05, **launcher)
              + _span("trace", 10.25, 10.45, 0.1, **launcher)
              + _span("trace", 10.6, 10.9, 0.2, **launcher)
              + _span("handed", 10.49, 10.5, 0.0) + _span("handed", 10.99, 11.0, 0.0)
              + _span("close_wait", 11.0, 11.3, 0.0)
              + _span("receive", 10.0, 10.5, 0.0, pid=2)
              + _span("written:gt1l", 10.5, 10.7, 0.08, pid=2)
              + _span("receive", 10.7, 11.0, 0.0, pid=2)
              + _span("written:gt1r", 11.0, 11.1, 0.05, pid=2)
              + _span("close", 11.1, 11.28, 0.1, pid=2))
    s = gt.summary(events[::-1], t0=10.0, t1=11.3)       # (any order: sorted by time)
    assert s["seconds"] == pytest.approx(1.3) and s["head_s"] == pytest.approx(0.1)
    assert s["boundary_gaps_s"] == [pytest.approx(0.15)]
    assert s["launcher_busy_s"] == pytest.approx(0.6)
    assert s["launcher_idle_s"] == pytest.approx(0.2)
    assert s["launcher_cpu_s"] == pytest.approx(0.35)
    assert s["simulating_cpu_s"] == pytest.approx(0.3)
    assert s["tail_s"] == pytest.approx(0.3) and s["writer_close_s"] == pytest.approx(0.18)
    assert s["writer_wait_s"] == pytest.approx(0.8) and s["writer_busy_s"] == pytest.approx(0.3)
    assert s["writer_first_section_s"] == pytest.approx(0.5)
    assert [x["section"] for x in s["sections"]] == ["0:gt1l", "0:gt1r"]
