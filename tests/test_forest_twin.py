"""The forest twin's inputs (studies.forest_twin) and the cover study's quick mode
(studies.canopy_cover), issue 42."""
from __future__ import annotations

import math
import pathlib

import numpy as np
import pytest

REAL_DIR = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "real"
REAL_ATL08 = REAL_DIR / "ATL08_gt1r_20220401_forest_wyoming.h5"
REAL_ATL03 = REAL_DIR / "ATL03_gt1r_20220401_forest_wyoming.h5"
needs_real = pytest.mark.skipif(not REAL_ATL08.exists(), reason="real forest clip not here")


@needs_real
def test_twin_inputs_come_from_the_clips_atl08_and_the_stand_holds_them():
    """The inputs are the file's (weak beam by its attribute and sc_orient 0; the medians of
    h_canopy and segment_cover; the DEM's along-track slope, the DEM rising south-bound) and
    the stand reproduces them: its cover within the Boolean model's sampling error (a
    binomial stem count over 256 m x 256 m: sd of the cover ~ (1 - c) |ln(1 - c)| / sqrt(n),
    < 0.002 here: 0.01 is 5 sd), the 98th percentile of its tree heights within 1 % of
    h_canopy (~9e4 trees: the percentile's sampling sd is ~0.1 %)."""
    import h5py
    from lidar_mitsuba.studies import forest_twin as ft
    i = ft.site_inputs(REAL_ATL08, "gt1r")
    with h5py.File(REAL_ATL08) as f:
        ls = f["gt1r/land_segments"]
        h = ls["canopy/h_canopy"][()]
        cover = ls["canopy/segment_cover"][()]
    assert i["strength"] == "weak" and i["sc_orient"] == 0
    assert i["h_canopy_m"] == pytest.approx(float(np.median(h)))
    assert i["cover"] == pytest.approx(float(np.median(cover)) / 100)
    assert 0.05 < i["slope"] < 0.2 and abs(abs(i["track_azimuth_deg"]) - 180) < 10
    f = ft.twin_forest(i)
    s = f.stand
    assert s.canopy_cover() == pytest.approx(i["cover"], abs=0.01)
    assert np.percentile(s.height_m, 98) == pytest.approx(i["h_canopy_m"], rel=0.01)
    assert f.representation == "gap" and f.ground.slope_deg == pytest.approx(
        math.degrees(math.atan(i["slope"])))
    # the plane rises along the track (heading south-south-west): 100 m on, 100 slope m higher
    az = math.radians(i["track_azimuth_deg"])
    dx, dy = 100 * math.sin(az), 100 * math.cos(az)
    rise = f.ground.height_m(128 + dx, 128 + dy) - f.ground.height_m(128.0, 128.0)
    assert rise == pytest.approx(100 * i["slope"], rel=1e-6)


@needs_real
def test_nasa_counts_are_the_products_own_per_shot():
    """NASA's ground and canopy photons per shot are the segments' counts over their shots
    (PRF / ground speed x 100 m), the height bins hold every classed photon in range."""
    import h5py
    from lidar_mitsuba.studies import forest_twin as ft
    spm = 1.4
    n = ft.nasa_counts(REAL_ATL08, "gt1r", spm)
    with h5py.File(REAL_ATL08) as f:
        ls = f["gt1r/land_segments"]
        te = ls["terrain/n_te_photons"][()]
        ca = ls["canopy/n_ca_photons"][()] + ls["canopy/n_toc_photons"][()]
        ph_h = f["gt1r/signal_photons/ph_h"][()]
        flag = f["gt1r/signal_photons/classed_pc_flag"][()]
    assert n["ground_per_shot"] == pytest.approx(np.median(te) / 140.0)
    assert n["canopy_per_shot"] == pytest.approx(np.median(ca) / 140.0)
    lo, hi = ft.HEIGHT_BINS_M[0], ft.HEIGHT_BINS_M[-1]
    inside = (flag > 0) & (ph_h >= lo) & (ph_h <= hi)
    assert sum(n["height_per_shot"]) * 140.0 * te.size == pytest.approx(inside.sum())


