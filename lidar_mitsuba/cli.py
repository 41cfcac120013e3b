"""Command-line interface ``lidar-mitsuba`` (simulate, stats, segments, terrain, make-dem, bench,
reproduce, sweep). ``simulate --dem`` streams a granule of up to six beams over a GeoTIFF
(:func:`lidar_mitsuba.granule.stream_granule`).

Bad input is reported as one line naming the option, with exit code 2 and no output file.
The options of ``simulate`` and ``terrain`` are generated from the API (:mod:`.cli_options`):
an option per field of :class:`~lidar_mitsuba.instrument.Instrument`,
:class:`~lidar_mitsuba.surface.SurfaceSpec` and :class:`~lidar_mitsuba.track.Track` and per
keyword of :func:`~lidar_mitsuba.simulate.simulate`, with their defaults and descriptions.
"""
from __future__ import annotations

import argparse
import inspect
import json
import os
import pathlib
import sys
import tempfile
import time
import warnings

from . import cli_options as opts
from .constants import ParameterError, SimulationWarning
from .geotrack import Site
from .instrument import DEAD_TIME_PRESETS_NS, INSTRUMENT_PRESETS, Instrument
from .radiometry import Atmosphere, LinkBudget
from .track import Track

PROG = "lidar-mitsuba"
#: simulate() keywords that are CLI options of their own (the rest are composed objects)
RUN_OPTIONS = ("shots", "seed", "paths_per_shot", "max_depth", "variant", "chunk_shots")


class UsageError(Exception):
    """Bad command-line input: ``option`` is the flag to name in the one-line message."""

    def __init__(self, option: str, message: str):
        super().__init__(f"{option}: {message}")


class _Parser(argparse.ArgumentParser):
    def error(self, message):   # one line, exit 2 (argparse would also print the usage)
        if message.startswith("argument "):      # "argument --shots: ..." -> "--shots: ..."
            message = message[len("argument "):]
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


def _out_path(value: str, suffixes: tuple[str, ...], option: str = "--out") -> pathlib.Path:
    """An output file: the right suffix, not a folder, in an existing folder where a file can
    be created (tried, not guessed from permissions: root passes every permission check)."""
    path = pathlib.Path(value)
    if suffixes and path.suffix.lower() not in suffixes:
        raise UsageError(option, f"must end with {' or '.join(suffixes)} (got {value!r})")
    if path.is_dir():
        raise UsageError(option, f"{value!r} is a folder")
    parent = path.parent if str(path.parent) else pathlib.Path(".")
    if not parent.is_dir():
        raise UsageError(option, f"folder {str(parent)!r} does not exist")
    _probe_writable(parent, option)
    return path


def _variant_list(value: str) -> list[str]:
    """argparse type of ``bench --variant``: known, usable variants, comma-separated."""
    from .variant import usable_variants
    names = [v.strip() for v in value.split(",") if v.strip()]
    usable = usable_variants()
    bad = [v for v in names if v not in usable]
    if not names or bad:
        raise argparse.ArgumentTypeError(
            f"{', '.join(bad) or repr(value)} not available here (choose from "
            f"{', '.join(usable)})")
    return names


def _out_dir(value: str, option: str = "--out") -> pathlib.Path:
    """An output folder (created by the command): not an existing file, inside a writable
    existing folder."""
    out = pathlib.Path(value)
    if out.exists() and not out.is_dir():
        raise UsageError(option, f"{value!r} exists and is not a folder")
    parent = out.parent if str(out.parent) else pathlib.Path(".")
    if not parent.is_dir():
        raise UsageError(option, f"folder {str(parent)!r} does not exist")
    _probe_writable(out if out.exists() else parent, option)
    return out


