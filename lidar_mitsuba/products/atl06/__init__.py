"""ATL06-style land-ice surface finding and first-photon-bias correction. Pure numpy/scipy.

A simplified, documented form of the ICESat-2 ATL06 land-ice algorithm (Smith et al., ATL06
ATBD: "ATLAS/ICESat-2 L3A Land Ice Height"), run on our photons:

**Segments.** 40 m along-track segments every 20 m (50 % overlap). Segment ``k`` is centred
on ``x_atc = x0 + 20 (k + 1)`` (``x0`` the first shot's along-track position) and holds the
shots and photons with along-track position in ``[x_atc - 20, x_atc + 20)``. ``segment_id``
is ``k + 1``: the segment spans the 20 m ATL03-like geosegments ``k`` and ``k + 1`` counted
from 0 at the first shot, so ``x_atc = x0 + 20 * segment_id``.

**Surface finding** (ATBD 3.1-3.2, with the "backup" signal-finding strategy since our photons
carry no ATL03 classification):

1. initial window: the ``initial_window_m`` (10 m) height interval holding the most photons;
   an initial line fit on those photons, then the window becomes
   ``max(initial_window_m, 6 max(sigma_r, sigma_expected))`` about that line;
2. iterate (at most ``max_iterations``, 20): least-squares line ``h = h_mean + dh_fit_dx x``
   (``x`` from the segment centre) through the selected photons; residuals ``r``; the
   background-corrected robust spread ``sigma_r`` of the selected residuals (see
   :func:`robust_spread`), capped at 5 m; ``sigma_expected = sqrt(sigma_pulse_h^2 +
   (footprint_sigma * dh_fit_dx)^2)``; new window ``W = max(6 sigma_expected, 6 sigma_r,
   0.75 W_last, 3 m)`` (i.e. +-3 sigma); select ``|r| < W / 2``. Stop when the selection stops
   changing. If a new selection has fewer than 10 photons or spans less than 20 m along track,
   the previous one is kept (as the ATBD does).
3. ``h_mean``, ``dh_fit_dx`` are the final line, ``w_surface_window_final`` the final ``W``.

**Background** ``bckgrd`` [MHz]: rate of detection-eligible background photon events (i.e. after
fill factor and PDE: what an ideal detector would count) for the whole detector (all channels),
corrected for dead-time losses. Counted from the segment's photons outside an exclusion zone
about the fitted line, ``|r| < E`` with ``E = max(W / 2, initial_window_m / 2, 5 sigma_r) +
c tau / 2`` (the window, at least the initial 10 m window whose edge does not depend on where
the refinement stopped, a 5-sigma guard against signal tails, and one dead time of shadow
below the surface), inside the range gate: ``rate = n_out / (N_pulses * (gate - 2E))``, gate
and zone in time units (per-shot overlap of zone and gate when the gate centres are known).
The observed per-channel rate ``r_o = rate / C`` is then corrected for dead time:
``r = r_o / (1 - r_o tau)`` (non-paralyzable) or the root of ``r_o = r exp(-r tau)``
(paralyzable).

**First-photon-bias correction** (ATBD 3.3, event by event instead of in 25 ps bins): each
window photon is weighted by the inverse of the fraction of channel-pulses alive when it
arrived, and the weighted, background-subtracted residuals give the corrections
(:mod:`lidar_mitsuba.products.first_photon_bias`, whose docstring derives them):

* ``fpb_corr_m = sum(w r) / (sum(w) - N_bg) - mean(r)``, added to ``h_mean``;
* ``fpb_med_corr_m``: the median of the corrected, background-subtracted residuals;
* ``fpb_gain = sum(w) / n``, ``fpb_min_alive``, ``fpb_n_corr = sum(w) - N_bg``.

**Heights**: ``h_li = h_mean + fpb_corr_m``, mean-based because the reference ``z_ref`` is a
footprint mean; ``h_mean + fpb_med_corr_m`` is the ATBD's median-based alternative (more robust
to background, but on rough terrain, whose residuals about the line are skewed, it sits a few
mm below the mean). ``h_li_sigma = max(sigma_h_mean, fpb_corr_sigma_m)`` as in the
ATBD: ``sigma_h_mean`` is the least-squares intercept error scaled by the per-photon spread
``max(sigma_photon_est, h_rms_misfit)``, and ``fpb_corr_sigma_m`` the error of the weighted
centroid, ``sqrt(sum w^2 (r - rbar)^2) / (sum w - N_bg)``.

**Flags** (``flags`` bit mask, :data:`FLAG_BITS`); any set bit makes ``atl06_quality_summary``
1, and flagged segments stay in the table but are left out of :func:`summarize`.

**Where the code is.** This module is the interface: :func:`fit_segments` lays the segments
along the track and hands each one's photons to an engine, :func:`segments_from_atl03` and
:func:`segments_from_result` feed it, :func:`write`, :func:`read` and :func:`summarize` take its
table. The table's columns and flags are in :mod:`lidar_mitsuba.products.atl06.table`; the fit of one
segment is :mod:`lidar_mitsuba.products.atl06.reference` (numpy, step by step as above) and its numba
twin :mod:`lidar_mitsuba.products.atl06.kernel`. Import every name from here.
"""
from __future__ import annotations

