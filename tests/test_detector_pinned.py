"""The detector's output, pinned bit for bit (issue 27: the detector was made faster "without
changing any detection").

Each case runs :func:`lidar_mitsuba.detector.pmt.detect` on seeded synthetic returns (no rendering) and
compares a SHA-256 digest of every array of the :class:`~lidar_mitsuba.detector.records.Detections` with
the digest the detector gave at commit 052b8fe, before its kernels were restructured. The cases
cover what the detector does differently: no noise, background and dark counts, saturation (the
argsort path), paralyzable dead time, the ideal detector, multi-bounce returns (the shuffle),
shots whose paths ran out, a weak beam's summed anodes, and gates shifted per shot or NaN (no
surface under the shot: it records nothing).

A digest that changes means detections changed: a deliberate change of the detector's model
must say so and update the digests here (``python tests/test_detector_pinned.py`` prints them).
"""
import hashlib
import sys

import numpy as np
import pytest

from lidar_mitsuba.detector import pmt
from lidar_mitsuba.constants import C_M_PER_NS
from lidar_mitsuba.instrument import Instrument
from lidar_mitsuba.detector.records import Returns

T0_NS = 2 * 496e3 / C_M_PER_NS


def _returns(n_shots, k, *, seed, depth_max=1):
    rng = np.random.default_rng(seed)
    ret = Returns.at_times(T0_NS + 0.4247 * rng.standard_normal(n_shots * k), paths_per_shot=k,
                           weight=rng.gamma(2.0, 0.5, n_shots * k).astype(np.float32))
    ret.x_m = rng.normal(0, 2.5, len(ret)).astype(np.float32)
    ret.y_m = rng.normal(0, 2.5, len(ret)).astype(np.float32)
    ret.z_m = rng.normal(0, 0.1, len(ret)).astype(np.float32)
    if depth_max > 1:
        ret.depth = (np.arange(len(ret)) % depth_max + 1).astype(np.uint8)
    return ret


CASES = {
    "strong, no noise": (dict(beam="strong"), 64, 1),
    "strong, 10 MHz and dark counts": (dict(beam="strong", background_mhz=10.0,
                                            dark_count_hz=5e4), 64, 1),
    "weak, 3 MHz": (dict(beam="weak", background_mhz=3.0), 32, 1),
    "saturated, 300 photons/shot": (dict(beam="strong", signal_photons=300.0), 256, 1),
    "heavy background, paralyzable": (dict(beam="strong", background_mhz=300.0,
                                           range_gate_m=100.0, paralyzable=True), 64, 1),
    "ideal detector, 30 MHz": (dict(beam="strong", ideal_detector=True, background_mhz=30.0),
                               64, 1),
    "two bounces, run out": (dict(beam="strong", signal_photons=40.0, background_mhz=1.0), 8, 2),
}
DIGESTS = {
    "strong, no noise":
        "2dfcab221d6ac261c2f687b59e3201797586b7a4ab2659eee63453254d267263",
    "strong, 10 MHz and dark counts":
        "837da579a255ea15d2ff4400868a6efa46c399f5187dacc9f1c6626750da79bd",
    "weak, 3 MHz":
        "db488361d318ab3b11626d6ec4dd4b6288bde8e53db235d2751719eca991e11b",
    "saturated, 300 photons/shot":
        "e0185cc7e08c44710a45e0cef36447e782f177a0a4d8da98f0d40986072d76d5",
    "heavy background, paralyzable":
        "d4ca547065518bb5ac7471c79e60f8b96f816cdfd3657e3570bd67b768e3a7c3",
    "ideal detector, 30 MHz":
        "2c8318bb313cc727e2f3f41a5295d2a6c45f29f9fa028ba213ab953f08ec60c2",
    "two bounces, run out":
        "2e1d511298a41046c8986f586f1b5e155f2a5876802f04d0f8c7808e84707ee4",
}