def _probe_writable(folder: pathlib.Path, option: str) -> None:
    """Create and remove a file in ``folder``: tried, not guessed from permissions (root passes
    every permission check, and a read-only file system fails only on writing)."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".lidar-mitsuba.", suffix=".probe", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise UsageError(option, f"cannot write in {str(folder)!r} ({e.strerror})") from None


def _dead_time(value: str) -> float:
    if value in DEAD_TIME_PRESETS_NS:
        return DEAD_TIME_PRESETS_NS[value]
    try:
        return float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"not a number or a preset ({', '.join(DEAD_TIME_PRESETS_NS)}): {value!r}") from None


def _max_depth(value: str):
    """An argparse type: an integer or ``auto`` (``--max-depth``, ``--paths-per-shot``)."""
    if value == "auto":
        return value
    try:
        return int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer or 'auto': {value!r}") from None


def _int_at_least(minimum: int):
    """An argparse type: an integer >= ``minimum``."""
    def parse(value: str) -> int:
        try:
            v = int(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {value!r}") from None
        if v < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum} (got {v})")
        return v
    return parse


_positive_int = _int_at_least(1)
_nonnegative_int = _int_at_least(0)


def _define(value: str) -> tuple[str, str]:
    name, eq, v = value.partition("=")
    if not eq or not name.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE (got {value!r})")
    return name.strip(), v


def _version() -> str:
    from .resources import versions
    v = versions()
    return f"{PROG} {v['lidar_mitsuba']} (mitsuba {v['mitsuba']}, drjit {v['drjit']})"


def build_parser() -> argparse.ArgumentParser:
    from . import terrain
    from .simulate import simulate
    from .surface import SURFACES, SurfaceSpec

    p = _Parser(prog=PROG, description="Physically based simulation of a spaceborne "
                "photon-counting lidar (ICESat-2/ATLAS-like) with Mitsuba 3.")
    p.add_argument("--version", action="version", version=_version())
    sub = p.add_subparsers(dest="command", parser_class=_Parser, metavar="COMMAND")

    s = sub.add_parser("simulate", help="simulate a ground track and write ATL03-like HDF5",
                       description="Simulate laser shots over a surface, detect their photons "
                       "and write an ATL03-like HDF5 file; prints bias and precision.")
    src = s.add_argument_group("scene (a built-in surface or your own Mitsuba XML)")
    src.add_argument("--scene", metavar="FILE.xml",
                     help="Mitsuba XML scene (z up, metres, its own BSDFs); a <integrator "
                     "type=\"pathlength\"> in it sets max_depth, altitude, footprint, pulse "
                     "and field of view")
    src.add_argument("-D", dest="define", action="append", type=_define, metavar="NAME=VALUE",
                     help="set the XML's <default name=\"NAME\"> parameter (repeatable)")
    g = s.add_argument_group("built-in surface (--surface; slope if --slope-deg is given)")
    surface_opts = opts.add_options(g, SurfaceSpec, metavars={"kind": None})
    s.set_defaults(_surface_opts=surface_opts)
    g._group_actions[0].choices = SURFACES
    i = s.add_argument_group("instrument")
    i.add_argument("--instrument", choices=INSTRUMENT_PRESETS, default=None,
                   help="paper (default; atlas with --like): Zhang & Kerekes' instrument, "
                   "signal and background as given; atlas: ATLAS as flown, signal from its "
                   "link budget, background from the sun and the air at each shot (README: "
                   "where each number comes from)")
    s.set_defaults(_instrument_opts=opts.add_options(
        i, Instrument, types_={"dead_time_ns": _dead_time}, skip=("link_budget",)))
    lb = s.add_argument_group("link budget (--instrument atlas)")
    s.set_defaults(_link_opts=opts.add_options(
        lb, LinkBudget, skip=("atmosphere", "solar_background", "laser_backscatter"))
        + opts.add_options(lb, Atmosphere, only=("aerosol_optical_depth",)))
    s.set_defaults(_site_opts=opts.add_options(
        i, Site, only=("lat_deg", "lon_deg", "height_m"),
        metavars={"lat_deg": "DEG", "lon_deg": "DEG"}))
    t = s.add_argument_group("track (default: along +x through the middle of the surface)")
    s.set_defaults(_track_opts=opts.add_options(t, Track, metavars={"start_xy_m": ("X", "Y")}))
    d = s.add_argument_group("real terrain and orbit (--dem: a granule of up to six beams)")
    d.add_argument("--dem", metavar="FILE.tif", help="GeoTIFF DEM in a projected CRS (metres); "
                   "the track streams over it in corridor tiles")
    d.add_argument("--like", metavar="ATL03.h5",
                   help="simulate a real ATL03 granule's twin: its beams, orientation, ground "
                   "tracks, times and sun, over --dem or a built-in surface (flat by default, "
                   "the spacecraft at the real range); --shots caps each beam's pulses")
    d.add_argument("--track", metavar="LAT,LON,AZIMUTH|FILE",
                   help="reference ground track: first shot and azimuth [deg, clockwise from "
                   "north], or a file of lat, lon rows (a polyline)")
    d.add_argument("--beams", default="all", metavar="all|strong|weak|gt1l,...",
                   help="beams to simulate (all)")
    d.add_argument("--sc-orient", type=int, choices=(0, 1), default=0,
                   help="spacecraft orientation: 0 backward (left beams strong), 1 forward")
    d.add_argument("--epoch", default=None, metavar="UTC",
                   help="time of the first shot (ISO 8601 UTC; default 2019-06-01T00:00:00Z "
                   "with --dem, 2019-06-21T16:00:00Z at --lat/--lon otherwise)")
    d.add_argument("--roughness-relief-m", type=float, metavar="M",
                   help="add fractal roughness below the DEM's posting with this relief")
    d.add_argument("--roughness-p", type=float, default=1.8, metavar="P",
                   help="spectral exponent of the roughness (1.8)")
    d.add_argument("--mesh-grid-m", type=float, default=None, metavar="M",
                   help="spacing of a corridor mesh along the track (default: 1 m with "
                        "--roughness-relief-m, else the DEM's own pixels, split to 1 mm of its "
                        "bilinear surface)")
    d.add_argument("--atl06", metavar="FILE.h5", help="also write ATL06 land-ice segments")
    v = s.add_argument_group("snow volume (off by default: the surface's BSDF is the snow)")
    v.add_argument("--snow-grain-um", type=float, metavar="UM",
                   help="trace snow as a scattering volume of this optical grain radius [um] "
                   "under the surface (built-in surfaces and --dem)")
    v.add_argument("--snow-density", type=float, metavar="KG_M3",
                   help="snow density [kg/m^3] (350)")
    v.add_argument("--snow-depth-m", type=float, metavar="M",
                   help="snow layer thickness [m] (inf: semi-infinite)")
    v.add_argument("--snow-base-albedo", type=float, metavar="A",
                   help="Lambertian albedo of the base under a finite layer (0)")
    v.add_argument("--snow-max-events", type=int, metavar="N",
                   help="scatterings traced per photon; later light is lost (default: enough "
                   "for 10 m of path in the snow)")
    v.add_argument("--snow-similarity-g", type=float, metavar="G",
                   help="trace a similar snow with this asymmetry (0 <= G < 0.89) and the same "
                   "sigma_s (1 - g): fewer scatterings, faster, approximate near the surface")
    r = s.add_argument_group("rendering")
    opts.add_options(r, simulate, only=RUN_OPTIONS,
                     types_={"max_depth": _max_depth, "paths_per_shot": _max_depth},
                     metavars={"max_depth": "N|auto", "paths_per_shot": "N|auto",
                               "variant": "NAME"})
    r.add_argument("--full-tile", action="store_true",
                   help="mesh the whole tile instead of the track's corridor (same photons)")
    o = s.add_argument_group("output")
    o.add_argument("--out", required=True, metavar="FILE.h5", help="ATL03-like HDF5 output")
    o.add_argument("--plot", metavar="FILE.png", help="also write the photon cloud (Fig. 10)")
    o.add_argument("--window", type=_positive_int, default=1000, metavar="SHOTS",
                   help="shots per statistics window (1000)")
    o.add_argument("--no-progress", action="store_true", help="no progress bar")
    o.add_argument("--explain", action="store_true",
                   help="print the modelling choices the run made (bounces, mesh, sampling)")

    st = sub.add_parser("stats", help="elevation bias and precision of a simulated file",
                        description="Bias and precision (mean and std of h - z_ref) of the "
                        "signal photons: overall, per window and per channel.")
    st.add_argument("file", metavar="FILE.h5")
    st.add_argument("--window", type=_positive_int, default=1000, metavar="SHOTS",
                    help="shots per window (1000)")
    st.add_argument("--json", action="store_true", help="print JSON instead of a table")

    sg = sub.add_parser("segments", help="ATL06-style surface segments with first-photon-bias "
                        "correction", description="Fit 40 m segments every 20 m (ATL06 land-ice "
                        "style: iterative window, 3-sigma editing, line fit, background, "
                        "first-photon-bias correction) to a simulated ATL03-like file.")
    sg.add_argument("file", metavar="FILE.h5")
    sg.add_argument("--json", action="store_true", help="print a JSON summary instead of a table")
    sg.add_argument("--out", metavar="SEGMENTS.h5",
                    help="write the table as land_ice_segments/h_li, ... (HDF5)")

    b = sub.add_parser("bench", help="throughput benchmarks (charts and bench.json)",
                       description="Benchmarks: detector events/s, integrator vs the ray-cast "
                       "ceiling, end-to-end shots/s, accuracy against time, stability sweeps, "
                       "the cost of each model simplification, and the mitransient peer "
                       "comparison (pip install 'lidar_mitsuba[bench]'). Medians of repeats; "
                       "ratios within one run.")
    b.add_argument("--out", required=True, metavar="DIR", help="folder for bench.json and PNGs")
    b.add_argument("--quick", action="store_true", help="small sizes (what the tests run)")
    b.add_argument("--variant", type=_variant_list, metavar="NAME[,NAME]",
                   help="Mitsuba variant(s) to measure, e.g. llvm_ad_mono,cuda_ad_mono: each "
                   "in its own process, charted side by side (default: the active one)")
    b.add_argument("--throughput-only", action="store_true",
                   help="only the throughput benchmarks (no studies)")

    rp = sub.add_parser("reproduce", help="regenerate the paper's results (Figs. 3-13) and "
                        "compare them with the paper",
                        description="Rerun the paper's results section at its own sample counts "
                        "(200,000 flat-plate shots, 50,000 per slope, 1000 per fractal track) and "
                        "write the 11 figures, report.md and report.json: each figure's quantities, "
                        "our values with Monte Carlo errors, the paper's values or trends, and "
                        "whether they agree.")
    rp.add_argument("--out", required=True, metavar="DIR",
                    help="folder for the PNGs, report.md and report.json (created if missing; its "
                    "parent must exist)")
    rp.add_argument("--quick", action="store_true",
                    help="fewer shots and configurations, same code (what the tests run)")
    rp.add_argument("--workers", type=_positive_int, metavar="N",
                    help="compute the figures as tasks on a Dask LocalCluster of N processes "
                    "(same numbers; default: one after another in this process)")
    rp.add_argument("--profile", metavar="FILE",
                    help="along-track profile to fit p on (Fig. 3): .npy of shape (n, 2) or a "
                    "two-column text file, distance [m] and height [m]")

    va = sub.add_parser("validate", help="compare the simulator with real ATLAS data and "
                        "published validation", description="Simulate the twin of a real "
                        "ATL03 subset (weak beam, night, sea ice; shipped in lidar_mitsuba/data) "
                        "with ATLAS as flown and compare photon rates, background and spread; "
                        "run ATLAS over interior snow and compare ATL06 bias and precision with "
                        "the published ground validation. Writes report.md, report.json and "
                        "figures.")
    va.add_argument("--out", required=True, metavar="DIR",
                    help="folder for report.md, report.json and the PNGs (created if missing)")
    va.add_argument("--quick", action="store_true",
                    help="fewer interior shots (what the tests run)")

    _add_sweep_parser(sub)

    t = sub.add_parser("terrain", help="fractal terrain by Fourier synthesis (.npy or .ply)",
                       description="Synthesise a periodic 1/f^p fractal heightfield (paper eqs. 2-4).")
    opts.add_options(t, terrain.fractal, metavars={"p": "P"})
    t.add_argument("--out", required=True, metavar="FILE.npy",
                   help=".npy (heights [m], shape (N, N)) or .ply (mesh for XML scenes)")
    md = sub.add_parser("make-dem", help="write the synthetic ice-sheet test DEM (GeoTIFF)",
                        description="Write a GeoTIFF DEM like a slice of the Greenland ice "
                        "sheet in EPSG:3413 (for simulate --dem): ~2000 m, 0.5 %% slope, "
                        "kilometre-scale undulations, a 1 km nodata square in its south-west "
                        "corner.")
    md.add_argument("--out", required=True, metavar="FILE.tif", help="GeoTIFF to write")
    md.add_argument("--lat", type=float, default=70.0, help="centre latitude [deg] (70)")
    md.add_argument("--lon", type=float, default=-45.0, help="centre longitude [deg] (-45)")
    md.add_argument("--width-m", type=float, default=12000.0, help="east-west extent (12000)")
    md.add_argument("--length-m", type=float, default=12000.0, help="north-south extent (12000)")
    md.add_argument("--posting-m", type=float, default=20.0, help="pixel size (20)")
    md.add_argument("--seed", type=_nonnegative_int, default=0, help="undulations' seed (0)")
    md.add_argument("--no-hole", action="store_true", help="no nodata square")
    return p


# ------------------------------------------------------------------------------ commands
def _cmd_simulate(a) -> int:
    out = _out_path(a.out, (".h5", ".hdf5"))
    plot = _out_path(a.plot, (".png",), "--plot") if a.plot else None
    dem_only = {"--track": a.track, "--atl06": a.atl06,
                "--roughness-relief-m": a.roughness_relief_m}
    if a.like is not None:
        return _simulate_like(a, out, plot)
    if a.dem is not None:
        return _simulate_dem(a, out, plot)
    for flag, value in dem_only.items():
        if value is not None:
            raise UsageError(flag, "only applies to --dem")
    from . import atl03
    from .retrieval import format_report
    from .simulate import simulate
    from .surface import SurfaceSpec

    surface_given = opts.given(a, a._surface_opts)
    params = dict(a.define or [])
    if a.scene is not None:
        if surface_given:
            raise UsageError(opts.option_name(next(iter(surface_given))),
                             "does not apply to --scene (set it in the XML; -D NAME=VALUE "
                             "sets its <default> parameters)")
    else:
        if params:
            raise UsageError("-D", "only applies to --scene")
        if "kind" not in surface_given and "slope_deg" in surface_given:
            surface_given["kind"] = "slope"
    inst = _instrument(a)
    site_opts = opts.given(a, a._site_opts)
    site = Site(**site_opts, **({} if a.epoch is None else {"epoch_utc": a.epoch}))
    if a.scene is not None and a.snow_grain_um is not None:
        raise UsageError("--snow-grain-um", "does not apply to --scene: put a <medium> inside "
                         "its terrain shape")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SimulationWarning)     # printed below, our way
        res = simulate(instrument=inst, surface=None if a.scene else SurfaceSpec(**surface_given),
                       scene_file=a.scene, params=params or None,
                       track=Track(**opts.given(a, a._track_opts)),
                       progress=not a.no_progress, crop_to_track=not a.full_tile,
                       snow=_snow(a), site=site, **opts.given(a, RUN_OPTIONS))
    inst = res.instrument           # as run (an XML <integrator> may set its geometry)
    for w in res.config["warnings"]:
        sys.stderr.write(f"{PROG} simulate: warning: {w}\n")
    atl03.write(res, out)
    rep = res.report(window_shots=a.window)
    what = a.scene or f"{res.config['surface']['kind']} surface"
    print(format_report(rep, title=f"{inst.beam} beam, {res.n_shots} shots over {what} "
                                   f"({res.timings_s['total_s']:.1f} s)"))
    if not res.detections.is_signal.all():
        print(_rates_line(res.classification()))
    if a.explain:
        print("model:")
        for line in res.config["choices"]:
            print(f"  - {line}")
    print(f"wrote {out}")
    if plot is not None:
        from .plotting import photon_cloud
        d = res.detections
        photon_cloud(along_track_m=res.along_track_m, surface_z_m=res.surface_z_m,
                     z_ref_m=res.z_ref_m, photon_along_m=res.along_track_m[d.shot],
                     photon_h_m=res.h_m, is_signal=d.is_signal, path=plot,
                     title=f"{inst.beam} beam over {what}: bias {100 * rep.overall.bias_m:.1f} cm, "
                           f"precision {100 * rep.overall.std_m:.1f} cm")
        print(f"wrote {plot}")
    return 0


def _instrument(a) -> Instrument:
    """The instrument of ``simulate``'s options: ``--instrument paper`` (the fields as given)
    or ``atlas`` (:meth:`Instrument.atlas`, with the given fields and link-budget options)."""
    given = opts.given(a, a._instrument_opts)
    link = opts.given(a, a._link_opts)
    if (a.instrument or "paper") == "atlas":
        return Instrument.atlas(given.pop("beam", "strong"), **given, **link)
    if link:
        raise UsageError(opts.option_name(next(iter(link))),
                         "only applies with --instrument atlas (a link budget)")
    return Instrument(**given)


def _snow(a):
    """The run's snow volume from the ``--snow-*`` options, or ``None`` (no --snow-grain-um)."""
    from . import snow
    options = (("--snow-density", "density_kg_m3", a.snow_density),
               ("--snow-depth-m", "depth_m", a.snow_depth_m),
               ("--snow-base-albedo", "base_albedo", a.snow_base_albedo),
               ("--snow-max-events", "max_events", a.snow_max_events),
               ("--snow-similarity-g", None, a.snow_similarity_g))
    given = [(flag, key, value) for flag, key, value in options if value is not None]
    if a.snow_grain_um is None:
        if given:
            raise UsageError(given[0][0], "only applies with --snow-grain-um")
        return None
    # options not given keep snow_from_grains' defaults
    vol = snow.snow_from_grains(grain_radius_um=a.snow_grain_um,
                                **{key: value for _, key, value in given if key})
    return vol if a.snow_similarity_g is None else vol.similar(a.snow_similarity_g)