import json
import math
import os
import pathlib

import numpy as np

from .reference import HALF_C, Config, fit_segment, line_fit
from .table import FIELDS, FLAG_BITS, SegmentTable, default_columns  # noqa: F401 (re-exported)
from ...constants import FWHM_PER_SIGMA
from ..first_photon_bias import corrected_background_mhz  # noqa: F401 (re-exported)
from ...machine import host_pool, host_threads

COMPILE_MIN_SEGMENTS = 1000
"""``engine="auto"`` compiles the kernel for tracks of this many segments (20 km) or more:
fewer cost the reference less than the compile."""
#: fewest segments worth a thread of their own in the compiled fit
_SEGMENTS_PER_THREAD_MIN = 256


# --------------------------------------------------------------------------- the track's segments

def fit_segments(*, photon_along_m: np.ndarray, h_m: np.ndarray, shot: np.ndarray,
                 channel: np.ndarray, n_shots: int, shot_along_m: np.ndarray, n_channels: int,
                 dead_time_ns: float, paralyzable: bool, pulse_sigma_ns: float,
                 range_gate_m: float, segment_length_m: float = 40.0,
                 segment_step_m: float = 20.0, z_ref_m: np.ndarray | None = None,
                 gate_center_h_m: np.ndarray | None = None, footprint_sigma_m: float = 0.0,
                 initial_window_m: float = 10.0, min_window_m: float = 3.0,
                 max_iterations: int = 20, min_photons: int = 10,
                 min_alive_pulses: float = 3.0, max_gain: float = 5.0,
                 x0_m: float | None = None, engine: str = "auto") -> SegmentTable:
    """ATL06-style segments from detected photons (see the module docstring).

    Args:
        photon_along_m: (n,) along-track position of each photon [m] (its shot's footprint
            centre, as ATLAS places them: ``shot_along_m[shot]``).
        h_m: (n,) photon heights [m]; shot: (n,) shot index; channel: (n,) detector channel
            (only checked: the correction pools the statistically identical channels).
        n_shots: shots in the track; shot_along_m: (n_shots,) along-track position [m],
            non-decreasing.
        n_channels: detector channels C; dead_time_ns: dead time (0: ideal detector);
        paralyzable: dead-time model; pulse_sigma_ns: transmit pulse sigma [ns];
        range_gate_m: height of the range gate [m].
        segment_length_m, segment_step_m: 40 m segments every 20 m.
        z_ref_m: (n_shots,) truth reference heights; fills ``h_ref_m`` (else NaN).
        gate_center_h_m: (n_shots,) height of each shot's gate centre [m] (instrument telemetry;
            ``simulate`` centres the gate on z_ref). ``None``: the exclusion zone is assumed to
            lie inside the gate.
        footprint_sigma_m: footprint sigma [m], for the expected spread on slopes.
        initial_window_m, min_window_m, max_iterations, min_photons: surface-finding settings.
        min_alive_pulses: flag ``fpb_dead`` when, at some window photon, fewer than this many
            of the ``N C`` channel-pulses are expected alive (``P_alive N C < 3``): the dead
            fraction there rests on too few live channels to be trusted. (The ATBD's test,
            ``P_alive < 1 / (2 C)``, flags e.g. every smooth 12-photon 4-channel segment, where
            this correction still removes 97 % of the bias; and any threshold on this noisy
            per-segment minimum biases the kept segments, so it is set where it rarely fires.)
        max_gain: flag ``fpb_gain`` when the corrected / observed count exceeds it.
        x0_m: along-track origin of the segment grid [m] (centres at ``x0 + 20 (k + 1)``);
            default the first shot's. A track fitted in sections passes the whole track's.
        engine: ``"compiled"`` (numba: :mod:`lidar_mitsuba.products.atl06.kernel`, ~10-20x faster),
            ``"reference"`` (the plain numpy
            :func:`lidar_mitsuba.products.atl06.reference.fit_segment`, ~1 ms a segment; the tests
            check that both give the same table to 1e-9) or ``"auto"``: compiled from
            :data:`COMPILE_MIN_SEGMENTS` segments on (its first compile takes ~20 s, then
            numba's on-disk cache <1 s). The choice depends on the track alone, so a track
            gives the same bits in every process.
    """
    if engine not in ("auto", "compiled", "reference"):
        raise ValueError(f"engine must be 'auto', 'compiled' or 'reference' (got {engine!r})")
    along, h, shot_along = _checked_photons(photon_along_m, h_m, shot, channel, n_shots,
                                            shot_along_m, n_channels)
    if dead_time_ns < 0 or not segment_length_m > 0 or not segment_step_m > 0:
        raise ValueError("dead_time_ns must be >= 0 and segment sizes > 0")
    cfg = Config(n_channels=int(n_channels), dead_time_ns=float(dead_time_ns),
                 paralyzable=bool(paralyzable), sigma_pulse_m=float(pulse_sigma_ns) * HALF_C,
                 footprint_sigma_m=float(footprint_sigma_m), gate_m=float(range_gate_m),
                 initial_window_m=float(initial_window_m), min_window_m=float(min_window_m),
                 max_iterations=int(max_iterations), min_photons=int(min_photons),
                 min_span_m=0.5 * segment_length_m, min_alive_pulses=float(min_alive_pulses),
                 max_gain=float(max_gain))
    if along.size > 1 and not np.all(along[1:] >= along[:-1]):   # (a track's are in order)
        order = np.argsort(along, kind="stable")
        along, h = along[order], h[order]
    half = segment_length_m / 2.0
    centres = _segment_centres(shot_along, x0_m=x0_m, length_m=segment_length_m,
                               step_m=segment_step_m)
    gate = None if gate_center_h_m is None else np.asarray(gate_center_h_m, np.float64)
    cols = default_columns(centres)
    if engine == "auto":
        engine = "compiled" if centres.size >= COMPILE_MIN_SEGMENTS else "reference"
    shot0 = np.searchsorted(shot_along, centres - half, side="left")
    shot1 = np.searchsorted(shot_along, centres + half, side="left")
    fit = _fit_compiled if engine == "compiled" else _fit_reference
    fit(cols, along, h, shot_along, gate, centres, half, shot0, shot1, cfg)
    if z_ref_m is not None:
        _fill_reference_heights(cols["h_ref_m"], np.asarray(z_ref_m, np.float64), shot_along,
                                centres, shot0, shot1, compiled=engine == "compiled")
    cols["atl06_quality_summary"] = (cols["flags"] != 0).astype(np.int64)
    return SegmentTable(**cols)


