"""ATL03-layout HDF5 output (lidar_mitsuba.products.atl03): exact round trip of a simulated run, units
and descriptions on every dataset, dtypes, atomic writes, and refusal of foreign files.
No tolerances: the file must give back exactly what was simulated."""
import dataclasses
import json
import os

import h5py
import numpy as np
import pytest

from lidar_mitsuba import __version__
from lidar_mitsuba.products import atl03
from lidar_mitsuba.instrument import Instrument
from lidar_mitsuba.run import simulate
from lidar_mitsuba.ground.surface import SurfaceSpec


@pytest.fixture(scope="module")
def result():
    """200 shots of the weak beam over the flat plate with 20 MHz background: signal and
    noise photons (NaN scattering points), 4 channels."""
    return simulate(instrument=Instrument(beam="weak", background_mhz=20.0),
                    surface=SurfaceSpec(kind="flat"), shots=200, seed=4, progress=False)


@pytest.fixture(scope="module")
def written(result, tmp_path_factory):
    return atl03.write(result, tmp_path_factory.mktemp("atl03") / "run.h5")


def expected_datasets(res):
    """The datasets of the run's photons and truth, with the array each must hold (the run's
    photons are in shot order already: heights/ keeps their order)."""
    d, inst = res.detections, res.instrument
    beam = atl03.BEAM_GROUPS[inst.beam]
    along = res.along_track_m[d.shot]
    return {
        f"{beam}/heights/h_ph": res.h_m.astype(np.float32),             # ATL03's dtypes
        f"{beam}/heights/delta_time": res.geolocation.delta_time_s[d.shot],
        f"{beam}/heights/lat_ph": res.geolocation.lat_deg[d.shot],
        f"{beam}/heights/lon_ph": res.geolocation.lon_deg[d.shot],
        f"{beam}/heights/dist_ph_along": (along - 20.0 * np.floor(along / 20.0)).astype(np.float32),
        f"{beam}/heights/signal_conf_ph": np.repeat(res.signal_conf[:, None], 5, axis=1),
        f"truth/{beam}/photons/shot": d.shot,
        f"truth/{beam}/photons/channel": d.channel,
        f"truth/{beam}/photons/anode": d.anode,
        f"truth/{beam}/photons/is_signal": d.is_signal.astype(np.int8),
        f"truth/{beam}/photons/time_ns": d.time_ns,
        f"truth/{beam}/photons/return_index": d.return_index,
        f"truth/{beam}/photons/h_m": res.h_m,
        f"truth/{beam}/photons/hit_x_m": d.hit_xyz_m[:, 0],
        f"truth/{beam}/photons/hit_y_m": d.hit_xyz_m[:, 1],
        f"truth/{beam}/photons/hit_z_m": d.hit_xyz_m[:, 2],
        f"truth/{beam}/shots/along_track_m": res.along_track_m,
        f"truth/{beam}/shots/x_m": res.shot_x_m,
        f"truth/{beam}/shots/y_m": res.shot_y_m,
        f"truth/{beam}/shots/z_ref_m": res.z_ref_m,
        f"truth/{beam}/shots/surface_z_m": res.surface_z_m,
        f"truth/{beam}/shots/arrivals": d.arrivals_per_shot,
        f"truth/{beam}/shots/mean_photons": d.mean_photons_per_shot,
    }


def test_the_run_has_what_the_round_trip_needs(result):
    d = result.detections
    assert result.instrument.beam == "weak" and result.n_shots == 200
    assert d.is_signal.any() and (~d.is_signal).any()             # signal and noise photons
    assert np.isnan(d.hit_xyz_m[~d.is_signal]).all()
    assert len(set(result.signal_conf.tolist())) > 1               # confidence varies