def _read_input(path: str, reader):
    """``reader(path)`` for the FILE argument; a missing or unreadable file is a usage error."""
    if not pathlib.Path(path).is_file():
        raise UsageError("FILE", f"{path!r} not found")
    try:
        return reader(path)
    except (OSError, ValueError, KeyError) as e:
        raise UsageError("FILE", f"cannot read {path!r} ({str(e).splitlines()[0]})") from None


def _cmd_stats(a) -> int:
    from . import atl03
    from .retrieval import elevation_report, format_report
    d = _read_input(a.file, atl03.read)
    sig = d["is_signal"]
    dh = d["h_m"] - d["z_ref_m"][d["shot"]]
    rep = elevation_report(dh_m=dh[sig], shot=d["shot"][sig], channel=d["channel"][sig],
                           n_shots=d["n_shots"], n_channels=d["n_channels"], window_shots=a.window)
    from .classify import classification_rates
    rates = classification_rates(d["signal_conf"], sig)
    if a.json:
        doc = rep.to_dict()
        doc.update(beam=d["beam"], file=str(a.file), classification=rates)
        print(json.dumps(_finite(doc), indent=1))
    else:
        print(format_report(rep, title=f"{a.file} ({d['beam']})"))
        if rates["n_noise"]:
            print(_rates_line(rates))
    return 0


