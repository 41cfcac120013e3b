"""HDF5 output in the ICESat-2 ATL03 layout, plus a documented truth group.

Layout (one beam per file)::

    /                         attrs: lidar_mitsuba_version, config (JSON), description
    /orbit_info/sc_orient     0 = backward: left beams strong (gt1l strong, gt1r weak)
    /<beam>/                  gt1l (strong) or gt1r (weak); attrs atlas_beam_type
        heights/h_ph          (n,) float64  photon elevation [m]
        heights/delta_time    (n,) float64  transmit time of the photon's shot [s] from the first shot
        heights/dist_ph_along (n,) float64  along-track distance of the footprint centre [m]
        heights/signal_conf_ph (n, 5) int8  ATL03 confidence (0 noise, 2 low, 3 medium, 4 high)
                                            from lidar_mitsuba.classify, same in all 5 columns
    /truth/photons/           per detected photon (n,): shot, channel, anode, is_signal,
                              time_ns [ns], return_index, h_m [m] (float64),
                              hit_x_m/hit_y_m/hit_z_m [m]
    /truth/shots/             per shot (n_shots,): along_track_m, x_m, y_m [m], z_ref_m [m]
                              (Gaussian-footprint mean height), surface_z_m [m], arrivals,
                              mean_photons

Every position of /truth is in one frame: the scene's coordinates [m] of the track as flown
(a track longer than a built-in tile is traced folded into the tile, and its scattering points
are moved back), so ``hit_x_m`` of a photon lies within a few footprint sigmas of ``x_m`` of
its shot. Heights are measured from the scene's z = 0 (``h_ph`` = altitude - c t / 2, the
spacecraft at ``altitude_m`` above z = 0).

Files are written atomically (a temporary file in the same folder, renamed on success) with
the permissions of any new file (0666 less the umask).
"""
from __future__ import annotations

import contextlib
import json
import os
import pathlib
import tempfile

import h5py
import numpy as np

from . import __version__, h5chunks

BEAM_GROUPS = {"strong": "gt1l", "weak": "gt1r"}


def write(result, path: str | os.PathLike) -> pathlib.Path:
    """Write a :class:`~lidar_mitsuba.simulate.SimulationResult` to ``path`` atomically."""
    path = pathlib.Path(path)
    inst = result.instrument
    det = result.detections
    with atomic_h5file(path) as f:
        f.attrs["lidar_mitsuba_version"] = __version__
        f.attrs["config"] = json.dumps(result.config)
        f.attrs["description"] = ("Simulated ATL03-like photon data (lidar_mitsuba); "
                                  "see /truth for the simulation truth.")
        _ds(f.require_group("orbit_info"), "sc_orient", np.int8(0), "1",
            "spacecraft orientation: 0 backward (left beams strong), 1 forward, 2 transition")
        g = f.create_group(f"{BEAM_GROUPS[inst.beam]}/heights")
        f[BEAM_GROUPS[inst.beam]].attrs["atlas_beam_type"] = inst.beam
        _ds(g, "h_ph", result.h_m, "meters", "photon elevation: altitude - c t / 2")
        _ds(g, "delta_time", det.shot / inst.prf_hz, "seconds",
            "transmit time of the photon's shot since the first shot")
        _ds(g, "dist_ph_along", result.along_track_m[det.shot], "meters",
            "along-track distance of the footprint centre from the first shot")
        _ds(g, "signal_conf_ph", np.repeat(result.signal_conf[:, None], 5, axis=1), "counts",
            "ATL03 confidence (land, ocean, sea ice, land ice, inland water; the same "
            "histogram test in every column): 0 noise, 2 low, 3 medium, 4 high")
        for group, name, data, units, desc in truth_fields(result):
            _ds(f.require_group(f"truth/{group}"), name, data, units, desc)
    return path


def truth_fields(result, *, order: np.ndarray | None = None, first_shot: int = 0):
    """The ``/truth`` datasets of one beam's result: ``(group, name, data, units,
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


@contextlib.contextmanager
def atomic_h5file(path: str | os.PathLike):
    """An ``h5py.File`` open for writing on a temporary file beside ``path``; renamed to
    ``path`` when the block succeeds, removed when it fails, so a failed write leaves nothing."""
    path = pathlib.Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent or ".")
    os.close(fd)
    try:
        with h5py.File(tmp, "w") as f:
            try:
                yield f
                h5chunks.drain(f)          # the chunks still being compressed
            except BaseException:
                h5chunks.discard(f)
                raise
        os.chmod(tmp, 0o666 & ~_umask())      # mkstemp makes 0600; a new file follows the umask
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _ds(group, name, data, units, description):
    return h5chunks.put(group, name, data, units, description)


def read(path: str | os.PathLike) -> dict:
    """Read what ``stats`` needs: per photon ``h_m``, ``shot``, ``channel``, ``is_signal``,
    ``signal_conf``;
    per shot ``z_ref_m``, ``along_track_m``, ``surface_z_m``; and ``config``, ``beam``,
    ``n_shots``, ``n_channels``. Raises ``ValueError`` for a file that is not ours."""
    with h5py.File(path, "r") as f:
        beams = [b for b in BEAM_GROUPS.values() if b in f]
        if not beams or "truth" not in f or "config" not in f.attrs:
            raise ValueError(f"{path} is not a lidar_mitsuba ATL03 file")
        beam = beams[0]
        config = json.loads(f.attrs["config"])
        out = {
            "beam": beam, "config": config,
            "h_m": f[f"{beam}/heights/h_ph"][()],
            "shot": f["truth/photons/shot"][()],
            "channel": f["truth/photons/channel"][()],
            "is_signal": f["truth/photons/is_signal"][()].astype(bool),
            "signal_conf": f[f"{beam}/heights/signal_conf_ph"][:, 3],
            "z_ref_m": f["truth/shots/z_ref_m"][()],
            "along_track_m": f["truth/shots/along_track_m"][()],
            "surface_z_m": f["truth/shots/surface_z_m"][()],
        }
    out["n_shots"] = int(out["z_ref_m"].size)
    out["n_channels"] = int(config["instrument"]["channels"])
    return out