def test_cover_study_quick_ground_follows_the_gap_probability():
    """Bare ground and 80 % cover, strong beam by night, 300 shots each, flat ground at
    z = 0: our ATL08 finds the ground in every segment within 0.3 m (the pulse's 0.1 m
    spread, ~100 ground photons per segment), and the ratio of the ground photons per shot
    (forest over bare) is the stand's mean gap probability over the tile (closed form, hot
    spot: P_gap, not P_gap^2) within 3 sigma of its Poisson error (sqrt(1/N1 + 1/N2)) plus
    10 % for what the classifier's ground buffer adds or drops (ESTIMATE)."""
    from lidar_mitsuba.studies import canopy_cover as cc
    from lidar_mitsuba.vegetation import gap, turbid
    doc = cc.run(quick=True, progress=None)
    bare, dense = doc["rows"]
    assert bare["p_ground"] == 1.0 and dense["p_ground"] == 1.0
    assert abs(bare["terrain_bias_m"]) < 0.3 and abs(dense["terrain_bias_m"]) < 0.3
    rng = np.random.default_rng(3)
    s = cc.stand_surface(0.8, seed=1).stand
    t = turbid.canopy_table(s, rho=0.1, tau=0.0)
    x, y = cc.TILE_M * rng.random(2000), cc.TILE_M * rng.random(2000)
    g = gap.gap_probability(t, x, y, 0.0)
    expected, without_hot_spot = float(g.mean()), float((g ** 2).mean())
    n1 = bare["ground_per_shot"] * bare["segments"] * 100 * 1.43
    n2 = dense["ground_per_shot"] * dense["segments"] * 100 * 1.43
    measured = dense["ground_per_shot"] / bare["ground_per_shot"]
    tol = expected * (3 * math.sqrt(1 / n1 + 1 / n2) + 0.1)
    assert abs(measured - expected) < tol, (measured, expected, tol)
    # 300 shots tell a ratio off by ~40 % (a canopy that hides or shows the ground wrongly),
    # not the hot spot itself (P_gap^2's mean, ``without_hot_spot``, lies within the
    # tolerance): tests/test_canopy's hot-spot tests check that on their own
    assert without_hot_spot < expected


def test_layer_signal_is_the_count_less_the_background():
    """``layer_signal`` on a synthetic cloud with a known answer: 2000 shots, ground photons
    Poisson(0.2) within +-0.3 m, canopy Poisson(0.6) uniform over 3-9 m, background 0.0125
    per m per shot (1.9 MHz) uniform over -30..30 m. Expected per shot: ground 0.2, the
    understorey 0, canopy 0.6; the sampling sd of a layer's count per shot is sqrt(mean/2000):
    canopy sqrt((0.6 + 0.16)/2000) = 0.02, so 0.08 (4 sd); ground and understorey 0.03."""
    from lidar_mitsuba.studies import forest_twin as ft
    rng = np.random.default_rng(7)
    n, bg = 2000, 0.0125
    dh = np.r_[rng.uniform(-0.3, 0.3, rng.poisson(0.2 * n)),
               rng.uniform(3, 9, rng.poisson(0.6 * n)),
               rng.uniform(-30, 30, rng.poisson(bg * 60 * n)), np.nan]
    got = ft.layer_signal(dh, shots=n, background_per_m_shot=bg)
    assert got["ground"] == pytest.approx(0.2, abs=0.03)
    assert got["understorey"] == pytest.approx(0.0, abs=0.03)
    assert got["canopy"] == pytest.approx(0.6, abs=0.08)