def _rates_line(r: dict) -> str:
    return (f"classifier (signal_conf_ph >= {r['min_conf']}): hit rate {r['hit_rate']:.3f} of "
            f"{r['n_signal']} signal photons, false alarms {r['false_alarm_rate']:.3f} of "
            f"{r['n_noise']} noise photons")


def _finite(obj):
    """JSON-safe copy: NaN and inf become null."""
    import math
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _simulate_dem(a, out, plot) -> int:
    """``simulate --dem``: a granule of up to six beams along a ground track."""
    from . import geotrack, granule
    atl06_out = _out_path(a.atl06, (".h5", ".hdf5"), "--atl06") if a.atl06 else None
    if a.scene is not None:
        raise UsageError("--scene", "give --dem or --scene, not both")
    for name in list(opts.given(a, a._surface_opts)) + list(opts.given(a, a._track_opts)):
        raise UsageError(opts.option_name(name), "does not apply to --dem (the DEM is the "
                         "surface; --track sets the ground track)")
    if a.define:
        raise UsageError("-D", "only applies to --scene")
    if a.track is None:
        raise UsageError("--track", "is required with --dem (LAT,LON,AZIMUTH or a file)")
    inst_opts = opts.given(a, a._instrument_opts)
    run = opts.given(a, RUN_OPTIONS)
    if "beam" in inst_opts:
        raise UsageError("--beam", "does not apply to --dem: use --beams")
    site_opts = opts.given(a, a._site_opts)
    if site_opts:
        raise UsageError(opts.option_name(next(iter(site_opts))), "does not apply to --dem "
                         "(--track places the shots on the Earth)")
    link = opts.given(a, a._link_opts)
    if link and a.instrument != "atlas":
        raise UsageError(opts.option_name(next(iter(link))),
                         "only applies with --instrument atlas (a link budget)")
    inst_opts.update(link)
    surface = _dem_surface(a, run.get("seed", 0))
    track = geotrack.GeoTrack.parse(a.track, **({} if a.epoch is None else
                                               {"epoch_utc": a.epoch}))
    beams = geotrack.select_beams(a.beams, a.sc_orient)
    shots = run.pop("shots", 1000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SimulationWarning)
        summaries = granule.stream_granule(
            surface=surface, track=track, beams=beams, sc_orient=a.sc_orient,
            instrument_options=inst_opts, instrument=a.instrument or "paper",
            progress=not a.no_progress, shots=shots,
            atl03_path=out, atl06_path=atl06_out, snow=_snow(a), **run)
    where = f"{surface.dem.path.name} ({surface.dem.crs.to_string()})"
    print(f"{len(summaries)} beam(s), {shots} shots each ({shots * 0.7e-3:.1f} km), over {where}")
    return _granule_report(a, summaries, out, atl06_out, plot)


