"""Snow as a tabulated subsurface kernel (issue 27: lidar_mitsuba.ground.snow.kernel, the snowkernel
integrator): the table's statistics against closed forms, the plugin's draws against the table
it was given, and the kernel against the full walk it tabulates, in the regimes where a
tabulation could fail (between angle nodes, steep facets, a thin layer over a bright base, large
grains, rough terrain).

Tolerances: Z = 4.5 standard errors (tests/closed_forms.py). A quantile of n samples has the
standard error sqrt(u (1 - u) / n) / pdf(Q(u)); a fraction, the binomial one. Kernel against
walk: two independent runs, so the standard errors add in quadrature (each run's photon-height
mean from its report, its mean signal per shot from the shots' spread), plus the table's own
Monte Carlo error (half its mean extra path's standard error, heights being half the round
trip, and its weight's relative standard error, each at the worst node the scene can use).
"""
import math

import mitsuba as mi
import numpy as np
import pytest
from scipy import stats

from lidar_mitsuba.ground import snow
from lidar_mitsuba.ground.snow import kernel as snow_kernel
from lidar_mitsuba.constants import C_M_PER_NS, ParameterError
from lidar_mitsuba.run import simulate
from lidar_mitsuba.ground.surface import SurfaceSpec
from lidar_mitsuba_plugins import kernel_table

from closed_forms import Z

ALT = 1000.0


# --------------------------------------------------------------------------- the table
def test_weighted_quantiles_of_known_laws(rng):
    """Equal weights on an exponential sample give its quantiles -ln(1 - u); weights 2x on a
    uniform sample give the law of density 2x, quantiles sqrt(u)."""
    n = 200_000
    u = np.array([0.1, 0.5, 0.9, 0.99])
    x = rng.exponential(size=n)
    q = snow_kernel.weighted_quantile_at(x, np.ones(n), u)
    truth = -np.log1p(-u)
    se = np.sqrt(u * (1 - u) / n) / np.exp(-truth)
    assert np.all(np.abs(q - truth) < Z * se), (q, truth, se)
    y = rng.uniform(size=n)
    q = snow_kernel.weighted_quantile_at(y, 2 * y, u)
    # weighted sample: effective size n_eff = (sum w)^2 / sum w^2 = 3n/4
    se = np.sqrt(u * (1 - u) / (0.75 * n)) / (2 * np.sqrt(u))
    assert np.all(np.abs(q - np.sqrt(u)) < Z * se), (q, np.sqrt(u), se)
    lv = kernel_table.quantile_levels(1024)
    assert lv[0] == 0 and lv[-1] == 1 and np.all(np.diff(lv) > 0)


def _plate(theta_deg: float, vol):
    scene, _ = snow_kernel._tilted_plane(vol, theta_deg)
    return scene


def _kernel_trace(scene, *, weight, extra_path_m, n_shots=64, pps=4096, seed=3):
    integ = mi.load_dict({"type": "snowkernel", "altitude_m": ALT, "footprint_sigma_m": 0.0,
                          "pulse_sigma_ns": 0.0, "fov_radius_m": 1e5})
    integ.set_table(weight=weight, extra_path_m=extra_path_m)
    r = integ.trace(scene, shot_x_m=np.zeros(n_shots), shot_y_m=np.zeros(n_shots),
                    paths_per_shot=pps, seed=seed)
    return r, np.asarray(r.time_ns, np.float64) * C_M_PER_NS - 2 * ALT


