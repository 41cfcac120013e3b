"""Peer comparison through water and cloud (lidar_mitsuba.studies.peer_media): mediapathlength
against mitransient's transient path tracers on a lake and a cloud layer, both tools' impulse
responses in OPL bins and their scale-free ratios, within Monte Carlo error. Fixed seeds;
small runs (~25 s together on 2 cores)."""
import numpy as np
import pytest

from lidar_mitsuba.studies import peer_media

pytest.importorskip("mitransient", reason="pip install 'lidar_mitsuba[bench]'")


def _check(res, *, min_dof):
    assert res["dof"] >= min_dof, res["dof"]
    assert res["p_value"] > 1e-3, (res["chi2"], res["dof"])
    for key in ("ours", "mitransient"):
        assert np.sum(res[key]) == pytest.approx(1.0, abs=1e-9)
    for r in res["ratios"]:
        assert abs(r["z"]) < 4.0, r
        assert r["ours_se"] > 0 and r["mitransient_se"] > 0, r


def test_lake_bottom_and_surface_agree_with_mitransient(tmp_path):
    """Rough water (roughdielectric, Beckmann 0.1) over a 0.5 bottom 1 m down. The bottom is
    where it should be in both tools once mitransient's two artefacts are moved out (the
    projector leg from under the surface counted at n, the float32 spawn offsets), and the
    bottom / surface ratio is the closed form T^2 rho 4 alpha^2 / (n^2 F) in ours (to its
    small error and the roughness's 1e-3) and in mitransient (to its error)."""
    res = peer_media.lake(shots=4096, paths=64, batches=64, spp=2 ** 18, seeds=16, seed=1)
    _check(res, min_dof=1)
    assert res["mitransient_mass_elsewhere"] < 1e-9
    ratio = res["ratios"][0]
    assert ratio["name"] == "bottom / surface"
    assert ratio["ours"] == pytest.approx(ratio["closed_form"], rel=3e-3)
    edges = np.asarray(res["edges_m"])
    bottom = np.argmax(np.where(edges[:-1] > 1.0, res["ours"], 0.0))
    assert edges[bottom] < peer_media.WATER_IOR * 2 * peer_media.LAKE_DEPTH_M < edges[bottom + 1]
    assert np.argmax(res["mitransient"][bottom - 1:bottom + 2]) == 1
    peer_media.plot([res], tmp_path / "lake.png")
    assert (tmp_path / "lake.png").stat().st_size > 10_000


def test_cloud_layer_agrees_with_mitransient_prbvolpath():
    """tau = 0.5 layer (albedo 0.9, HG 0.7) 10-30 m above a 0.9 plate: layer backscatter,
    direct ground and the forward-scattered late ground agree bin by bin (0.5 m OPL) with
    transient_prbvolpath; the direct-ground bin holds at least the unscattered exp(-2 tau)."""
    res = peer_media.cloud(shots=2048, paths=64, batches=64, spp=2 ** 19, seeds=16, seed=1)
    _check(res, min_dof=100)
    ratios = {r["name"]: r for r in res["ratios"]}
    direct = ratios["direct ground / clear plate"]
    assert direct["ours"] > res["unscattered_ground_over_plate"]
    assert ratios["layer / clear plate"]["ours"] > 0.9 * res["single_scattering_layer_over_plate"]