def _dem_surface(a, seed: int):
    """``--dem``'s surface, with ``--roughness-*`` and ``--mesh-grid-m``."""
    from . import dem as dems
    dem = dems.DEM.open(a.dem)
    rough = None
    if a.roughness_relief_m is not None:
        rough = dems.roughness(p=a.roughness_p, relief_m=a.roughness_relief_m,
                               posting_m=dem.posting_m, grid_m=a.mesh_grid_m or 1.0, seed=seed)
    return dems.DEMSurface(dem, roughness=rough, mesh_grid_m=a.mesh_grid_m)


def _granule_report(a, summaries, out, atl06_out, plot) -> int:
    """Print a granule's per-beam bias and precision (and ``--explain``); draw ``--plot``."""
    for sm in summaries:
        for w in sm.config["warnings"]:
            sys.stderr.write(f"{PROG} simulate: warning: {sm.beam.name}: {w}\n")
    print(f"  {'beam':5} {'spot':>4} {'type':6} {'signal':>9} {'bias [cm]':>14} "
          f"{'precision [cm]':>14}")
    for sm in summaries:
        print(f"  {sm.beam.name:5} {sm.beam.spot:>4} {sm.beam.strength:6} {sm.photons:>9} "
              f"{100 * sm.bias_m:+7.2f} ± {100 * sm.bias_se_m:4.2f} {100 * sm.std_m:>14.2f}")
    if a.explain:
        print("model (first section of the first beam):")
        for line in summaries[0].config["choices"]:
            print(f"  - {line}")
    print(f"wrote {out}")
    if atl06_out is not None:
        print(f"wrote {atl06_out}")
    if plot is not None:
        from .plotting import granule_clouds
        granule_clouds(out, plot)
        print(f"wrote {plot}")
    return 0


