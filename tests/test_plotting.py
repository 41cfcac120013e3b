"""The photon-cloud figure (lidar_mitsuba.plotting.photon_cloud, the paper's Fig. 10): what it
plots is the data it was given (exact comparisons)."""
import numpy as np
from matplotlib.figure import Figure

from lidar_mitsuba.plotting import photon_cloud, plt


def cloud(rng, n_shots=50, n=400):
    along = 0.7 * np.arange(n_shots)
    surface = np.sin(along / 5)
    shot = np.sort(rng.integers(0, n_shots, n))
    sig = rng.random(n) < 0.7
    h = np.where(sig, surface[shot] + 0.1 * rng.standard_normal(n), rng.uniform(-15, 15, n))
    return dict(along_track_m=along, surface_z_m=surface, z_ref_m=surface - 0.05,
                photon_along_m=along[shot], photon_h_m=h, is_signal=sig)


def lines(fig):
    (ax,) = fig.axes
    return ax, {ln.get_label().split(" (")[0]: ln for ln in ax.get_lines()}


def test_photon_cloud_plots_noise_signal_surface_and_reference(rng, tmp_path):
    d = cloud(rng)
    fig = photon_cloud(**d, title="t", path=tmp_path / "c.png")
    assert isinstance(fig, Figure) and (tmp_path / "c.png").stat().st_size > 10_000
    ax, ln = lines(fig)
    sig = d["is_signal"]
    assert set(ln) == {"noise photons", "signal photons", "surface along track",
                       "reference elevation"}
    assert ln["noise photons"].get_label() == f"noise photons ({(~sig).sum()})"
    assert ln["signal photons"].get_label() == f"signal photons ({sig.sum()})"
    for name, keep in (("noise photons", ~sig), ("signal photons", sig)):
        np.testing.assert_array_equal(ln[name].get_xdata(), d["photon_along_m"][keep])
        np.testing.assert_array_equal(ln[name].get_ydata(), d["photon_h_m"][keep])
    np.testing.assert_array_equal(ln["surface along track"].get_ydata(), d["surface_z_m"])
    np.testing.assert_array_equal(ln["reference elevation"].get_ydata(), d["z_ref_m"])
    np.testing.assert_array_equal(ln["reference elevation"].get_xdata(), d["along_track_m"])
    assert ax.get_xlabel() == "along-track distance [m]" and ax.get_ylabel() == "elevation [m]"
    assert ax.get_title() == "t"


def test_photon_cloud_thins_large_clouds_but_counts_every_photon(rng):
    """Over ``max_points`` photons a fixed random subset is drawn (photons of the data, in
    their order); the legend still counts them all. Without truth every photon is signal."""
    d = cloud(rng, n=1000)
    fig = photon_cloud(**d, max_points=300)
    plt.close(fig)                                    # no path: left open for the caller
    _, ln = lines(fig)
    sig = d["is_signal"]
    xs = np.concatenate([ln["noise photons"].get_xdata(), ln["signal photons"].get_xdata()])
    assert xs.size == 300
    assert ln["signal photons"].get_label() == f"signal photons ({sig.sum()})"
    pairs = set(zip(d["photon_along_m"][sig], d["photon_h_m"][sig]))
    assert set(zip(ln["signal photons"].get_xdata(), ln["signal photons"].get_ydata())) <= pairs
    assert np.all(np.diff(ln["signal photons"].get_xdata()) >= 0)      # kept in order
    fig = photon_cloud(**d, max_points=300)
    plt.close(fig)
    again = lines(fig)[1]
    np.testing.assert_array_equal(again["signal photons"].get_ydata(),
                                  ln["signal photons"].get_ydata())  # the same subset
    d.pop("is_signal")
    fig = photon_cloud(**d)
    plt.close(fig)
    _, ln = lines(fig)
    assert "noise photons" not in ln and ln["signal photons"].get_xdata().size == 1000