def test_every_array_round_trips_exactly(result, written):
    from lidar_mitsuba.products.atl03.fields import GROUPS
    expect = expected_datasets(result)
    with h5py.File(written) as f:
        names = set()
        f.visititems(lambda name, obj: names.add(name) if isinstance(obj, h5py.Dataset) else None)
        # the beam: ATL03's fields and nothing else; the truth: the documented datasets
        assert {n for n in names if n.startswith(("gt", "truth"))} == (
            {n for n in expect if n.startswith("truth")}
            | {f"gt1r/{g}/{k}" for g, spec in GROUPS.items() for k in spec})
        assert "orbit_info/sc_orient" in names
        for name, data in expect.items():
            got = f[name][()]
            assert got.shape == np.shape(data), name
            assert got.dtype == np.asarray(data).dtype, name
            np.testing.assert_array_equal(got, data, err_msg=name)   # NaN == NaN here
        assert f["orbit_info/sc_orient"][()] == 0
        assert f["gt1r"].attrs["atlas_beam_type"] == "weak"
        assert f.attrs["lidar_mitsuba_version"] == __version__
        assert json.loads(f.attrs["config"]) == json.loads(json.dumps(result.config))
    back = atl03.read(written)
    d = result.detections
    for key, data in (("h_m", result.h_m), ("shot", d.shot), ("channel", d.channel),
                      ("is_signal", d.is_signal), ("signal_conf", result.signal_conf),
                      ("z_ref_m", result.z_ref_m), ("along_track_m", result.along_track_m),
                      ("surface_z_m", result.surface_z_m)):
        assert back[key].dtype == np.asarray(data).dtype, key
        np.testing.assert_array_equal(back[key], data, err_msg=key)
    assert back["beam"] == "gt1r" and back["n_shots"] == 200 and back["n_channels"] == 4
    assert back["config"] == json.loads(json.dumps(result.config))


def test_dtypes_and_attributes(written):
    with h5py.File(written) as f:
        h = f["gt1r/heights"]
        n = h["h_ph"].shape[0]
        assert n > 0
        assert h["signal_conf_ph"].dtype == np.int8 and h["signal_conf_ph"].shape == (n, 5)
        assert set(np.unique(h["signal_conf_ph"][()])) <= {0, 2, 3, 4}
        for name, dtype in (("h_ph", np.float32), ("delta_time", np.float64),
                            ("dist_ph_along", np.float32)):                # ATL03's dtypes
            assert h[name].dtype == dtype and h[name].shape == (n,)
        assert f["truth/gt1r/photons/time_ns"].dtype == np.float64
        assert f["truth/gt1r/photons/is_signal"].dtype == np.int8

        def check(name, obj):
            if isinstance(obj, h5py.Dataset) and name not in ("orbit_info/sc_orient",
                                                              "ds_surf_type", "ds_xyz"):
                assert obj.attrs["units"], name
                assert len(obj.attrs["description"]) > 5, name
        f.visititems(check)
        assert h["h_ph"].attrs["units"] == "meters"
        assert h["delta_time"].attrs["units"] == "seconds since 2018-01-01"
        assert f["truth/gt1r/photons/time_ns"].attrs["units"] == "ns"


def test_a_failed_write_leaves_nothing(tmp_path):
    target = tmp_path / "out.h5"
    with pytest.raises(RuntimeError, match="boom"):
        with atl03.atomic_h5file(target) as f:
            f.create_dataset("x", data=np.arange(10))
            assert any(p.name.endswith(".tmp") for p in tmp_path.iterdir())   # written beside
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    # a success replaces the target in one step, and leaves no temporary file
    with atl03.atomic_h5file(target) as f:
        f.create_dataset("x", data=np.arange(3))
    assert [p.name for p in tmp_path.iterdir()] == ["out.h5"]
    # a failing write over an existing file keeps the old one intact
    with pytest.raises(KeyboardInterrupt):
        with atl03.atomic_h5file(target) as f:
            f.create_dataset("x", data=np.arange(99))
            raise KeyboardInterrupt
    assert [p.name for p in tmp_path.iterdir()] == ["out.h5"]
    with h5py.File(target) as f:
        np.testing.assert_array_equal(f["x"][()], np.arange(3))


