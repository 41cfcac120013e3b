"""One beam of an ATL03 file: every dataset of a real granule's beam group
(:mod:`lidar_mitsuba.products.atl03.fields`) from a simulated run, and the run's truth.

:func:`write_beam` appends one run (a whole paper-mode track, or one section of a streamed
granule) to the beam's groups:

* ``heights/``: one row per detected photon, in shot order;
* ``geolocation/``, ``geophys_corr/``: one row per 20 m segment from the track's first shot
  (sections hold whole segments); the reference shot is the one nearest the segment centre;
* ``bckgrd_atlas/``: one row per 50 shots of the whole track (a row cut by a section's end is
  held until the next section completes it, or until the file closes: :func:`flush`);
* ``signal_find_output/<surface type>/``: one row per block of the histogram test
  (:mod:`lidar_mitsuba.products.classify`, 20 shots of the run);
* ``/truth/<beam>/{photons,shots}``: the simulation truth (:func:`truth_fields`).

Every row's ``delta_time`` is the group's HDF5 dimension scale, as in real granules.
"""
from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass

import numpy as np
from h5py import h5a

from . import file as atl03_file, kernels
from .. import h5template, h5write as h5chunks
from ...detector import pmt
from ... import radiometry
from .fields import COORDINATES, F4_FILL, GROUPS, HEIGHTS, SURFACE_TYPES
from ...trace.stream import gate_heights_m
from ..classify import histogram_test
from ..record import SEGMENT_M  # noqa: F401 (ATL03's 20 m segments: one definition)
from ...constants import C_M_PER_NS
from ...night import BCKGRD_SHOTS, removed_extremes   # (a bckgrd_atlas row: one definition)

PULSES_PER_MAJOR_FRAME = 200
_C_M_PER_S = C_M_PER_NS * 1e9
_pending: dict = {}         # (file key, beam) -> the bckgrd_atlas row the next section continues
_groups: dict = {}          # (HDF5 file number, path) -> the h5py.Group write_beam made or
                            # opened there (a file being written: dropped by flush, discard)


# --------------------------------------------------------------------------- the run's rows
@dataclass
class _Section:
    """One run's photons in shot order, its segments and its histogram test."""
    run: object
    done: int              # photons of this beam already written (earlier sections)

    def __post_init__(self):
        res = self.run.result
        self.res, self.inst, det = res, res.instrument, res.detections
        shot = det.shot
        # (simulate()'s photons come in shot order: then the order is the identity, and the
        # per-photon fields are views, not gathered copies)
        self.order = (slice(None) if shot.size < 2 or bool(np.all(shot[1:] >= shot[:-1]))
                      else np.argsort(shot, kind="stable"))
        # (read only: views where the photons' own arrays already have these dtypes)
        self.shot = shot[self.order].astype(np.int64, copy=False)  # local to this run
        self.channel = det.channel[self.order]
        self.conf = np.asarray(res.signal_conf)[self.order].astype(np.int8, copy=False)
        (self.seg_of_shot, self.first, self.count, self.ref_shot,
         self.k0) = _segments(res.along_track_m, self.shot)
        self.gate = gate_heights_m(res.z_ref_m)       # the gates simulate() centred
        self.saturated = _saturated_pulses(self)     # (full, near) per shot
        self.test = getattr(res, "signal_test", None)
        if self.test is None or self.test.conf is not res.signal_conf:
            # (run once by simulate(), whose signal_conf it gave, with these arguments)
            self.test = histogram_test(shot=det.shot, h_m=res.h_m, gate_center_h_m=self.gate,
                                       range_gate_m=self.inst.range_gate_m)


def _segments(along_m: np.ndarray, photon_shot: np.ndarray):
    """The 20 m segments ``k0 .. k0 + n - 1`` the shots fall in (``along_m`` (n_shots,) from
    the track's first shot): each shot's segment, the index of each segment's first photon
    and its photon count (photons sorted by shot, ``photon_shot`` local), the shot nearest
    each segment's centre, and ``k0``."""
    seg_of_shot = np.floor(along_m / SEGMENT_M).astype(np.int64)
    k0 = int(seg_of_shot[0]) if along_m.size else 0
    n_seg = int(seg_of_shot[-1]) - k0 + 1 if along_m.size else 0
    count = np.bincount(seg_of_shot[photon_shot] - k0, minlength=n_seg)
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    centre = (k0 + np.arange(n_seg) + 0.5) * SEGMENT_M
    ref_shot = np.clip(np.searchsorted(along_m, centre), 0, along_m.size - 1)
    prev = np.maximum(ref_shot - 1, 0)
    closer = np.abs(along_m[prev] - centre) < np.abs(along_m[ref_shot] - centre)
    ref_shot = np.where(closer, prev, ref_shot)
    return seg_of_shot, first, count, ref_shot, k0


