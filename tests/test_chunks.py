"""The trace -> detect chunk loop and its seeding (lidar_mitsuba.trace.stream), on synthetic sources
(lidar_mitsuba.detector.records.Returns.at_times): no rendering.

Results depend on the chunk size by design (chunk k traces with trace_seed(seed, k) and detects
with detector_rng(seed, k)), so nothing here compares different chunkings; every comparison is
exact, against the same stages called by hand."""
import numpy as np
import pytest

from lidar_mitsuba.trace import stream as chunks
from lidar_mitsuba.detector import pmt
from lidar_mitsuba.constants import C_M_PER_NS
from lidar_mitsuba.instrument import Instrument
from lidar_mitsuba.detector.records import Detections, Returns

ALT = 496e3
T0 = 2 * ALT / C_M_PER_NS          # round-trip time to h = 0 [ns]
N_SHOTS, CHUNK, K = 1000, 300, 32  # four chunks: 300, 300, 300, 100 shots


class SeededSource:
    """A stand-in for the tracer: the returns of shots a..b-1 depend only on the seed it is
    given (Gaussian times about the surface at h = 0, with a 0.3 m ramp along the track so
    shots differ), and it records its calls."""

    def __init__(self, k=K):
        self.k = k
        self.calls = []

    def __call__(self, a, b, seed):
        self.calls.append((a, b, seed))
        rng = np.random.default_rng(seed)
        n = (b - a) * self.k
        ramp = np.repeat(0.3 * np.arange(a, b) / N_SHOTS, self.k)      # height [m]
        t = T0 - 2 * ramp / C_M_PER_NS + 0.42 * rng.standard_normal(n)
        return Returns.at_times(t, paths_per_shot=self.k,
                                weight=rng.uniform(0.5, 1.5, n).astype(np.float32))


def inst(**kw):
    return Instrument(beam="strong", background_mhz=5.0, altitude_m=ALT, **kw)


def assert_detections_equal(a: Detections, b: Detections):
    for name in Detections.__dataclass_fields__:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype, name
        np.testing.assert_array_equal(x, y, err_msg=name)


def by_hand(source, instrument, *, seed, z_ref, chunk_shots):
    """The loop's definition, written out: chunk k of [a, b) traces with trace_seed(seed, k),
    detects with detector_rng(seed, k) and a gate centred on 2 (altitude - z_ref) / c; the
    chunks are joined with global shot and return indices."""
    parts, r0 = [], 0
    for k, a in enumerate(range(0, len(z_ref), chunk_shots)):
        b = min(len(z_ref), a + chunk_shots)
        ret = source(a, b, chunks.trace_seed(seed, k))
        det = pmt.detect(ret, instrument, chunks.detector_rng(seed, k),
                         gate_center_ns=2 * (instrument.altitude_m - z_ref[a:b]) / C_M_PER_NS)
        parts.append((det, a, r0))
        r0 += len(ret)
    return Detections.concatenate(parts)


@pytest.fixture(scope="module")
def z_ref():
    return np.zeros(N_SHOTS)


@pytest.fixture(scope="module")
def kept(z_ref):
    src = SeededSource()
    run = chunks.run(source=src, detectors={"run": inst()}, z_ref_m=z_ref, seed=7,
                     chunk_shots=CHUNK, keep_returns=True)
    return run, src


def test_run_is_the_chunk_loop_written_out(kept, z_ref):
    run, src = kept
    assert [(a, b) for a, b, _ in src.calls] == [(0, 300), (300, 600), (600, 900), (900, 1000)]
    assert_detections_equal(run.detections["run"],
                            by_hand(SeededSource(), inst(), seed=7, z_ref=z_ref, chunk_shots=CHUNK))
    d = run.detections["run"]
    assert d.arrivals_per_shot.size == N_SHOTS and d.mean_photons_per_shot.size == N_SHOTS
    assert np.all(np.diff(d.shot) >= 0) and d.shot.max() < N_SHOTS
    assert np.any(d.shot >= 900) and np.any(~d.is_signal)          # last chunk, and noise
    assert set(run.timings_s) == {"trace_s", "detect_s"}