@needs_real
def test_nasa_ground_puts_its_ground_photons_at_the_ground():
    """Heights above NASA's ground joined from its own classed photons: NASA's ground photons
    lie within its ground band there (median |dh| < 0.5 m, the clip's slopes spreading them by
    up to ~0.5 m), every listed photon maps (1610 of 1771 listed lie in the clip's ATL03), and
    the background per metre per shot is the file's ~1.9 MHz x 2/c."""
    import h5py
    from lidar_mitsuba.studies import forest_twin as ft
    r = ft.nasa_ground_dh(REAL_ATL03, REAL_ATL08, "gt1r")
    assert r["mapped"] > 1500 and 1000 < r["shots"] < 1300
    assert r["background_per_m_shot"] == pytest.approx(1.9e6 * 2 / 299792458.0, rel=0.1)
    layers = ft.layer_signal(r["dh_m"], shots=r["shots"],
                             background_per_m_shot=r["background_per_m_shot"])
    assert layers["canopy"] > layers["ground"] > 0
    with h5py.File(REAL_ATL08) as f:
        n_te = f["gt1r/land_segments/terrain/n_te_photons"][()].sum()
    # NASA's ground photons are within the +-1 m layer (their count over the span's shots)
    assert layers["ground"] * r["shots"] > 0.9 * n_te


def test_the_clips_background_is_its_own_rows_not_its_granules(tmp_path):
    """A clip keeps its granule's whole ``bckgrd_atlas`` table (the two ICESat2VegR clips of
    one granule both hold its 102 093 rows): the background rate is the median over the rows
    at the clip's geolocation segments (the row at or after each, as the realism matrix reads
    it), not over the granule's; without segments, at its photons."""
    import h5py
    from lidar_mitsuba.studies import forest_twin as ft
    path = tmp_path / "ATL03_clip.h5"
    rows_t = np.arange(1000) * 0.005                      # the granule's rows, 5 s
    rate = np.where((rows_t > 2.0) & (rows_t < 2.1), 4.0e6, 1.0e6)
    with h5py.File(path, "w") as f:
        f["gt1r/bckgrd_atlas/delta_time"] = rows_t
        f["gt1r/bckgrd_atlas/bckgrd_rate"] = rate.astype(np.float32)
        f["gt1r/heights/delta_time"] = np.linspace(2.01, 2.09, 50)
    assert ft.background_hz(path, "gt1r") == pytest.approx(4.0e6)
    assert float(np.median(rate)) == pytest.approx(1.0e6)          # the granule's median
    with h5py.File(path, "a") as f:                      # segments outside the bright rows
        f["gt1r/geolocation/delta_time"] = np.linspace(3.0, 3.5, 20)
    assert ft.background_hz(path, "gt1r") == pytest.approx(1.0e6)


def test_snow_cover_classes_take_the_published_snow_albedos():
    """Moody et al. 2007's snow-covered albedos (0.47 um, its abstract) by class, the two
    land-cover code lists ATL08 carries (Copernicus from release 005: 111/121 evergreen needle
    leaf, 115/125 mixed, 40 cropland, 60 bare, 70 snow and ice; IGBP before: 1, 5, 12, 16, 15)
    and the stand-ins said as ESTIMATE; water and unknown classes have none."""
    from lidar_mitsuba.vegetation import snow_cover as sc
    for codes, albedo in (((111, 121, 1), 0.36), ((115, 125, 5), 0.39), ((40, 12, 14), 0.76),
                          ((60, 16), 0.87), ((70, 15), 0.95)):
        for c in codes:
            a, _, source = sc.snow_covered_albedo(c)
            assert a == albedo and "ESTIMATE" not in source, c
    for c, stand in ((20, 0.39), (114, 0.39), (8, 0.39), (30, 0.76), (90, 0.76), (13, 0.76)):
        a, _, source = sc.snow_covered_albedo(c)
        assert a == stand and "ESTIMATE" in source and "standing in" in source, c
    for c in (0, 17, 80, 200, 999, -1):
        assert sc.snow_covered_albedo(c) is None, c
    # forests under snow stay far below snow's own albedo: the crowns shade it
    assert max(sc.SNOW_COVERED_ALBEDO[k] for k in ("evergreen needleleaf forest",
                                                  "mixed forest")) < 0.5