def _ph_id_count(shot: np.ndarray, channel: np.ndarray) -> np.ndarray:
    """1-based index of each event among the events of its shot and channel, in order: one
    compiled pass over photons in shot order (:func:`.kernels.ph_id_count`), else numpy's
    stable sort of (shot, channel)."""
    n = shot.size
    if n == 0:
        return np.zeros(0, np.uint8)
    out = np.empty(n, np.uint8)
    if kernels.ph_id_count(shot, channel, out):
        return out
    key = (shot.astype(np.int64) - shot.min()) * 64 + channel.astype(np.int64)
    if key.max() < 2 ** 31:         # (a section's: an int32 sort is ~30 % faster)
        key = key.astype(np.int32)
    order = np.argsort(key, kind="stable")
    k = key[order]
    start = np.r_[True, k[1:] != k[:-1]]
    run_start = np.maximum.accumulate(np.where(start, np.arange(n), 0))
    out = np.empty(n, np.int64)
    out[order] = np.arange(n) - run_start + 1
    return np.minimum(out, 255).astype(np.uint8)


def _heights(s: _Section) -> dict:
    run, res = s.run, s.res
    shot = s.shot
    p = s.test.tail_p[s.order]
    base = 1 if run.beam.strength == "strong" else 17
    gshot = run.first_shot + np.arange(res.n_shots, dtype=np.int64)   # (per shot, gathered)
    f = HEIGHTS                # (per-shot values in the file's dtype, then gathered: the same
    return {                   # values as gathered, then converted)
        "lat_ph": run.lat_deg[shot], "lon_ph": run.lon_deg[shot], "h_ph": res.h_m[s.order],
        "delta_time": run.delta_time_s[shot],
        "dist_ph_along": (res.along_track_m - SEGMENT_M * s.seg_of_shot).astype(
            f["dist_ph_along"].dtype)[shot],
        "dist_ph_across": np.zeros(shot.size, f["dist_ph_across"].dtype),
        "signal_conf_ph": np.repeat(s.conf[:, None], len(SURFACE_TYPES), axis=1),
        "weight_ph": np.round(255.0 * np.clip(-np.log10(np.maximum(p, 1e-300)) / 6.0, 0, 1)),
        "ph_id_count": _ph_id_count(shot, s.channel),
        "ph_id_channel": s.channel.astype(np.int64) + base,
        "ph_id_pulse": (gshot % PULSES_PER_MAJOR_FRAME + 1).astype(
            f["ph_id_pulse"].dtype)[shot],
        "pce_mframe_cnt": (gshot // PULSES_PER_MAJOR_FRAME).astype(
            f["pce_mframe_cnt"].dtype)[shot],
        "quality_ph": _quality(s),
    }


def _geolocation(s: _Section, sc_orient: int) -> dict:
    run, res, inst, ref = s.run, s.res, s.inst, s.ref_shot
    n_seg, shot, first = s.count.size, s.shot, s.first
    ref_ph = np.searchsorted(shot, ref)
    has = ((ref_ph < shot.size) & (shot[np.minimum(ref_ph, max(shot.size - 1, 0))] == ref)
           if shot.size else np.zeros(n_seg, bool))
    z_ref = res.z_ref_m[ref]
    elev, azim = _solar(s)
    full, near = _saturation(s)
    link = getattr(inst, "link_budget", None)
    return {
        "segment_id": s.k0 + np.arange(1, n_seg + 1), "segment_ph_cnt": s.count,
        "ph_index_beg": np.where(s.count > 0, s.done + first + 1, 0),
        "segment_dist_x": SEGMENT_M * (s.k0 + np.arange(n_seg, dtype=np.float64)),
        "segment_length": np.full(n_seg, SEGMENT_M),
        "reference_photon_lat": run.lat_deg[ref], "reference_photon_lon": run.lon_deg[ref],
        "reference_photon_index": np.where(has, ref_ph - first + 1, 0),
        "delta_time": run.delta_time_s[ref],
        "ref_azimuth": np.deg2rad(run.azimuth_deg[ref]), "ref_elev": np.full(n_seg, np.pi / 2),
        "altitude_sc": np.full(n_seg, inst.altitude_m),
        "bounce_time_offset": _or_fill((inst.altitude_m - z_ref) / _C_M_PER_S),
        "solar_elevation": elev, "solar_azimuth": azim,
        "full_sat_fract": full, "near_sat_fract": near,
        "velocity_sc": _velocity_enu(run.lat_deg, run.lon_deg, run.delta_time_s, ref),
        "yaw": np.full(n_seg, 180.0 if sc_orient == 0 else 0.0),
        "surf_type": np.tile(np.array([0, 0, 0, 1, 0]), (n_seg, 1)),
        "tx_pulse_energy": (np.full(n_seg, link.pulse_energy_uj * 1e-6) if link is not None
                            else NotModelled("the instrument has no link budget (the paper's "
                                             "instrument: signal_photons is given, not a "
                                             "pulse energy); --instrument atlas has one")),
    }