def test_replayed_source_reproduces_the_run_exactly(kept, z_ref):
    """Re-detecting the kept returns with the same seed and chunking gives exactly the
    detections of the fresh run."""
    run, _ = kept
    again = chunks.run(source=chunks.replayed(run.returns), detectors={"run": inst()},
                       z_ref_m=z_ref, seed=7, chunk_shots=CHUNK)
    assert_detections_equal(again.detections["run"], run.detections["run"])
    assert again.n_returns == run.n_returns and again.returns is None
    # a different seed changes the detector's draws on the same returns (the test can fail)
    other = chunks.run(source=chunks.replayed(run.returns), detectors={"run": inst()},
                       z_ref_m=z_ref, seed=8, chunk_shots=CHUNK)
    assert not np.array_equal(other.detections["run"].arrivals_per_shot,
                              run.detections["run"].arrivals_per_shot)


def test_every_detector_sees_the_same_photons_and_stream(z_ref):
    """Two identical instruments in one run detect identically; each detector alone gives what
    it gives beside another (the stream is the chunk's, not shared); a detector differing
    only in dead time sees the same arrivals (same Poisson draws) and differs only after."""
    dets = {"a": inst(), "b": inst(), "para": inst(paralyzable=True, dead_time_ns=6.0)}
    both = chunks.run(source=SeededSource(), detectors=dets, z_ref_m=z_ref, seed=3,
                      chunk_shots=CHUNK)
    assert_detections_equal(both.detections["a"], both.detections["b"])
    alone = chunks.run(source=SeededSource(), detectors={"para": dets["para"]}, z_ref_m=z_ref,
                       seed=3, chunk_shots=CHUNK)
    assert_detections_equal(alone.detections["para"], both.detections["para"])
    a, p = both.detections["a"], both.detections["para"]
    np.testing.assert_array_equal(p.arrivals_per_shot, a.arrivals_per_shot)
    np.testing.assert_array_equal(p.mean_photons_per_shot, a.mean_photons_per_shot)
    assert len(p) < len(a)                           # the longer, extending dead time acted


def test_keep_returns_joins_chunks_with_global_shots(kept):
    run, src = kept
    r = run.returns
    assert r.n_shots == N_SHOTS and r.paths_per_shot == K and len(r) == run.n_returns
    assert r.shot.dtype == np.int64
    np.testing.assert_array_equal(r.shot, np.repeat(np.arange(N_SHOTS), K))
    fresh = SeededSource()
    expect = np.concatenate([fresh(a, b, s).time_ns for a, b, s in src.calls])
    np.testing.assert_array_equal(r.time_ns, expect)
    # the detections' return indices point into the joined returns
    d = run.detections["run"]
    sig = d.is_signal
    np.testing.assert_array_equal(r.shot[d.return_index[sig]], d.shot[sig])
    np.testing.assert_array_equal(r.time_ns[d.return_index[sig]], d.time_ns[sig])
    assert np.all(d.return_index[~sig] == -1)
    # not kept unless asked
    off = chunks.run(source=SeededSource(), detectors={"run": inst()}, z_ref_m=np.zeros(50),
                     seed=7, chunk_shots=CHUNK)
    assert off.returns is None and off.n_returns == 50 * K


def test_seeds_are_deterministic_and_differ_between_chunks(kept):
    run, src = kept
    assert [s for *_, s in src.calls] == [chunks.trace_seed(7, k) for k in range(4)]
    seeds = {chunks.trace_seed(s, k) for s in (0, 1, 7) for k in range(50)}
    assert len(seeds) == 150                                   # all distinct
    assert chunks.trace_seed(7, 2) == chunks.trace_seed(7, 2)
    assert all(isinstance(s, int) and 0 <= s < 2 ** 32 for s in seeds)
    draws = {(s, k): tuple(chunks.detector_rng(s, k).integers(0, 2 ** 62, 4))
             for s in (0, 1, 7) for k in range(50)}
    assert len(set(draws.values())) == 150
    assert tuple(chunks.detector_rng(7, 2).integers(0, 2 ** 62, 4)) == draws[(7, 2)]
    # the detector's stream is not the tracer's: a generator seeded with the trace seed differs
    assert tuple(np.random.default_rng(chunks.trace_seed(7, 2)).integers(0, 2 ** 62, 4)) \
        != draws[(7, 2)]


def test_gate_centre_is_the_round_trip_to_the_reference():
    z = np.array([0.0, 10.0, -5.5])
    np.testing.assert_allclose(chunks.gate_center_ns(inst(), z), 2 * (ALT - z) / C_M_PER_NS,
                               rtol=1e-15)


class _Built:
    """What a stand-in tiling's prepare builds for a chunk: its shots and the thread that
    built it."""

    def __init__(self, a, b):
        import threading
        self.span, self.thread = (a, b), threading.current_thread().name