def test_plugin_draws_the_table_it_is_given():
    """A table with the exponential law's quantiles (mean 0.3 m) at every node and a weight
    falling linearly with angle: at nadir every photon weighs W(0) and the extra paths follow
    the law (mean and quantiles within sampling error); at 7.5 deg, halfway between two
    nodes, the weight is the average of theirs (exactly) and the delay comes from either node
    half the time (binomial)."""
    vol = snow.snow_from_grains(grain_radius_um=100)
    j = snow_kernel.N_NODES
    weight = 1.2 - 0.01 * kernel_table.node_angles_deg(j)
    u = kernel_table.quantile_levels(1024)
    mean = 0.3
    q = -mean * np.log1p(-np.minimum(u, 1 - 1e-12))
    r, L = _kernel_trace(_plate(0.0, vol), weight=weight, extra_path_m=np.tile(q, (j, 1)))
    assert len(r) == 64 * 4096
    np.testing.assert_allclose(r.weight, 1.2, rtol=1e-6)
    n = L.size
    # float32 legs at 1 km: each extra path is exact to ~1e-4 m, far below the SE below
    assert abs(L.mean() - mean) < Z * mean / math.sqrt(n) + 1e-4, L.mean()
    for uu in (0.5, 0.9, 0.999):
        truth = -mean * math.log1p(-uu)
        se = math.sqrt(uu * (1 - uu) / n) / (math.exp(-truth / mean) / mean)
        assert abs(np.quantile(L, uu) - truth) < Z * se + 1e-3, (uu, np.quantile(L, uu))
    # between nodes 1 and 2: constant delays 0.1 m and 0.2 m there
    steps = np.repeat((0.1 * np.arange(j))[:, None], 1024, axis=1)
    r, L = _kernel_trace(_plate(7.5, vol), weight=weight, extra_path_m=steps)
    np.testing.assert_allclose(r.weight, 1.2 - 0.075, rtol=1e-5)
    near_1 = np.abs(L - 0.1) < 2e-3
    near_2 = np.abs(L - 0.2) < 2e-3
    assert np.all(near_1 | near_2)
    frac = near_2.mean()
    assert abs(frac - 0.5) < Z * math.sqrt(0.25 / L.size), frac


def test_plugin_refuses_a_bad_table():
    integ = mi.load_dict({"type": "snowkernel"})
    with pytest.raises(ValueError, match="do not match"):
        integ.set_table(weight=np.ones(3), extra_path_m=np.zeros((4, 8)))
    with pytest.raises(ValueError, match="non-decreasing"):
        integ.set_table(weight=np.ones(2), extra_path_m=np.array([[0, 1.0], [1.0, 0]]))
    with pytest.raises(ValueError, match="no table"):
        integ.trace(_plate(0.0, snow.snow_from_grains(grain_radius_um=100)),
                    shot_x_m=[0.0], shot_y_m=[0.0], paths_per_shot=8, seed=0)


def test_table_is_cached_and_keyed_by_the_optics(monkeypatch):
    """The second call reads the file the first wrote; other optics, another table."""
    monkeypatch.setattr(snow_kernel, "PHOTONS", 1 << 12)
    vol = snow.snow_from_grains(grain_radius_um=1000, max_events=2000)
    p1, t1 = snow_kernel.table(vol, progress=False)
    p2, t2 = snow_kernel.table(vol, progress=False)
    assert p1 == p2 and p1.is_file()
    np.testing.assert_array_equal(t1["extra_path_m"], t2["extra_path_m"])
    other = snow.snow_from_grains(grain_radius_um=1000, max_events=2000, g=0.75)
    assert snow_kernel.key(other) != snow_kernel.key(vol)
    assert t1["weight"].shape == (snow_kernel.N_NODES,)
    assert t1["extra_path_m"].shape == (snow_kernel.N_NODES, snow_kernel.N_QUANTILES)
    # the table's nadir weight and mean path are the walk's (test_snow checks the walk)
    assert 0 < t1["weight"][0] < 2 and t1["mean_path_m"][0] > 0


def test_plane_warning_follows_the_spread():
    t = {"lateral_rms_m": np.array([0.02, 0.03])}
    assert snow_kernel.plane_warning(t, facet_m=1.0) is None
    assert snow_kernel.plane_warning(t, facet_m=None) is None
    w = snow_kernel.plane_warning(t, facet_m=0.2)
    assert "3 cm sideways" in w and "0.2 m facets" in w