def _simulate_like(a, out, plot) -> int:
    """``simulate --like REAL.h5``: the twin of a real granule over ``--dem`` or a built-in
    surface (:mod:`lidar_mitsuba.twin`)."""
    from . import granule, twin
    from .surface import SurfaceSpec
    atl06_out = _out_path(a.atl06, (".h5", ".hdf5"), "--atl06") if a.atl06 else None
    for flag, value in (("--track", a.track), ("--scene", a.scene), ("--epoch", a.epoch),
                        ("-D", a.define)):
        if value:
            raise UsageError(flag, "does not apply to --like (the real granule sets the "
                             "shots, their times and places)")
    for name in list(opts.given(a, a._track_opts)) + list(opts.given(a, a._site_opts)):
        raise UsageError(opts.option_name(name), "does not apply to --like")
    if a.sc_orient != 0:
        raise UsageError("--sc-orient", "does not apply to --like (the file's orientation)")
    inst_opts = opts.given(a, a._instrument_opts)
    if "beam" in inst_opts:
        raise UsageError("--beam", "does not apply to --like: use --beams")
    preset = a.instrument or "atlas"
    link = opts.given(a, a._link_opts)
    if link and preset != "atlas":
        raise UsageError(opts.option_name(next(iter(link))),
                         "only applies with --instrument atlas (a link budget)")
    inst_opts.update(link)
    run = opts.given(a, RUN_OPTIONS)
    shots = run.pop("shots", None)
    real = twin.read(a.like)
    beams = real.select_beams(a.beams)
    # the spacecraft at the real range to the surface (a DEM: at the real altitude above it)
    inst_opts.setdefault("altitude_m", real.median_range_m() if a.dem is None
                         else real.median_altitude_m())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SimulationWarning)
        if a.dem is not None:
            summaries = granule.stream_granule(
                surface=_dem_surface(a, run.get("seed", 0)), track=real, beams=beams,
                sc_orient=real.sc_orient, instrument_options=inst_opts, instrument=preset,
                progress=not a.no_progress, shots=shots, atl03_path=out,
                atl06_path=atl06_out, snow=_snow(a), **run)
        else:
            surface_given = opts.given(a, a._surface_opts)
            if "kind" not in surface_given and "slope_deg" in surface_given:
                surface_given["kind"] = "slope"
            surface_given.setdefault("kind", "flat")
            g = twin.simulate_over_surface(
                real, surface=SurfaceSpec(**surface_given), beams=",".join(b.name for b in beams),
                shots=shots, instrument=preset, instrument_options=inst_opts,
                progress=not a.no_progress, snow=_snow(a), **run)
            granule.write_atl03(g, out)
            if atl06_out is not None:
                granule.write_atl06(g, atl06_out)
            summaries = []
            for r in g.beams:
                sm = granule.BeamSummary(beam=r.beam)
                sm.add(r.result)
                summaries.append(sm)
    n = {b.beam.name: b.n_shots for b in real.beams}
    print(f"the twin of {real.path.name}: {len(summaries)} beam(s) "
          f"({', '.join(f'{sm.beam.name} {sm.shots} shots' for sm in summaries)} of "
          f"{', '.join(f'{k} {v}' for k, v in n.items())}), {preset} instrument, over "
          + (a.dem if a.dem else f"a {surface_given['kind']} surface"))
    return _granule_report(a, summaries, out, atl06_out, plot)