@dataclass(frozen=True)
class NotModelled:
    """A field written with its fill value in this file, and why (``model_note``)."""
    why: str


def _or_fill(v):
    v = np.asarray(v, np.float64)
    return np.where(np.isfinite(v), v, F4_FILL)


def _solar(s: _Section):
    """The sun at each segment's reference shot [deg]: the run's radiometry's where it has
    one, else :func:`lidar_mitsuba.radiometry.solar_angles` there."""
    rad, run, ref = s.res.radiometry, s.run, s.ref_shot
    if rad is not None:
        return rad.solar_elevation_deg[ref], rad.solar_azimuth_deg[ref]
    return radiometry.solar_angles(run.lat_deg[ref], run.lon_deg[ref], run.delta_time_s[ref])


def _saturated_pulses(s: _Section):
    """Per shot (n_shots,): fully saturated (its surface events, ``signal_conf_ph >= 2``, at
    least the beam's channels) and nearly saturated (at least 3/4 of them, fewer than all)."""
    surface = np.bincount(s.shot[s.conf >= 2], minlength=s.res.n_shots)
    channels = s.inst.channels
    full = surface >= channels
    return full, (surface >= math.ceil(0.75 * channels)) & ~full


#: ``quality_ph`` below a (fully or nearly) saturated pulse's highest surface event [m]:
#: 1 (possible afterpulse) over the receiver's echoes, 2 (possible impulse-response effect)
#: below them down to the end of the photomultiplier's afterpulses. ESTIMATE: ATL03's own
#: windows are not published where we could read them; ours bracket Lu et al. 2021's echoes
#: (~2.3 m and ~4.2 m, +-0.5 m: the saturation window) and afterpulses (to ~45 m)
QUALITY_WINDOWS_M = ((1.8, 4.7, 1), (4.7, 45.0, 2))


def _quality(s: _Section) -> np.ndarray:
    """``quality_ph`` per photon (in the section's order): 0 nominal; in a saturated pulse
    (:func:`_saturated_pulses`), by depth below its highest surface event,
    :data:`QUALITY_WINDOWS_M`. 3 (possible TEP) never: the transmitter echo path is not
    simulated. int8."""
    q = np.zeros(s.shot.size, np.int8)
    full, near = s.saturated
    sat = full | near
    if not sat.any():
        return q
    h = np.asarray(s.res.h_m, np.float64)[s.order]
    top = np.full(sat.size, -np.inf)
    surf = s.conf >= 2
    at = s.shot[surf]              # (ascending: photons are in shot order; the maximum of
    if at.size:                    # each shot's run is exact, as np.maximum.at's, NaN too)
        start = np.flatnonzero(np.r_[True, at[1:] != at[:-1]])
        top[at[start]] = np.maximum.reduceat(h[surf], start)
    depth = np.where(sat[s.shot], top[s.shot] - h, -np.inf)
    for lo, hi, flag in QUALITY_WINDOWS_M:
        q[(depth > lo) & (depth <= hi)] = flag
    return q