# --------------------------------------------------------------------------- kernel vs walk
#: the kernel's shots per walk shot over flat ground: a kernel run costs a hundredth of the
#: walk's (16 paths a shot against the walk's 1024, no events to follow), and its photon
#: heights had the larger standard error (flat, 100 um, 300 shots each: 1.45 cm against the
#: walk's 1.11), so four times the shots give it half that error and let the walk run 200
#: shots (its cost is the test's): the height tolerance below, Z x sqrt(SE_walk^2 +
#: SE_kernel^2 + SE_table^2), comes out smaller than with 300 shots each (flat, 100 um:
#: 7.0 cm against 8.3 cm). Over a slope or relief the longer track would cross other heights
#: (the KS test compares the heights themselves): there both run the same shots.
KERNEL_SHOTS_PER_WALK_SHOT = 4
FLAT = SurfaceSpec(kind="flat")

CASES = {
    # name: (surface, snow options, the walk's shots, the kernel's shots)
    "flat, 100 um (interior snow)": (FLAT, {"grain_radius_um": 100},
                                     200, 200 * KERNEL_SHOTS_PER_WALK_SHOT),
    "slope 37.5 deg (between nodes)": (SurfaceSpec(kind="slope", slope_deg=37.5),
                                       {"grain_radius_um": 200}, 300, 300),
    "slope 62.5 deg (steep)": (SurfaceSpec(kind="slope", slope_deg=62.5),
                               {"grain_radius_um": 200}, 300, 300),
    "3 cm layer over a bright base": (FLAT, {"grain_radius_um": 200, "depth_m": 0.03,
                                             "base_albedo": 0.8},
                                      200, 200 * KERNEL_SHOTS_PER_WALK_SHOT),
    "1 mm grains": (FLAT, {"grain_radius_um": 1000}, 200, 200 * KERNEL_SHOTS_PER_WALK_SHOT),
    "2 cm wind crust over light snow": (FLAT, {"grain_radius_um": 200, "density_kg_m3": 300,
                                               "crust_m": 0.02, "crust_grain_um": 100,
                                               "crust_density_kg_m3": 450},
                                        200, 200 * KERNEL_SHOTS_PER_WALK_SHOT),
    "rough fractal terrain": (SurfaceSpec(kind="fractal", size_m=64.0, relief_m=3.0),
                              {"grain_radius_um": 200}, 300, 300),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CASES))