class _PreparedSource(SeededSource):
    """A stand-in for a granule's :class:`~lidar_mitsuba.trace.stream.TiledSource`: chunks
    launched on the trace launcher thread, each taking the tile :meth:`prepare` built for it
    (built here on launch when none was), and a log of both, in order."""

    def __init__(self):
        super().__init__()
        self.log, self.ready = [], {}

    def prepare(self, a, b):
        self.log.append(("prepare", a, b))
        self.ready[(a, b)] = _Built(a, b)

    def launch(self, a, b, seed):
        import threading
        built = self.ready.pop((a, b), None) or _Built(a, b)
        self.log.append(("launch", a, b, built.thread, threading.current_thread().name))
        return _Ready(self(a, b, seed))


class _Ready:
    def __init__(self, returns):
        self.returns = returns

    def result(self):
        return self.returns


def test_a_granule_s_stream_builds_each_next_tile_here_while_the_launcher_traces(
        z_ref, monkeypatch):
    """With the trace launcher (a granule's stream), chunk k + 1's tile is prepared on the
    stream's own thread before chunk k's returns are waited for, and its launch, on the
    launcher thread, takes that tile; the first chunk's is the one the plan built. The
    detections are those of the same source run without the launcher, to the bit."""
    from concurrent.futures import ThreadPoolExecutor
    import threading
    pool = ThreadPoolExecutor(1, thread_name_prefix="test-trace")
    monkeypatch.setattr(chunks, "trace_launcher", lambda: pool)
    src = _PreparedSource()
    try:
        run = chunks.run(source=src, detectors={"run": inst()}, z_ref_m=z_ref, seed=7,
                         chunk_shots=CHUNK)
    finally:
        pool.shutdown()
    here = threading.current_thread().name
    spans = [(0, 300), (300, 600), (600, 900), (900, 1000)]
    assert [e[1:3] for e in src.log if e[0] == "prepare"] == spans[1:]
    launches = [e for e in src.log if e[0] == "launch"]
    assert [e[1:3] for e in launches] == spans
    assert all(e[4].startswith("test-trace") for e in launches)
    assert [e[3] == here for e in launches] == [False, True, True, True]
    for k, (a, b) in enumerate(spans[1:], 1):        # prepared before the launch it feeds
        assert src.log.index(("prepare", a, b)) < src.log.index(launches[k])
    assert not src.ready
    plain = chunks.run(source=SeededSource(), detectors={"run": inst()}, z_ref_m=z_ref,
                       seed=7, chunk_shots=CHUNK)
    assert_detections_equal(run.detections["run"], plain.detections["run"])


def test_chunk_tiles_build_a_prepared_tile_from_what_was_prepared():
    """:class:`~lidar_mitsuba.ground.surface.ChunkTiles`: ``tile(a, b, prepared)`` builds
    from ``prepared`` (what a tiling's ``prepare(a, b)`` made ahead: a DEM's corridor mesh),
    ``tile(a, b)`` from the shots alone; the first chunk's tile is the one built at the
    start; what a tile does to its user (``_use``) happens in ``tile``, in order."""
    from lidar_mitsuba.ground.surface import ChunkTiles

    class Stub(ChunkTiles):
        def prepare(self, a, b):
            return ("mesh", a, b)

        def _build(self, a, b, prepared=None):
            self.builds.append((a, b, prepared))
            return (f"scene{a}", self.x_m[a:b], self.y_m[a:b], None, b - a)

        def _use(self, built):
            self.used.append(built[0])

    Stub.builds, Stub.used = [], []
    t = Stub(np.arange(10.0), np.zeros(10), reach_m=1.0, bsdf=None, chunk_shots=4)
    assert t.builds == [(0, 4, None)]                     # the plan's first tile
    assert t.tile(0, 4)[0] == "scene0"
    ahead = t.prepare(4, 8)
    assert t.builds == [(0, 4, None)] and t.used == ["scene0"]
    scene, x, *_ = t.tile(4, 8, ahead)
    assert scene == "scene4" and t.builds[-1] == (4, 8, ("mesh", 4, 8))
    np.testing.assert_array_equal(x, np.arange(4.0, 8.0))
    assert t.tile(8, 10)[0] == "scene8" and t.builds[-1] == (8, 10, None)
    assert t.used == ["scene0", "scene4", "scene8"]
    assert t.stats() == {"tiles": 3, "max_tile_triangles": 4}