def digest(case: str) -> str:
    options, k, depth_max = CASES[case]
    n_shots = 3000
    ret = _returns(n_shots, k, seed=11, depth_max=depth_max)
    gate = np.full(n_shots, T0_NS) + np.linspace(-3.0, 3.0, n_shots)    # gates move per shot
    gate[::97] = np.nan                                                   # no surface there
    det = pmt.detect(ret, Instrument(**options), np.random.default_rng(5), gate_center_ns=gate)
    h = hashlib.sha256()
    for name in ("shot", "channel", "anode", "time_ns", "return_index", "is_signal",
                 "hit_xyz_m", "arrivals_per_shot", "mean_photons_per_shot", "run_out_shots"):
        a = np.ascontiguousarray(getattr(det, name))
        h.update(name.encode() + str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
    return h.hexdigest()


@pytest.mark.parametrize("case", list(CASES))
def test_detections_are_pinned(case):
    assert digest(case) == DIGESTS[case]


if __name__ == "__main__":          # print the digests of this code
    import lidar_mitsuba  # noqa: F401
    for c in CASES:
        print(f'    "{c}": "{digest(c)}",')
    sys.exit(0)


def test_a_block_that_overflows_its_room_runs_again_with_the_same_events():
    """``detect_shots`` reserves each block of shots room for its signal and expected noise;
    with no allowance for noise (``spare=0``) every noisy block overflows and the pass runs
    again with room to spare: the events must be those of a pass that fitted at once."""
    from lidar_mitsuba.detector import deadtime as _deadtime
    rng = np.random.default_rng(3)
    n_shots = 2 * _deadtime.BLOCK_SHOTS + 17
    n_sig = rng.poisson(5.0, n_shots)
    start = np.concatenate([[0], np.cumsum(n_sig)]).astype(np.int64)
    t = np.repeat(np.linspace(0.0, 50.0, n_shots), n_sig) + rng.normal(0, 2.0, start[-1])
    args = (start, t, rng.integers(0, 16, t.size).astype(np.int16),
            np.arange(t.size, dtype=np.int32), np.full(n_shots, -100.0), 300.0,
            rng.uniform(0.0, 0.5, n_shots), 16, 4, 3.0, False, 99)
    fitted = _deadtime.detect_shots(*args, 1)
    retried = _deadtime.detect_shots(*args, 0)
    assert fitted[0].size > n_sig.sum()                      # noise was recorded
    for a, b in zip(fitted, retried):
        np.testing.assert_array_equal(a, b)


# ------------------------------------------------------------------ the paper's mode, end to end
#: digests of simulate() with the paper's instrument at 052b8fe (before the radiometry, the
#: per-shot detector inputs and the geolocation of issue 26): the paper mode must not move
#: The fractal run's bits depend on the CPU's vector width: numpy's float64 exp/sin/cos (and
#: Embree's traversal) take other code paths on AVX-512 (numpy's X86_V4 dispatch) than on AVX2,
#: which differ in the last bit, and the terrain's random-phase synthesis carries that into
#: the mesh. Its digest is pinned per CPU family: the AVX-512 one from 052b8fe, the AVX2 one
#: from 1b867dc (the code of that commit, run on an AVX2-only EPYC, gives it; no code change
#: between them moved the paper mode).
SIMULATE_DIGESTS = {
    "flat, strong, 10 MHz":
        "64576e3eea1b67b7c6238cc3f0e88994dca49724d9509a61a1a9687549baf60d",
    "fractal, weak": {
        True: "9843beff5d04d03e8ae22789cfff97c43ed661d0033691aea8e4a7fca6a9a166",
        False: "4b7d281d3589a722a62ca9f26a3b5668b696f983084bb79ce9567d946179a798"},
}


def _avx512() -> bool:
    """Does numpy dispatch to its AVX-512 (X86_V4 / AVX512_SKX) kernels on this CPU?"""
    from numpy._core._multiarray_umath import __cpu_features__
    return bool(__cpu_features__.get("AVX512_SKX", False))


@pytest.mark.parametrize("case", list(SIMULATE_DIGESTS))
def test_paper_mode_runs_are_pinned(case):
    """Photons, heights, confidence and reference elevations of two paper-mode runs (a flat
    plate with background; the fractal snow with the bounce pilot and the path scout)."""
    from lidar_mitsuba.run import simulate
    from lidar_mitsuba.ground.surface import SurfaceSpec
    inst, surf, shots, seed = {
        "flat, strong, 10 MHz": (dict(beam="strong", background_mhz=10.0),
                                 SurfaceSpec(kind="flat"), 2000, 3),
        "fractal, weak": (dict(beam="weak"), SurfaceSpec(kind="fractal", p=1.8, size_m=256.0),
                          600, 4)}[case]
    res = simulate(instrument=Instrument(**inst), surface=surf, shots=shots, seed=seed,
                   progress=False)
    h = hashlib.sha256()
    d = res.detections
    for a in (d.shot, d.channel, d.time_ns, d.return_index, d.hit_xyz_m, res.h_m,
              res.signal_conf, res.z_ref_m):
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode() + a.tobytes())
    pinned = SIMULATE_DIGESTS[case]
    assert h.hexdigest() == (pinned[_avx512()] if isinstance(pinned, dict) else pinned)