def test_snow_on_the_ground_is_the_flags_fraction_and_the_snowy_classes_mean():
    """segment_snowcover 2 (snow) and 3 (ice) count as snow, 0 and 1 not; fill (127) and
    other values are not flags; the albedo is the mean over the snowy segments whose class
    has one (a lake's segment has none); without landcover, a fraction and no albedo."""
    from lidar_mitsuba.vegetation.snow_cover import snow_on_ground
    snow = np.array([2, 2, 3, 1, 127, 0], np.int8)
    land = np.array([111, 40, 80, 111, 111, 111], np.int16)
    s = snow_on_ground(snow, land)
    assert s["snow_fraction"] == pytest.approx(3 / 5)
    assert s["albedo"] == pytest.approx((0.36 + 0.76) / 2)         # the lake (80): none
    assert len(s["sources"]) == 2
    assert snow_on_ground(snow, None) == {"snow_fraction": pytest.approx(0.6), "albedo": None,
                                          "sources": []}
    assert snow_on_ground(np.full(4, 127, np.int8), land[:4])["snow_fraction"] is None


def test_the_twins_floor_is_the_clips_own_snow_flag(tmp_path):
    """The twin's floor follows the clip's ATL08 ``segment_snowcover`` (not fitted): snow on
    more than half of the flagged segments gives a snow floor and the sunlit albedo of the
    class under snow, which the forest's solar background takes (the floor's own ~0.9 would
    count the snow unshaded); snow-free, or no flag, a litter floor with its own albedo."""
    import h5py
    from lidar_mitsuba.studies import forest_twin as ft
    from lidar_mitsuba.studies.realism_forest import floor_albedo
    path = tmp_path / "atl08_clip.h5"
    n = 6
    lat = np.linspace(59.0, 59.01, n)
    with h5py.File(path, "w") as f:
        ls = f.create_group("gt1r/land_segments")
        ls["canopy/h_canopy"] = np.full(n, 8.0, np.float32)
        ls["canopy/segment_cover"] = np.full(n, 60, np.int16)
        ls["dem_h"] = np.linspace(500.0, 501.0, n).astype(np.float32)
        ls["latitude"], ls["longitude"] = lat, np.full(n, -105.0)
        ls["segment_landcover"] = np.full(n, 111, np.int16)
        ls["segment_snowcover"] = np.array([2, 2, 2, 2, 1, 127], np.int8)
        f["gt1r"].attrs["atlas_beam_type"] = b"weak"
    i = ft.site_inputs(path, "gt1r")
    assert i["snow"]["snow_fraction"] == pytest.approx(0.8)
    floor, sunlit, why = ft.floor_of(i)
    assert (floor, sunlit) == ("snow", 0.36) and "Moody" in why
    forest = ft.twin_forest(i, tile_m=64.0)
    assert forest.sunlit_albedo == 0.36 and forest.floor.albedo > 0.8      # snow's optics
    assert floor_albedo({"floor": "snow", "sunlit_albedo": sunlit}) == 0.36
    with h5py.File(path, "a") as f:
        f["gt1r/land_segments/segment_snowcover"][...] = np.array([1, 1, 1, 2, 2, 0], np.int8)
    i = ft.site_inputs(path, "gt1r")
    assert ft.floor_of(i)[:2] == ("litter", None)
    forest = ft.twin_forest(i, tile_m=64.0)
    assert forest.sunlit_albedo is None and "litter" in forest.floor.name
    assert floor_albedo({"floor": "litter", "sunlit_albedo": None}) == forest.floor.albedo
    with h5py.File(path, "a") as f:       # snow, but no land cover: the twin's conifers'
        f["gt1r/land_segments/segment_snowcover"][...] = 2
        del f["gt1r/land_segments/segment_landcover"]
    i = ft.site_inputs(path, "gt1r")
    assert i["landcover"] == [] and ft.floor_of(i)[:2] == ("snow", 0.36)
    assert "no segment_landcover" in ft.floor_of(i)[2]
    with h5py.File(path, "a") as f:
        del f["gt1r/land_segments/segment_snowcover"], f["gt1r/land_segments/dem_h"]
    i = ft.site_inputs(path, "gt1r")
    assert "no segment_snowcover" in ft.floor_of(i)[2] and i["slope"] == 0.0