def test_write_of_a_broken_result_leaves_nothing(result, tmp_path):
    """A failure inside atl03.write itself (here: a config that is not JSON) leaves no file."""
    bad = dataclasses.replace(result, config={"x": object()})
    with pytest.raises(TypeError):
        atl03.write(bad, tmp_path / "bad.h5")
    assert list(tmp_path.iterdir()) == []


def test_read_refuses_a_file_that_is_not_ours(tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.create_dataset("gt1l/heights/h_ph", data=np.zeros(3))   # ATL03-like, no truth/config
    with pytest.raises(ValueError, match="not a lidar_mitsuba ATL03 file"):
        atl03.read(other)
    empty = tmp_path / "empty.h5"
    h5py.File(empty, "w").close()
    with pytest.raises(ValueError, match="not a lidar_mitsuba ATL03 file"):
        atl03.read(empty)
    assert os.path.exists(other) and os.path.exists(empty)           # reading changes nothing


def test_ph_id_count_compiled_is_the_numpy_sort(rng, monkeypatch):
    """ATL03's ``ph_id_count`` from the compiled pass over photons in shot order
    (products.atl03.kernels) is its numpy form's (a stable sort by shot and channel), with
    more than 255 events of one shot and channel; photons out of shot order are left to
    numpy."""
    from lidar_mitsuba.products.atl03 import beam, kernels
    shot = np.sort(rng.integers(0, 500, 4000))
    channel = rng.integers(0, 16, shot.size).astype(np.int16)
    shot[:300], channel[:300] = 0, 5
    fast = beam._ph_id_count(shot, channel)
    assert not kernels.ph_id_count(shot[::-1].copy(), channel, np.empty(shot.size, np.uint8))
    monkeypatch.setattr(kernels, "ph_id_count", lambda *args: False)
    np.testing.assert_array_equal(fast, beam._ph_id_count(shot, channel))
    assert fast.dtype == np.uint8 and fast.max() == 255 and fast.min() == 1


def test_quality_ph_by_runs_of_shots_is_the_unbuffered_maximum():
    """``quality_ph`` takes each saturated pulse's highest surface event by a maximum over the
    shot's run of photons (photons in shot order) instead of ``np.maximum.at``: the same flags
    for random sections with NaN heights, empty shots and both kinds of saturation."""
    import types
    from lidar_mitsuba.products.atl03 import beam
    gen = np.random.default_rng(3)
    flagged = 0
    for _ in range(100):
        n_shots, n = 50, int(gen.integers(0, 400))
        shot = np.sort(gen.integers(0, n_shots, n))
        h = gen.normal(0.0, 20.0, n)
        h[gen.random(n) < 0.02] = np.nan
        conf = gen.integers(0, 5, n).astype(np.int8)
        full = gen.random(n_shots) < 0.3
        near = (gen.random(n_shots) < 0.3) & ~full
        s = types.SimpleNamespace(shot=shot, conf=conf, saturated=(full, near),
                                  order=slice(None), res=types.SimpleNamespace(h_m=h))
        top = np.full(n_shots, -np.inf)                 # the numpy form it replaced
        surf = conf >= 2
        with np.errstate(invalid="ignore"):
            np.maximum.at(top, shot[surf], h[surf])
            depth = np.where((full | near)[shot], top[shot] - h, -np.inf)
        want = np.zeros(n, np.int8)
        for lo, hi, flag in beam.QUALITY_WINDOWS_M:
            want[(depth > lo) & (depth <= hi)] = flag
        with np.errstate(invalid="ignore"):
            got = beam._quality(s)
        np.testing.assert_array_equal(got, want)
        flagged += int((want > 0).sum())
    assert flagged > 0                                  # (the windows were reached)
