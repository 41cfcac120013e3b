"""HDF5 output in the ICESat-2 ATL03 layout, plus a documented truth group.

:func:`write` writes one run as a one-beam ATL03 file, the same layout as one beam of a
granule (:mod:`lidar_mitsuba.granule`; the writer is :mod:`lidar_mitsuba.products.atl03.beam` and
:mod:`lidar_mitsuba.products.atl03.file`), so the same reader code opens both, and real granules::

    /                         attrs: short_name ATL03, lidar_mitsuba_version, config (JSON), ...
    /orbit_info/sc_orient     0 = backward: left beams strong (gt1l strong, gt1r weak)
    /ancillary_data/, /atlas_impulse_response/, /METADATA/
    /<beam>/                  gt1l (strong) or gt1r (weak); attrs atlas_beam_type, ...
        heights/, geolocation/, bckgrd_atlas/, geophys_corr/, signal_find_output/<type>/:
                              every dataset of a real granule's beam group, with its dtype,
                              shape, units and fill value (lidar_mitsuba.products.atl03.fields)
    /truth/<beam>/photons/    per detected photon (n,), in the order of heights/: shot,
                              channel, anode, is_signal, time_ns [ns], return_index,
                              h_m [m] (float64), hit_x_m/hit_y_m/hit_z_m [m]
    /truth/<beam>/shots/      per shot (n_shots,): along_track_m, x_m, y_m [m], z_ref_m [m]
                              (Gaussian-footprint mean height), surface_z_m [m], arrivals,
                              mean_photons
    /truth/<beam>             attrs: config (JSON: the run's model and choices); in a granule
                              whose later sections were planned anew (snow or roughness
                              varying along the track), section_configs (JSON list of each
                              such section's first_shot and config)

The shots are placed on the Earth by the run's geolocation (``result.geolocation``: the scene
origin at ``--lat``/``--lon``, the first shot at ``--epoch``; by default the paper's site in
northern Greenland): ``lat_ph``, ``lon_ph``, ``delta_time`` [s since 2018-01-01].

Every position of /truth is in one frame: the scene's coordinates [m] of the track as flown
(a track longer than a built-in tile is traced folded into the tile, and its scattering points
are moved back), so ``hit_x_m`` of a photon lies within a few footprint sigmas of ``x_m`` of
its shot. Heights are measured from the scene's z = 0 (``h_ph`` = altitude - c t / 2, the
spacecraft at ``altitude_m`` above z = 0). :func:`read` reads these files, granules and the
files of earlier versions (one beam, truth in ``/truth/photons``, ``/truth/shots``).

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

from . import beam as atl03_beam, file as atl03_file
from ... import geotrack
from .. import h5write as h5chunks
from ..record import BEAM_GROUPS, Granule  # noqa: F401  (BEAM_GROUPS: readers use it)
from .beam import truth_fields  # noqa: F401  (the truth datasets, re-exported)


def write(result, path: str | os.PathLike) -> pathlib.Path:
    """Write a :class:`~lidar_mitsuba.run.SimulationResult` to ``path`` atomically: one
    beam (``gt1l`` strong, ``gt1r`` weak; spacecraft orientation 0) at the run's
    geolocation (:meth:`~lidar_mitsuba.products.record.Granule.single`).

    >>> import lidar_mitsuba as lm
    >>> lm.write_atl03(lm.simulate(shots=100), "run.h5")                # doctest: +SKIP"""
    path = pathlib.Path(path)
    granule = Granule.single(result)
    with atomic_h5file(path) as f:
        atl03_file.header(f, granule, *granule.span(), path=path)
        atl03_beam.write_beam(f, granule.beams[0], 0)
    return path


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
                atl03_beam.flush(f)        # rows held for a next section
                h5chunks.drain(f)          # the chunks still being compressed
            except BaseException:
                atl03_beam.discard(f)
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


def read(path: str | os.PathLike, beam: str | None = None) -> dict:
    """Read what ``stats`` needs from one beam (``beam``, default the first of ``gt1l`` ..
    ``gt3r`` the file has) of one of our ATL03 files (one run, a granule, or a file of an
    earlier version): per photon ``h_m`` (float64), ``shot``, ``channel``, ``is_signal``,
    ``signal_conf``; per shot ``z_ref_m``, ``along_track_m``, ``surface_z_m``; and ``config``
    (the beam's run's), ``beam``, ``n_shots``, ``n_channels``. Raises ``ValueError`` for a file
    that is not ours or a beam it lacks.

    >>> import lidar_mitsuba as lm
    >>> beam = lm.read_atl03("run.h5")     # no renderer needed   # doctest: +SKIP
    >>> beam["h_m"][:3], beam["n_shots"]                            # doctest: +SKIP"""
    with h5py.File(path, "r") as f:
        truth = f.get("truth")
        beams = [b.name for b in geotrack.beam_layout(0)
                 if b.name in f and truth is not None and (b.name in truth or "photons" in truth)]
        if not beams or "config" not in f.attrs:
            raise ValueError(f"{path} is not a lidar_mitsuba ATL03 file")
        beam = beams[0] if beam is None else beam
        if beam not in beams:
            raise ValueError(f"{path} has no beam {beam!r} (it has {', '.join(beams)})")
        t = truth[beam] if beam in truth else truth       # (earlier versions: /truth/photons)
        config = json.loads(t.attrs["config"] if "config" in t.attrs else f.attrs["config"])
        out = {
            "beam": beam, "config": config,
            "h_m": t["photons/h_m"][()],
            "shot": t["photons/shot"][()],
            "channel": t["photons/channel"][()],
            "is_signal": t["photons/is_signal"][()].astype(bool),
            "signal_conf": f[f"{beam}/heights/signal_conf_ph"][:, 3],
            "z_ref_m": t["shots/z_ref_m"][()],
            "along_track_m": t["shots/along_track_m"][()],
            "surface_z_m": t["shots/surface_z_m"][()],
        }
    out["n_shots"] = int(out["z_ref_m"].size)
    out["n_channels"] = int(config["instrument"]["channels"])
    return out