def test_a_forests_sunlit_albedo_is_the_solar_backgrounds():
    """A forest that gives its sunlit albedo has the solar background of a Lambertian plate of
    that albedo (radiometry.run_radiometry takes it instead of probing the scene's floor)."""
    from types import SimpleNamespace
    from lidar_mitsuba.constants import ParameterError
    from lidar_mitsuba.instrument import Instrument
    from lidar_mitsuba import radiometry
    from lidar_mitsuba.vegetation.forest import forest
    from lidar_mitsuba.ground.surface import Plane
    with pytest.raises(ParameterError, match="sunlit_albedo"):
        forest(ground=Plane(size_m=32.0), height_m=5.0, cover=0.5, lai=2.0, seed=1,
               sunlit_albedo=1.5)
    f = forest(ground=Plane(size_m=32.0), height_m=5.0, cover=0.5, lai=2.0, seed=1,
               sunlit_albedo=0.36)
    assert f.config()["sunlit_albedo"] == 0.36
    assert "sunlit_albedo" not in forest(ground=Plane(size_m=32.0), height_m=5.0, cover=0.5,
                                         lai=2.0, seed=1).config()
    inst = Instrument.atlas("weak")
    n = 4
    geo = SimpleNamespace(solar_elevation_deg=np.full(n, 30.0), solar_azimuth_deg=np.zeros(n),
                          delta_time_s=np.zeros(n))
    got = radiometry.run_radiometry(inst, geo, np.zeros(n), scene=None, x_m=np.zeros(n),
                                    y_m=np.zeros(n), snow=None, albedo=0.36)
    want = radiometry.shot_radiometry(inst, delta_time_s=geo.delta_time_s, z_m=np.zeros(n),
                                      albedo=0.36, solar_elevation_deg=geo.solar_elevation_deg,
                                      solar_azimuth_deg=geo.solar_azimuth_deg)
    assert got.albedo == 0.36 and np.array_equal(got.background_mhz, want.background_mhz)
    assert got.solar_mhz[0] > 0.1                       # a sunlit forest: ~MHz


def test_the_cli_forest_takes_a_snow_floor_and_the_suns_albedo_of_a_snowy_forest():
    """``--forest ...,floor=snow``: the snow's optics on the floor, and for the sun a
    snow-covered forest's published albedo (0.36 evergreen needleleaf for conifers, 0.39
    mixed otherwise) unless ``sunlit_albedo`` is given; a bad floor or albedo names
    ``--forest`` (the CLI's option), a litter floor keeps its own albedo for the sun."""
    from lidar_mitsuba.constants import ParameterError
    from lidar_mitsuba.vegetation.forest import forest_from_spec
    base = "height=8,cover=0.5,lai=2,size=64"
    f = forest_from_spec(f"conifer:{base},floor=snow")
    assert f.floor.albedo > 0.9 and f.sunlit_albedo == 0.36
    assert forest_from_spec(f"broadleaf:{base},floor=snow").sunlit_albedo == 0.39
    assert forest_from_spec(f"conifer:{base},floor=snow,sunlit_albedo=0.5").sunlit_albedo == 0.5
    f = forest_from_spec(f"conifer:{base}")
    assert f.sunlit_albedo is None and "litter" in f.floor.name
    for bad, word in (("floor=ice", "floor"), ("sunlit_albedo=2", "sunlit_albedo"),
                      ("sunlit_albedo=x", "sunlit_albedo")):
        with pytest.raises(ParameterError, match=word) as e:
            forest_from_spec(f"conifer:{base},{bad}")
        assert e.value.name == "forest"