def _saturation(s: _Section):
    """Per segment, the fractions of its pulses with photons that are fully saturated and
    nearly saturated (:func:`_saturated_pulses`); fill value without photons."""
    n_shots, n_seg = s.res.n_shots, s.count.size
    with_photons = np.bincount(s.shot, minlength=n_shots) > 0
    full, near = s.saturated
    seg = s.seg_of_shot - s.k0
    pulses = np.bincount(seg, weights=with_photons, minlength=n_seg)
    out = []
    for flag in (full, near):
        k = np.bincount(seg, weights=flag & with_photons, minlength=n_seg)
        out.append(np.where(pulses > 0, k / np.maximum(pulses, 1), F4_FILL))
    return out


@functools.lru_cache(maxsize=1)
def _to_ecef():
    from pyproj import Transformer
    return Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)


def _velocity_enu(lat_deg, lon_deg, t_s, at) -> np.ndarray:
    """(n, 3) east, north, up velocity [m/s] of the footprint at shots ``at``: the central
    difference of its neighbours' ECEF positions on the ellipsoid, in the local frame."""
    n = lat_deg.size
    i0, i1 = np.maximum(at - 1, 0), np.minimum(at + 1, n - 1)
    both = np.concatenate([i0, i1])          # (one call: PROJ transforms point by point)
    p = np.column_stack(_to_ecef().transform(lon_deg[both], lat_deg[both],
                                             np.zeros(both.size)))
    p0, p1 = p[:at.size], p[at.size:]
    dt = t_s[i1] - t_s[i0]
    v = (p1 - p0) / np.where(dt > 0, dt, np.inf)[:, None]
    lat, lon = np.deg2rad(lat_deg[at]), np.deg2rad(lon_deg[at])
    east = np.column_stack([-np.sin(lon), np.cos(lon), np.zeros(at.size)])
    north = np.column_stack([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)])
    up = np.column_stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    out = np.column_stack([(v * e).sum(1) for e in (east, north, up)])
    return np.where((dt > 0)[:, None], out, F4_FILL)


def _geophys(s: _Section) -> dict:
    return {"delta_time": s.run.delta_time_s[s.ref_shot],
            "dem_h": _or_fill(s.res.surface_z_m[s.ref_shot])}