def _cmd_segments(a) -> int:
    out = _out_path(a.out, (".h5", ".hdf5")) if a.out else None
    from . import atl06
    table = _read_input(a.file, atl06.segments_from_atl03)
    summary = atl06.summarize(table)
    if out is not None:
        atl06.write(table, out)
    if a.json:
        print(json.dumps(_finite(summary), indent=1))
    else:
        def cm(key, sign="+"):
            v = summary.get(key)
            return "n/a" if v is None else f"{100 * v:{sign}.2f} cm"
        print(f"{a.file}: {summary['n_segments']} segments, {summary['n_good']} good, "
              f"{summary['n_flagged']} flagged")
        print(f"  h_li - h_ref    mean {cm('h_li_minus_ref_mean_m')} "
              f"(± {cm('h_li_minus_ref_se_m', '')}), std {cm('h_li_minus_ref_std_m', '')}")
        print(f"  uncorrected     mean {cm('h_mean_minus_ref_mean_m')}")
        print(f"  mean first-photon-bias correction {cm('mean_fpb_corr_m')}, "
              f"mean h_li_sigma {cm('mean_h_li_sigma', '')}")
        bg = summary.get("mean_bckgrd")
        if bg is not None:
            print(f"  background estimate {bg:.3f} MHz")
    if out is not None:   # stdout stays pure JSON with --json
        print(f"wrote {out}", file=sys.stderr if a.json else sys.stdout)
    return 0


def _cmd_bench(a) -> int:
    out = _out_dir(a.out)
    from .studies import bench
    doc = bench.run(out_dir=out, quick=a.quick, variants=a.variant,
                    throughput_only=a.throughput_only)
    print(bench.format_summary(doc))
    print(f"wrote {out / 'bench.json'} and the charts {', '.join(doc['charts'])} in {out}")
    return 0


def _cmd_make_dem(a) -> int:
    out = _out_path(a.out, (".tif", ".tiff"))
    from .dem import synthetic_ice_sheet
    if not (abs(a.lat) < 85 and -180 <= a.lon <= 360):
        raise UsageError("--lat" if abs(a.lat) >= 85 else "--lon", "out of range")
    for flag, v, lo, hi in (("--width-m", a.width_m, 200, 2e6), ("--length-m", a.length_m, 200, 2e6),
                            ("--posting-m", a.posting_m, 0.5, 1000)):
        if not lo <= v <= hi:
            raise UsageError(flag, f"must be in [{lo:g}, {hi:g}] (got {v:g})")
    if a.width_m / a.posting_m * a.length_m / a.posting_m > 1e8:
        raise UsageError("--posting-m", "more than 1e8 pixels: use a coarser posting")
    import tempfile
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:    # no partial file on failure
        t = pathlib.Path(tmp) / out.name
        synthetic_ice_sheet(t, lat_deg=a.lat, lon_deg=a.lon, width_m=a.width_m,
                            length_m=a.length_m, posting_m=a.posting_m, seed=a.seed,
                            hole=not a.no_hole)
        os.replace(t, out)
    print(f"wrote {out}")
    return 0


def _cmd_terrain(a) -> int:
    out = _out_path(a.out, (".npy", ".ply"))
    import numpy as np

    from . import terrain
    from .surface import export_ply, heightfield_to_trimesh
    kw = inspect.signature(terrain.fractal).bind(
        **opts.given(a, ("p", "size_m", "grid_m", "relief_m", "seed")))
    kw.apply_defaults()
    hf = terrain.fractal(**kw.arguments)
    tmp = out.with_name(f".{out.name}.tmp{out.suffix}")
    try:
        if out.suffix.lower() == ".npy":
            with open(tmp, "wb") as fh:
                np.save(fh, hf.z_m)
        else:
            export_ply(heightfield_to_trimesh(hf), tmp)
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()
    print(f"wrote {out} ({hf.z_m.shape[0]}x{hf.z_m.shape[1]} grid, {hf.grid_m} m, "
          f"relief {hf.relief_m:.3f} m, p {kw.arguments['p']:g}, seed {kw.arguments['seed']})")
    return 0


def _cmd_validate(a) -> int:
    out = _out_dir(a.out)
    from .studies import validate
    doc = validate.run(out, quick=a.quick)
    print(validate.format_summary(doc))
    print(f"wrote {out / 'report.md'}, {out / 'report.json'} and {len(validate.PNG)} figures")
    return 0


def _cmd_reproduce(a) -> int:
    started = time.perf_counter()
    out = _out_dir(a.out)
    from .studies import reproduce
    profile = None
    if a.profile is not None:
        try:
            profile = reproduce.load_profile(a.profile)
        except ValueError as e:
            raise UsageError("--profile", str(e)) from None
    doc = reproduce.run(out, quick=a.quick, profile=profile,
                        profile_name=pathlib.Path(a.profile).name if a.profile else None,
                        log=lambda msg: print(msg, flush=True), started=started,
                        workers=a.workers)
    print(reproduce.format_summary(doc))
    print(f"wrote {out / 'report.md'}, {out / 'report.json'} and {len(reproduce.PNG)} figures")
    return 0