def _checked_photons(photon_along_m, h_m, shot, channel, n_shots: int, shot_along_m,
                     n_channels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`fit_segments`' photon and shot arrays checked (``ValueError``) and as float64:
    ``(photon along-track [m], photon heights [m], shot along-track [m])``."""
    along = np.asarray(photon_along_m, np.float64)
    h = np.asarray(h_m, np.float64)
    shot = np.asarray(shot, np.int64)
    channel = np.asarray(channel)
    shot_along = np.asarray(shot_along_m, np.float64)
    if not (along.shape == h.shape == shot.shape == channel.shape):
        raise ValueError("photon arrays must have the same shape")
    if shot_along.shape != (n_shots,):
        raise ValueError(f"shot_along_m must have shape ({n_shots},)")
    if shot_along.size > 1 and np.any(np.diff(shot_along) < 0):
        raise ValueError("shot_along_m must be non-decreasing")
    if channel.size and (channel.min() < 0 or channel.max() >= n_channels):
        raise ValueError(f"channel out of range [0, {n_channels})")
    return along, h, shot_along


def _segment_centres(shot_along: np.ndarray, *, x0_m: float | None, length_m: float,
                     step_m: float) -> np.ndarray:
    """(n_segments,) centres [m] of the segments of ``length_m`` every ``step_m`` that fit
    between ``x0_m`` (default the first shot's position) and the last shot."""
    if shot_along.size == 0:
        return np.zeros(0)
    x0, x1 = (shot_along[0] if x0_m is None else float(x0_m)), shot_along[-1]
    n_seg = int(math.floor((x1 - x0 - length_m) / step_m + 1e-9)) + 1
    return x0 + length_m / 2.0 + step_m * np.arange(max(n_seg, 0))


def _fit_reference(cols: dict, along, h, shot_along, gate, centres, half: float, s0, s1,
                   cfg: Config) -> None:
    """Every segment through the numpy reference, into ``cols`` (pre-filled defaults);
    segment ``k`` holds shots ``s0[k]:s1[k]`` and the photons within ``half`` [m] of its
    centre."""
    for k, (c, a, b) in enumerate(zip(centres, s0, s1)):
        p0, p1 = np.searchsorted(along, [c - half, c + half], side="left")
        res = fit_segment(along[p0:p1] - c, h[p0:p1], shot_along[a:b] - c,
                          None if gate is None else gate[a:b], cfg)
        for name, v in res.items():
            cols[name][k] = v


def _fit_compiled(cols: dict, along, h, shot_along, gate, centres, half: float, s0, s1,
                  cfg: Config) -> None:
    """Every segment through the compiled kernel, into ``cols`` (pre-filled defaults);
    segment ``k`` holds shots ``s0[k]:s1[k]``."""
    from . import kernel as K
    from ..first_photon_bias import IQR_PER_SIGMA
    p0 = np.searchsorted(along, centres - half, side="left")
    p1 = np.searchsorted(along, centres + half, side="left")
    cfg_v = np.array([float(getattr(cfg, name)) for name in K.CFG_FIELDS]
                     + [HALF_C, IQR_PER_SIGMA], np.float64)
    out = np.column_stack([cols[name].astype(np.float64) for name in K.OUT_FIELDS])
    gate_v = np.zeros(shot_along.size) if gate is None else gate
    centres = np.asarray(centres, np.float64)

    def fit(a: int, b: int) -> None:      # segments a..b-1 (the kernel releases the GIL)
        K.fit_all(along, h, shot_along, gate_v, gate is not None, centres[a:b], p0[a:b],
                  p1[a:b], s0[a:b], s1[a:b], cfg_v, out[a:b])

    # segments are independent: contiguous blocks on the host's threads, same results
    pool = host_pool()
    blocks = max(1, min(host_threads(), centres.size // _SEGMENTS_PER_THREAD_MIN))
    cuts = np.linspace(0, centres.size, blocks + 1).astype(int)
    for job in [pool.submit(fit, a, b) for a, b in zip(cuts[:-1], cuts[1:])]:
        job.result()
    for i, name in enumerate(K.OUT_FIELDS):
        cols[name][:] = out[:, i]


def _fill_reference_heights(h_ref: np.ndarray, z_ref: np.ndarray, shot_along, centres, s0,
                            s1, *, compiled: bool = False) -> None:
    """The truth column ``h_ref_m`` [m], in place: each segment's least-squares line through
    its shots' ``z_ref`` [m] at the centre (their mean when the line is singular); segments
    without shots keep NaN. ``compiled``: the same column, to the bit, without a Python loop
    (:func:`lidar_mitsuba.products.atl06.kernel.reference_heights`)."""
    if compiled:
        from .kernel import reference_heights
        reference_heights(np.ascontiguousarray(shot_along, np.float64),
                          np.ascontiguousarray(z_ref), np.asarray(centres, np.float64),
                          np.asarray(s0, np.int64), np.asarray(s1, np.int64), h_ref)
        return
    for k, (c, a, b) in enumerate(zip(centres, s0, s1)):
        if b - a >= 1:
            fit = line_fit(shot_along[a:b] - c, z_ref[a:b])
            h_ref[k] = fit[0] if fit is not None else float(np.mean(z_ref[a:b]))


# --------------------------------------------------------------------------- files and summary

def segments_from_atl03(path: str | os.PathLike, **options) -> SegmentTable:
    """Fit segments to one of our ATL03-like files (:func:`lidar_mitsuba.products.atl03.read`).

    Detector settings come from the file's ``config['instrument']`` (files written before the
    noise fields existed get no dead-time model choice (non-paralyzable), a 30 m gate, and no
    noise). The gate is centred on each shot's ``z_ref_m``, as ``simulate`` does, and ``z_ref_m``
    fills ``h_ref_m``. ``options`` are passed to :func:`fit_segments`.
    """
    from .. import atl03
    d = atl03.read(path)
    inst = d["config"]["instrument"]
    dead = 0.0 if inst.get("ideal_detector", False) else float(inst.get("dead_time_ns", 3.0))
    fwhm = float(inst.get("pulse_fwhm_ns", 1.0))
    kw = dict(photon_along_m=d["along_track_m"][d["shot"]], h_m=d["h_m"], shot=d["shot"],
              channel=d["channel"], n_shots=d["n_shots"], shot_along_m=d["along_track_m"],
              n_channels=d["n_channels"], dead_time_ns=dead,
              paralyzable=bool(inst.get("paralyzable", False)),
              pulse_sigma_ns=fwhm / FWHM_PER_SIGMA,
              range_gate_m=float(inst.get("range_gate_m", 30.0)),
              z_ref_m=d["z_ref_m"], gate_center_h_m=d["z_ref_m"],
              footprint_sigma_m=float(inst.get("footprint_diameter_m", 10.0)) / 4.0)
    kw.update(options)
    return fit_segments(**kw)


def segments_from_result(result, **options) -> SegmentTable:
    """Fit segments to a :class:`~lidar_mitsuba.run.SimulationResult` directly, without
    writing a file: the same photons, gate and truth as :func:`segments_from_atl03` reads
    from the file that ``atl03.write(result, ...)`` would write. ``options`` are passed to
    :func:`fit_segments`."""
    d = result.detections
    kw = dict(photon_along_m=result.along_track_m[d.shot], h_m=result.h_m, shot=d.shot,
              channel=d.channel, n_shots=result.n_shots, shot_along_m=result.along_track_m,
              z_ref_m=result.z_ref_m, gate_center_h_m=result.z_ref_m,
              **instrument_settings(result.instrument))
    kw.update(options)
    return fit_segments(**kw)


def instrument_settings(inst) -> dict:
    """:func:`fit_segments`' detector settings for an
    :class:`~lidar_mitsuba.instrument.Instrument` as simulated."""
    return dict(n_channels=inst.channels, dead_time_ns=inst.effective_dead_time_ns,
                paralyzable=inst.paralyzable, pulse_sigma_ns=inst.pulse_sigma_ns,
                range_gate_m=inst.range_gate_m, footprint_sigma_m=inst.footprint_sigma_m)


def write(table: SegmentTable, path: str | os.PathLike, *, attrs: dict | None = None
          ) -> pathlib.Path:
    """Write ``table`` as ``land_ice_segments/<name>`` datasets (attrs ``units``,
    ``description``) to ``path`` atomically: a temporary file in the same folder, renamed on
    success and removed on failure. ``attrs``: extra root attributes (JSON-encoded if not
    str/number)."""
    from ... import __version__
    from ..atl03 import atomic_h5file
    path = pathlib.Path(path)
    with atomic_h5file(path) as f:
        f.attrs["lidar_mitsuba_version"] = __version__
        f.attrs["description"] = ("ATL06-like land-ice segments (lidar_mitsuba.products.atl06): 40 m "
                                  "segments every 20 m, first-photon-bias corrected")
        f.attrs["flag_bits"] = json.dumps(FLAG_BITS)
        for k, v in (attrs or {}).items():
            f.attrs[k] = v if isinstance(v, (str, int, float)) else json.dumps(v)
        g = f.create_group("land_ice_segments")
        for name, (units, desc) in FIELDS.items():
            ds = g.create_dataset(name, data=np.asarray(getattr(table, name)))
            ds.attrs["units"] = units
            ds.attrs["description"] = desc
    return path


def read(path: str | os.PathLike) -> SegmentTable:
    """Read a table written by :func:`write`."""
    import h5py
    with h5py.File(path, "r") as f:
        g = f["land_ice_segments"]
        return SegmentTable(**{name: g[name][()] for name in FIELDS})


def _finite_or_none(v):
    v = float(v)
    return v if math.isfinite(v) else None


def summarize(table: SegmentTable) -> dict:
    """JSON-safe summary over the unflagged segments: counts (and flagged ones by reason),
    mean/median/std of ``h_li - h_ref_m`` and of the uncorrected ``h_mean - h_ref_m`` (NaN →
    None without truth), the standard error of the mean from every other segment (segments
    overlap by half, so alternate ones are independent), and mean correction, gain and
    background."""
    good = table.good
    n = len(table)
    out = {"n_segments": n, "n_good": int(good.sum()), "n_flagged": int(n - good.sum()),
           "flagged_by_reason": {k: int(np.count_nonzero(table.flags & v))
                                 for k, v in FLAG_BITS.items()}}
    alt = good & (np.arange(n) % 2 == 0)
    for key, h in (("h_li", table.h_li), ("h_mean", table.h_mean)):
        d = h - table.h_ref_m
        dg = d[good & np.isfinite(d)]
        da = d[alt & np.isfinite(d)]
        out[f"{key}_minus_ref_mean_m"] = _finite_or_none(dg.mean()) if dg.size else None
        out[f"{key}_minus_ref_median_m"] = _finite_or_none(np.median(dg)) if dg.size else None
        out[f"{key}_minus_ref_std_m"] = _finite_or_none(dg.std(ddof=1)) if dg.size > 1 else None
        out[f"{key}_minus_ref_se_m"] = (_finite_or_none(da.std(ddof=1) / math.sqrt(da.size))
                                            if da.size > 1 else None)
    for key in ("fpb_corr_m", "fpb_med_corr_m", "fpb_gain", "h_li_sigma", "bckgrd"):
        v = getattr(table, key)[good]
        v = v[np.isfinite(v)]
        out[f"mean_{key}"] = _finite_or_none(v.mean()) if v.size else None
    return out