def test_kernel_matches_the_walk(case, monkeypatch, tmp_path):
    """The kernel gives the walk's signal photons per shot and photon heights (their mean
    within the Monte Carlo errors, their distribution by a two-sample KS test: every later
    step, ATL06 included, is a function of them), in the regimes where a tabulation could
    fail. The table is built with 2^15 walk
    photons per node here (its error enters the tolerance) to keep the test short.

    Over flat ground every photon enters at nadir and the kernel reads the table's first
    node alone: there the other nodes are walked with the fewest photons a node takes
    (1024; the node at 0 deg keeps its 2^15, the same walk bit for bit), in a folder of the
    test's own, so that such a table never stands in for a full one. The kernel's draws,
    and so every number compared, are those of the full table's (checked once: photon
    heights, signal flags and per-shot signal identical for the 100 um case); the build
    costs ~3.6 s instead of ~19 s CPU a case."""
    import warnings
    monkeypatch.setattr(snow_kernel, "PHOTONS", 1 << 15)
    surface, opts, walk_shots, kernel_shots = CASES[case]
    if surface.kind == "flat":
        walk_node = snow_kernel.build_node

        def nadir_only(vol, theta_deg, *, photons, seed):
            return walk_node(vol, theta_deg, photons=photons if theta_deg == 0 else 1024,
                             seed=seed)
        monkeypatch.setattr(snow_kernel, "build_node", nadir_only)
        monkeypatch.setenv("LIDAR_MITSUBA_CACHE", str(tmp_path))
    vol = snow.snow_from_grains(**opts)
    out, heights = {}, {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for model in ("walk", "kernel"):
            res = simulate(surface=surface, snow=vol, snow_model=model, seed=5,
                           shots={"walk": walk_shots, "kernel": kernel_shots}[model],
                           progress=False)
            assert res.config["snow_model"] == model
            assert res.config["integrator"] == {"walk": "volpathlength",
                                                "kernel": "snowkernel"}[model]
            rep = res.report().overall
            sig = np.asarray(res.detections.mean_photons_per_shot, np.float64)
            out[model] = (rep.bias_m, rep.bias_se_m, sig.mean(), sig.std() / math.sqrt(sig.size))
            heights[model] = np.asarray(res.h_m)[np.asarray(res.detections.is_signal)]
    _, t = snow_kernel.table(vol, progress=False)
    steep_deg = {"flat": 0.0, "slope": surface.slope_deg, "fractal": 90.0}[surface.kind]
    steepest = min(int(np.ceil(steep_deg / kernel_table.THETA_STEP_DEG)),
                   snow_kernel.N_NODES - 1)
    table_se = 0.5 * float(np.max(t["mean_path_se_m"][:steepest + 1]))
    (hw, sw, nw, snw), (hk, sk, nk, snk) = out["walk"], out["kernel"]
    tol_h = Z * math.sqrt(sw ** 2 + sk ** 2 + table_se ** 2)
    assert abs(hk - hw) < tol_h, (case, hw, hk, tol_h)
    rel_w = float(np.max(t["weight_se"][:steepest + 1] / t["weight"][:steepest + 1]))
    tol_n = Z * math.sqrt(snw ** 2 + snk ** 2 + (rel_w * nk) ** 2)
    assert abs(nk - nw) < tol_n, (case, nw, nk, tol_n)
    # and the whole distribution of the signal photons' heights (two-sample Kolmogorov-
    # Smirnov; ATL06's h_li is a function of these photons)
    p = stats.ks_2samp(heights["walk"], heights["kernel"]).pvalue
    assert p > 1e-4, (case, p, heights["walk"].size, heights["kernel"].size)


def test_auto_takes_the_kernel_and_refuses_bad_models(monkeypatch):
    monkeypatch.setattr(snow_kernel, "PHOTONS", 1 << 12)
    vol = snow.snow_from_grains(grain_radius_um=1000, max_events=2000)
    res = simulate(surface=SurfaceSpec(kind="flat"), snow=vol, shots=50, progress=False)
    assert res.config["snow_model"] == "kernel"
    assert res.config["snow_kernel"]["nodes"] == snow_kernel.N_NODES
    assert any("snow model: kernel" in c for c in res.config["choices"])
    for bad, name in ((dict(snow=vol, snow_model="fast"), "snow_model"),
                      (dict(snow_model="kernel"), "snow_model")):
        with pytest.raises(ParameterError) as e:
            simulate(surface=SurfaceSpec(kind="flat"), shots=10, progress=False, **bad)
        assert e.value.name == name


def test_cli_snow_model(tmp_path, capsys):
    """--snow-model walk|kernel run; without --snow-grain-um it is refused (one line, exit 2,
    no file). In process, the runs too (tests/cli_checks.py: a process each cost seconds of
    start-up; tests/test_cli.py starts the command's own process)."""
    from cli_checks import bad_call
    from lidar_mitsuba.cli import main
    exe = ["simulate", "--surface", "flat", "--shots", "50", "--no-progress"]
    for model in ("walk", "kernel"):
        out = tmp_path / f"{model}.h5"
        code = main(exe + ["--snow-grain-um", "1000", "--snow-max-events", "2000",
                           "--snow-model", model, "--out", str(out), "--explain"])
        printed = capsys.readouterr()
        assert code == 0, printed.err
        assert ("snow model: kernel" in printed.out) == (model == "kernel") and out.is_file()
    bad = tmp_path / "bad.h5"
    for args, flag in ((["--snow-model", "kernel"], "--snow-model"),
                       (["--snow-grain-um", "100", "--snow-g", "1.2"], "--snow-g"),
                       (["--snow-grain-um", "100", "--snow-absorption-b", "9"],
                        "--snow-absorption-b"),
                       (["--snow-grain-um", "100", "--snow-backscatter", "1.5"],
                        "--snow-backscatter"),
                       (["--snow-grain-um", "100", "--snow-crust-grain-um", "50"],
                        "--snow-crust-m"),
                       (["--snow-grain-um", "100", "--snow-crust-m", "0.02",
                         "--snow-crust-density", "5"], "--snow-crust-density")):
        err = bad_call(exe + args + ["--out", str(bad)], capsys)
        assert flag in err and not bad.exists(), err