def _add_sweep_parser(sub) -> None:
    sw = sub.add_parser("sweep", help="parameter sweeps on Dask: a table of bias, precision, "
                        "... per task, resumable", description="Run a grid (or list) of "
                        "parameters and replicates as independent tasks on Dask (a LocalCluster "
                        "here, or any running scheduler), one row of statistics per task, "
                        "appended to DIR as tasks finish; rerunning resumes. The spec format is "
                        "in the README and in `lidar_mitsuba.sweep`.")
    sw.add_argument("spec", metavar="SPEC.toml", help="the sweep: [sweep], [fixed], [grid], "
                    "[[list]]")
    sw.add_argument("--out", required=True, metavar="DIR", help="folder for rows/, "
                    "results.parquet (or .csv) and charts (created if missing; reusing it "
                    "skips the tasks already done)")
    sw.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler, e.g. "
                    "tcp://host:8786 (default: a LocalCluster on this machine)")
    sw.add_argument("--workers", type=_nonnegative_int, metavar="N", help="worker processes "
                    "of the LocalCluster (default: the cores; 0: no Dask, tasks run here one "
                    "after another)")
    sw.add_argument("--threads", type=_positive_int, metavar="N", help="Dr.Jit and numba "
                    "threads per task (default: cores / workers on the LocalCluster, the "
                    "workers' own setting with --scheduler)")
    sw.add_argument("--plot", action="append", metavar="PARAM", help="draw bias and precision "
                    "against the swept parameter PARAM to DIR/sweep_PARAM.png (repeatable)")
    sw.add_argument("--retry-failed", action="store_true", help="run the tasks recorded as "
                    "failed again")
    sw.add_argument("--no-progress", action="store_true", help="no progress bar")


def _cmd_sweep(a) -> int:
    """Checks everything (spec, options, scheduler) before anything is written."""
    from . import sweep
    from .sweep import plot as sweep_plot
    if not pathlib.Path(a.spec).is_file():
        raise UsageError("SPEC", f"{a.spec!r} not found")

    def named(e):        # "SPEC.toml: [grid] p: ..." (the file alone for file-wide errors)
        whole = e.key in ("spec", str(pathlib.Path(a.spec)))
        return UsageError(a.spec if whole else f"{a.spec}: {e.key}", e.message)
    try:
        spec = sweep.load_spec(a.spec)
    except sweep.SpecError as e:
        raise named(e) from None
    out = _out_dir(a.out)
    if a.scheduler is not None and a.workers is not None:
        raise UsageError("--workers", "does not apply to --scheduler (its workers are started "
                         "there)")
    for param in a.plot or []:
        if param not in spec.swept:
            raise UsageError("--plot", f"{param!r} is not a swept parameter of {a.spec} "
                             f"(swept: {', '.join(spec.swept) or 'none'})")
    client = None
    if a.scheduler is not None:
        from dask.distributed import Client
        try:
            client = Client(a.scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as e:
            raise UsageError("--scheduler", f"cannot connect to {a.scheduler!r} ({e})") from None
        print(f"connected to {a.scheduler}: {len(client.scheduler_info()['workers'])} workers")
    try:
        df = sweep.run(spec, client, out=out, workers=a.workers, threads=a.threads,
                       retry_failed=a.retry_failed, progress=not a.no_progress,
                       log=lambda msg: print(msg, flush=True))
    except sweep.SpecError as e:
        raise named(e) from None
    except KeyboardInterrupt:
        sys.stderr.write(f"{PROG} sweep: the finished tasks are in {out / 'rows'}; run the same "
                         "command again to resume\n")
        raise
    finally:
        if client is not None:
            client.close()
    n, failed = df.attrs["tasks"], df[df["status"] == "failed"]
    print(f"{spec.name}: {n} tasks, {df.attrs['ran']} run now, {df.attrs['skipped']} already "
          f"done, {len(failed)} failed; wrote {df.attrs['results']}")
    for _, row in failed.head(5).iterrows():
        what = ", ".join(f"{k} = {row[k]}" for k in spec.swept) or f"task {row['task_index']}"
        sys.stderr.write(f"{PROG} sweep: warning: task {row['task_id']} ({what}, replicate "
                         f"{row['replicate']}) failed: {row['error']}\n")
    if len(failed) > 5:
        sys.stderr.write(f"{PROG} sweep: warning: {len(failed) - 5} more failed tasks (status "
                         "'failed' in the table)\n")
    for param in a.plot or []:
        path = out / f"sweep_{param}.png"
        sweep_plot.plot(df, param, path=path, title=f"{spec.name}: {n} tasks")
        print(f"wrote {path}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:             # no command: say what there is
        parser.print_help()
        return 0
    prog = f"{PROG} {args.command}"
    try:
        try:
            return {"simulate": _cmd_simulate, "stats": _cmd_stats, "segments": _cmd_segments,
                    "bench": _cmd_bench, "terrain": _cmd_terrain, "make-dem": _cmd_make_dem,
                    "reproduce": _cmd_reproduce, "sweep": _cmd_sweep,
                    "validate": _cmd_validate}[args.command](args)
        except ParameterError as e:
            raise UsageError(opts.option_name(e.name), e.message) from None
    except UsageError as e:
        sys.stderr.write(f"{prog}: error: {e}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write(f"{prog}: interrupted\n")
        return 130


if __name__ == "__main__":
    sys.exit(main())