def _signal_find(s: _Section) -> dict:
    """One row per histogram block of the run (its noise level, pooled as the test pooled it;
    blocks after the last photon's take the last block's)."""
    test, n_shots = s.test, s.res.n_shots
    n_blocks = -(-n_shots // test.block_shots)
    lam = test.noise_per_bin
    lam = lam[np.minimum(np.arange(n_blocks), lam.size - 1)] if lam.size else np.zeros(n_blocks)
    start = np.arange(n_blocks) * test.block_shots
    return {"bckgrd_mean": lam, "bckgrd_sigma": np.sqrt(lam),
            "delta_time": s.run.delta_time_s[start],
            "t_pc_delta": np.full(n_blocks, test.block_shots / s.inst.prf_hz),
            "z_pc_delta": np.full(n_blocks, test.bin_m)}


# --------------------------------------------------------------------------- bckgrd_atlas
_ROW_SUMS = ("counts", "signal", "rate_sum", "shots")


def noise_rate_hz(res, instrument=None) -> np.ndarray:
    """(n_shots,) the modelled rate of noise events the detector records at each shot of a
    run's result [Hz]: background reaching the detector x fill factor x PDE + every
    channel's dark counts (:func:`~lidar_mitsuba.detector.pmt.noise_rate_per_ns`). What
    ``bckgrd_atlas/bckgrd_rate`` averages over a row's 50 shots, and what our ATL06's
    ``geophysical/bckgrd`` takes at a segment's centre, as NASA's ATL06 takes ATL03's rate
    (``instrument``: the run's, by default ``res.instrument``)."""
    bg = None if res.radiometry is None else res.radiometry.background_mhz
    inst = res.instrument if instrument is None else instrument
    return np.broadcast_to(pmt.noise_rate_per_ns(inst, bg) * 1e9, (res.n_shots,))


def _bckgrd_rows(s: _Section) -> dict:
    """The run's 50-shot rows (of the whole track's grid): sums over the run's shots in each,
    and what the row's first shot gives it (when that shot is in this run).

    ``signal``, ``lo`` and ``hi`` are the row's high-confidence photons (``signal_conf_ph`` 4
    for any surface type: every column we write is the one test's ``conf``), their number and
    lowest and highest height [m]: what real ATL03 takes out of a row's histogram
    (``bckgrd_counts - bckgrd_counts_reduced`` is their number and ``bckgrd_int_height -
    bckgrd_int_height_reduced`` their span in every whole row of the shipped night subset,
    ``tests/test_realism.py::test_atl03_removes_exactly_its_high_confidence_photons_and_their_span``;
    :func:`lidar_mitsuba.night.removed_signal`)."""
    res, inst, g0 = s.res, s.inst, s.run.first_shot
    n = res.n_shots
    row = (g0 + np.arange(n)) // BCKGRD_SHOTS
    lr = row - row[0]
    n_rows = int(lr[-1]) + 1
    rate = noise_rate_hz(res, inst)
    # the rows' high-confidence photons and their extremes, by night's one rule (photons in
    # shot order: ascending rows)
    at = lr[s.shot]
    signal, lo, hi = removed_extremes(row=at, h_m=res.h_m[s.order], high=s.conf == 4,
                                      n_rows=n_rows, ascending=True)
    first = np.searchsorted(lr, np.arange(n_rows))
    return {"row": row[0] + np.arange(n_rows), "counts": np.bincount(at, minlength=n_rows),
            "signal": signal,
            "rate_sum": np.bincount(lr, weights=rate, minlength=n_rows),
            "shots": np.bincount(lr, minlength=n_rows), "lo": lo, "hi": hi,
            "time": s.run.delta_time_s[first],
            "top": s.gate[first] + inst.range_gate_m / 2.0,
            "gate": np.full(n_rows, inst.range_gate_m)}


def _join_rows(held: dict, rows: dict) -> dict:
    """``rows`` with the row held from the previous run merged into its first."""
    if rows["row"][0] != held["row"][0]:           # (a row the track does not continue)
        return {k: np.concatenate([held[k], rows[k]]) for k in rows}
    out = {k: v.copy() for k, v in rows.items()}
    for k in _ROW_SUMS:
        out[k][0] += held[k][0]
    out["lo"][0] = min(out["lo"][0], held["lo"][0])
    out["hi"][0] = max(out["hi"][0], held["hi"][0])
    for k in ("time", "top", "gate"):
        out[k][0] = held[k][0]
    return out


def _bckgrd(rows: dict) -> dict:
    span = np.where(rows["signal"] > 0, rows["hi"] - rows["lo"], 0.0)
    return {"bckgrd_counts": rows["counts"],
            "bckgrd_counts_reduced": rows["counts"] - rows["signal"],
            "bckgrd_hist_top": rows["top"], "bckgrd_int_height": rows["gate"],
            "bckgrd_int_height_reduced": rows["gate"] - span,
            "bckgrd_rate": rows["rate_sum"] / np.maximum(rows["shots"], 1),
            "delta_time": rows["time"],
            "pce_mframe_cnt": rows["row"] * BCKGRD_SHOTS // PULSES_PER_MAJOR_FRAME,
            "tlm_height_band1": rows["gate"], "tlm_top_band1": rows["top"]}


def _append_bckgrd(gt, s: _Section, *, at: tuple | None = None) -> None:
    """Append the run's complete 50-shot rows; hold a row the next run continues (``at``:
    as :func:`_write_group`'s)."""
    key = (h5chunks._file_key(gt), gt.name)
    rows = _bckgrd_rows(s)
    held = _pending.pop(key, None)
    if held is not None:
        rows = _join_rows(held, rows)
    if (s.run.first_shot + s.res.n_shots) % BCKGRD_SHOTS:       # the last row goes on
        _pending[key] = {k: v[-1:] for k, v in rows.items()}
        rows = {k: v[:-1] for k, v in rows.items()}
    _write_group(gt, "bckgrd_atlas", _bckgrd(rows), at=at)


def flush(f) -> None:
    """Append the rows held for file ``f`` (a track's last, shorter than 50 shots)."""
    key = h5chunks._file_key(f)
    for k in [k for k in _pending if k[0] == key]:
        _write_group(f[k[1]], "bckgrd_atlas", _bckgrd(_pending.pop(k)))
    _forget_groups(f)


def discard(f) -> None:
    """Forget the rows held for file ``f`` (its write failed)."""
    key = h5chunks._file_key(f)
    for k in [k for k in _pending if k[0] == key]:
        del _pending[k]
    _forget_groups(f)


def _forget_groups(f) -> None:
    fileno = f.id.fileno
    for k in [k for k in _groups if k[0] == fileno]:
        del _groups[k]


def _group(fileno: int, path: str):
    """The group at ``path`` of the file numbered ``fileno`` (``f.id.fileno``) as this module
    last made or opened it, or ``None``: h5py's lookups of a name cost ~50 us each, and each
    section of each beam asks for ~15 groups."""
    g = _groups.get((fileno, path))
    return g if g is not None and g.id.valid else None


# --------------------------------------------------------------------------- writing
def _write_group(gt, name: str, values: dict, *, at: tuple | None = None) -> None:
    """Append ``values`` to group ``gt/name`` as its fields (:data:`GROUPS`) say: dtype,
    constants for the fields not given, attributes and the ``delta_time`` dimension scale
    when the group is new (its datasets copied from a template:
    :mod:`lidar_mitsuba.products.h5template`). ``at``: ``(HDF5 file number, gt's path)``,
    where the group is kept from section to section (:func:`_group`)."""
    spec = GROUPS[name]
    extra = set(values) - set(spec)
    if extra:
        raise KeyError(f"{name}: not ATL03 fields: {sorted(extra)}")
    n = len(values["delta_time"])
    coordinates = COORDINATES.get(name, "delta_time")
    columns, made = [], []
    for field_name, fld in spec.items():
        v = values.get(field_name, fld.const)
        note = fld.model_note
        if isinstance(v, NotModelled):
            v, note = fld.fill, v.why
        if v is None:
            raise KeyError(f"{name}/{field_name}: no values and no constant")
        data = np.asarray(v)
        if data.ndim == 0 or data.shape[0] != n:
            data = np.broadcast_to(data, (n,) + fld.shape)
        data = data.astype(fld.dtype, copy=False)
        columns.append((field_name, data, fld.units, fld.description,
                        functools.partial(_field_attrs, fld, note, coordinates, field_name),
                        fld.fill))
        made.append((field_name, note, data.dtype.str, data.shape[1:]))
    held = None if at is None else _group(at[0], f"{at[1]}/{name}")
    # (the template's key: the group's fields, notes, dtypes and row shapes make its specs)
    g, new = h5template.put_group(gt, name, columns, key=("atl03", name, tuple(made)),
                                  group=held)
    if at is not None and held is None:
        _groups[(at[0], f"{at[1]}/{name}")] = g
    if new:
        atl03_file.dimension_scale(g)


def _field_attrs(fld, note: str, coordinates: str, name: str) -> dict:
    """A field's attributes after ``units`` and ``description``."""
    attrs = {"long_name": fld.long_name}
    if fld.fill is not None:
        attrs["_FillValue"] = np.asarray(fld.fill, fld.dtype)
    for k, v in fld.attrs.items():
        attrs[k] = np.asarray(v, fld.dtype) if not isinstance(v, str) else v
    coords = " ".join(c for c in coordinates.split() if c != name)
    if coords:
        attrs["coordinates"] = coords
    if note:
        attrs["model_note"] = note
    return attrs


def beam_attrs(beam, sc_orient: int) -> dict:
    """The attributes of a beam's group, ATL03's and ATL06's alike: strength, spot, PCE,
    ground track and the spacecraft's orientation."""
    return {"atlas_beam_type": beam.strength, "atlas_spot_number": str(beam.spot),
            "atlas_pce": f"pce{beam.pce}", "groundtrack_id": beam.name,
            "sc_orientation": "Backward" if sc_orient == 0 else "Forward"}


def write_beam(f, run, sc_orient: int, *, replanned: bool = False) -> None:
    """Append one run (a :class:`~lidar_mitsuba.products.record.BeamRun`: the beam, its result and
    each shot's latitude, longitude, direction and time) to the beam's groups of ATL03 file
    ``f``, and its truth to ``/truth/<beam>``. The file's header
    (:func:`lidar_mitsuba.products.atl03.file.header`) comes first; a file not opened with
    :func:`lidar_mitsuba.products.atl03.atomic_h5file` needs :func:`flush` before it closes.

    The beam's first run gives ``/truth/<beam>`` its ``config`` attribute (JSON). A later
    section of a streamed granule that was planned anew (``replanned``: its snow or roughness
    differs from the section before) adds ``{"first_shot", "config"}`` of its own to the JSON
    list ``section_configs``, so the file says what every section was simulated with."""
    beam = run.beam
    fileno = f.id.fileno
    gt = _group(fileno, f"/{beam.name}")
    if gt is None:
        if beam.name not in f:                            # (the first section's)
            h5chunks.set_attrs(f.create_group(beam.name), {
                **beam_attrs(beam, sc_orient),
                "description": "one ATLAS beam: photons, geolocation, background"})
        gt = _groups[(fileno, f"/{beam.name}")] = f[beam.name]
    at = (fileno, f"/{beam.name}")
    done = h5chunks.rows(gt, "heights/h_ph")              # earlier sections' photons
    s = _Section(run, done)
    _write_group(gt, "heights", _heights(s), at=at)
    _write_group(gt, "geolocation", _geolocation(s, sc_orient), at=at)
    _write_group(gt, "geophys_corr", _geophys(s), at=at)
    _append_bckgrd(gt, s, at=at)
    found = _signal_find(s)
    for surface in SURFACE_TYPES:
        _write_group(gt, f"signal_find_output/{surface}", found, at=at)
    truth = _group(fileno, f"/truth/{beam.name}")
    if truth is None:
        truth = _groups[(fileno, f"/truth/{beam.name}")] = \
            f.require_group("truth").require_group(beam.name)
    groups: dict = {}
    for group, name, data, units, desc in truth_fields(s.res, order=s.order,
                                                       first_shot=run.first_shot):
        groups.setdefault(group, []).append((name, data, units, desc, {}, None))
    for group, columns in groups.items():
        held = _group(fileno, f"/truth/{beam.name}/{group}")
        key = ("truth", group, tuple((c[0], np.asarray(c[1]).dtype.str, np.shape(c[1])[1:],
                                      c[2], c[3]) for c in columns))
        g, _ = h5template.put_group(truth, group, columns, key=key, group=held)
        _groups[(fileno, f"/truth/{beam.name}/{group}")] = g
    if not h5a.exists(truth.id, b"config"):               # (the first section's)
        truth.attrs["config"] = json.dumps(s.res.config)
    elif replanned:                                       # a section with a model of its own
        past = json.loads(truth.attrs.get("section_configs", "[]"))
        past.append({"first_shot": int(run.first_shot), "config": s.res.config})
        truth.attrs["section_configs"] = json.dumps(past)
    atl03_file.extend_extent(f, run.lat_deg, run.lon_deg)


def truth_fields(result, *, order: np.ndarray | None = None, first_shot: int = 0):
    """The ``/truth/<beam>`` datasets of one beam's result: ``(group, name, data, units,
    description)`` with group ``photons`` (per detected photon, in ``order``) or ``shots``
    (per shot); shot numbers count from ``first_shot`` (a granule written in sections)."""
    det = result.detections
    o = slice(None) if order is None else order
    yield "photons", "shot", det.shot[o] + first_shot, "1", "shot index"
    yield "photons", "channel", det.channel[o], "1", "detector channel (0-based)"
    yield "photons", "anode", det.anode[o], "1", "PMT anode segment"
    yield "photons", "is_signal", det.is_signal[o].astype(np.int8), "1", "1 signal, 0 noise"
    yield "photons", "time_ns", det.time_ns[o], "ns", "round-trip time from the pulse centre"
    yield ("photons", "return_index", det.return_index[o], "1",
           "index of the traced return in its run (-1 for noise)")
    yield "photons", "h_m", result.h_m[o], "meters", "photon height (float64)"
    for j, axis in enumerate(("x", "y", "z")):
        yield ("photons", f"hit_{axis}_m", det.hit_xyz_m[o, j], "meters",
               f"{axis} of the scattering point (NaN for noise)")
    yield "shots", "along_track_m", result.along_track_m, "meters", "along-track distance"
    yield "shots", "x_m", result.shot_x_m, "meters", "footprint centre x"
    yield "shots", "y_m", result.shot_y_m, "meters", "footprint centre y"
    yield ("shots", "z_ref_m", result.z_ref_m, "meters",
           "reference elevation: Gaussian-footprint-weighted mean height")
    yield "shots", "surface_z_m", result.surface_z_m, "meters", "height at the footprint centre"
    yield "shots", "arrivals", det.arrivals_per_shot, "1", "photons reaching the detector"
    yield "shots", "mean_photons", det.mean_photons_per_shot, "1", "Poisson mean per shot"
