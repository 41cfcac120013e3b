"""``lidar-mitsuba simulate``: its options (generated from the API where they are fields or
keywords of it, :mod:`.options`) and its three runs: a built-in surface or an XML scene
(:func:`~lidar_mitsuba.run.simulate`, one beam), a DEM granule of up to six beams
(:func:`~lidar_mitsuba.granule.stream_granule`) and a real granule's twin
(:mod:`~lidar_mitsuba.twin`, ``--like``)."""
from __future__ import annotations

import sys
import warnings

from . import options as opts
from .args import (PROG, RUN_OPTIONS, UsageError, dead_time, define, max_depth_or_auto, out_path,
                   positive_int, rates_line)
from ..constants import SimulationWarning
from ..geotrack import Site
from ..instrument import INSTRUMENT_PRESETS, Instrument
from ..radiometry import Atmosphere, LinkBudget
from ..track import Track


def add_parser(sub) -> None:
    """The ``simulate`` subcommand and its option groups."""
    s = sub.add_parser("simulate", help="simulate a ground track and write ATL03-like HDF5",
                       description="Simulate laser shots over a surface, detect their photons "
                       "and write an ATL03-like HDF5 file; prints bias and precision.")
    _add_scene_options(s)
    _add_instrument_options(s)
    _add_track_and_orbit_options(s)
    _add_snow_options(s)
    _add_cloud_options(s)
    _add_run_and_output_options(s)


def _add_scene_options(s) -> None:
    """A built-in surface (generated from ``SurfaceSpec``) or a Mitsuba XML scene."""
    from ..ground.surface import SURFACES, SurfaceSpec
    src = s.add_argument_group("scene (a built-in surface or your own Mitsuba XML)")
    src.add_argument("--scene", metavar="FILE.xml",
                     help="Mitsuba XML scene (z up, metres, its own BSDFs); a <integrator "
                     "type=\"pathlength\"> in it sets max_depth, altitude, footprint, pulse "
                     "and field of view")
    src.add_argument("-D", dest="define", action="append", type=define, metavar="NAME=VALUE",
                     help="set the XML's <default name=\"NAME\"> parameter (repeatable)")
    src.add_argument("--forest", metavar="SPECIES[:KEY=VALUE,...]",
                     help="a forest stand (conifer, broadleaf or shrub) over the built-in "
                     "surface (flat SIZE m without --surface) or --dem (a periodic SIZE m "
                     "square, 2048 by default), its leaves explicit, e.g. "
                     "conifer:height=18,cover=0.6,lai=4; keys: height, cover or stems (per "
                     "ha), lai, leaf_angle, clumping, crown_ratio, crown_radius, crown_shape, "
                     "leaf_width, size, seed, representation (explicit, turbid, gap), "
                     "floor (litter, soil, snow), sunlit_albedo (the sun's albedo of the "
                     "forest; with floor=snow by default a snow-covered forest's, Moody et "
                     "al. 2007) (docs/guide/forests.md)")
    g = s.add_argument_group("built-in surface (--surface; slope if --slope-deg is given)")
    surface_opts = opts.add_options(g, SurfaceSpec, metavars={"kind": None})
    s.set_defaults(_surface_opts=surface_opts)
    g._group_actions[0].choices = SURFACES


def _add_instrument_options(s) -> None:
    """``--instrument``, one option per ``Instrument`` field, the link budget's, and where the
    scene lies (``Site``)."""
    i = s.add_argument_group("instrument")
    i.add_argument("--instrument", choices=INSTRUMENT_PRESETS, default=None,
                   help="paper (default; atlas with --like): Zhang & Kerekes' instrument, "
                   "signal and background as given; atlas: ATLAS as flown, signal from its "
                   "link budget, background from the sun and the air at each shot "
                   "(docs/guide/atlas.md: where each number comes from)")
    s.set_defaults(_instrument_opts=opts.add_options(
        i, Instrument, types_={"dead_time_ns": dead_time}, skip=("link_budget",)))
    lb = s.add_argument_group("link budget (--instrument atlas)")
    s.set_defaults(_link_opts=opts.add_options(
        lb, LinkBudget, skip=("atmosphere", "solar_background", "laser_backscatter"))
        + opts.add_options(lb, Atmosphere, only=("aerosol_optical_depth",)))
    s.set_defaults(_site_opts=opts.add_options(
        i, Site, only=("lat_deg", "lon_deg", "height_m"),
        metavars={"lat_deg": "DEG", "lon_deg": "DEG"}))


def _add_track_and_orbit_options(s) -> None:
    """A straight track over the scene (``Track``), or a DEM, an orbit and beams, or a real
    granule's twin."""
    t = s.add_argument_group("track (default: along +x through the middle of the surface)")
    s.set_defaults(_track_opts=opts.add_options(t, Track, metavars={"start_xy_m": ("X", "Y")}))
    d = s.add_argument_group("real terrain and orbit (--dem: a granule of up to six beams)")
    d.add_argument("--dem", metavar="FILE.tif", help="GeoTIFF DEM in a projected CRS (metres); "
                   "the track streams over it in corridor tiles")
    d.add_argument("--like", metavar="REAL.h5",
                   help="simulate a real granule's twin (ATL03, ATL06, ATL07 or ATL08, any "
                   "release): its beams, strong or weak, ground tracks, times, sun and pulse "
                   "energy, over --dem or a built-in surface (flat by default, the spacecraft "
                   "at the real range); --shots caps each beam's pulses; says what the file "
                   "lacks in one line")
    d.add_argument("--water-wind-mps", type=float, metavar="M_S",
                   help="open water (ocean, leads) instead of the Ward snow: the water BSDF "
                   "roughened by this wind speed [m/s] (Cox & Munk) on the built-in surface")
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
    d.add_argument("--atl08", metavar="FILE.h5",
                   help="also write our ATL08 land and canopy segments (with --forest: by "
                   "default, beside --out as NAME_ATL08.h5)")


#: the ``--snow-*`` options after ``--snow-grain-um``: (flag, type, metavar, the keyword of
#: ``snow.snow_from_grains`` it sets (None: handled apart), help)
SNOW_OPTIONS = (
    ("--snow-density", float, "KG_M3", "density_kg_m3", "snow density [kg/m^3] (350)"),
    ("--snow-depth-m", float, "M", "depth_m", "snow layer thickness [m] (inf: semi-infinite)"),
    ("--snow-base-albedo", float, "A", "base_albedo",
     "Lambertian albedo of the base under a finite layer (0)"),
    ("--snow-max-events", int, "N", "max_events", "scatterings traced per photon; later light "
     "is lost (default: enough for 10 m of path in the snow)"),
    ("--snow-similarity-g", float, "G", None, "trace a similar snow with this asymmetry (0 <= "
     "G < the snow's g) and the same sigma_s (1 - g): fewer scatterings, faster, approximate "
     "near the surface"),
    ("--snow-g", float, "G", "g",
     "Henyey-Greenstein asymmetry of the grains (0.80, natural snow; 0.89: spheres)"),
    ("--snow-absorption-b", float, "B", "absorption_enhancement_b",
     "absorption enhancement B (1.6, natural snow, Libois et al. 2014; 1.25: spheres)"),
    ("--snow-ice-absorption", float, "PER_M", "ice_absorption_per_m",
     "ice's absorption coefficient at 532 nm [1/m] (0.04)"),
    ("--snow-backscatter", float, "FRACTION", "backscatter_fraction", "a backscattering lobe: "
     "this fraction of the phase function is HG with g = -0.5 (two-term HG; 0)"),
    ("--snow-crust-m", float, "M", "crust_m",
     "a denser surface layer (wind crust) this thick [m] (0: none)"),
    ("--snow-crust-grain-um", float, "UM", "crust_grain_um",
     "the crust's optical grain radius [um] (default: the pack's)"),
    ("--snow-crust-density", float, "KG_M3", "crust_density_kg_m3",
     "the crust's density [kg/m^3] (default: the pack's)"),
)


def _add_snow_options(s) -> None:
    """Snow as a scattering volume under the surface."""
    v = s.add_argument_group("snow volume (off by default: the surface's BSDF is the snow)")
    v.add_argument("--snow-grain-um", type=float, metavar="UM",
                   help="trace snow as a scattering volume of this optical grain radius [um] "
                   "under the surface (built-in surfaces and --dem)")
    for flag, type_, metavar, _, help_ in SNOW_OPTIONS:
        v.add_argument(flag, type=type_, metavar=metavar, help=help_)
    v.add_argument("--snow-model", choices=("auto", "walk", "kernel"), default=None,
                   help="kernel: the walk tabulated once per snowpack against incidence angle "
                   "(cached on disk), at the cost of a surface hit; walk: the full random walk "
                   "under every photon (the reference); auto (default): the kernel")


def _add_cloud_options(s) -> None:
    """A cloud layer over the track (``lidar_mitsuba.atmosphere.cloud_layer.Cloud``)."""
    c = s.add_argument_group("cloud (off by default: clear sky; docs/guide/clouds.md)")
    c.add_argument("--cloud-od", type=float, metavar="TAU",
                   help="a cloud of this optical depth at 532 nm over the whole track")
    c.add_argument("--cloud-base-m", type=float, metavar="M",
                   help="the cloud's base above the surface [m] (1000)")
    c.add_argument("--cloud-top-m", type=float, metavar="M",
                   help="the cloud's top above the surface [m] (base + 500)")
    c.add_argument("--cloud-phase", choices=("water", "ice"), default=None,
                   help="water (default: g 0.85, lidar ratio 18.8 sr) or ice (g 0.75, 25 sr)")
    c.add_argument("--cloud-g", type=float, metavar="G",
                   help="Henyey-Greenstein asymmetry instead of the phase's")


def _cloud(a):
    """The run's cloud from the ``--cloud-*`` options, or ``None`` (no --cloud-od)."""
    from dataclasses import replace
    from ..atmosphere.cloud_layer import Cloud
    given = [(f, v) for f, v in (("--cloud-base-m", a.cloud_base_m),
                                 ("--cloud-top-m", a.cloud_top_m),
                                 ("--cloud-phase", a.cloud_phase), ("--cloud-g", a.cloud_g))
             if v is not None]
    if a.cloud_od is None:
        if given:
            raise UsageError(given[0][0], "only applies with --cloud-od")
        return None
    base = 1000.0 if a.cloud_base_m is None else a.cloud_base_m
    top = base + 500.0 if a.cloud_top_m is None else a.cloud_top_m
    make = Cloud.ice if a.cloud_phase == "ice" else Cloud.water
    cloud = make(a.cloud_od, base, top)
    return cloud if a.cloud_g is None else replace(cloud, g=a.cloud_g)


def _add_run_and_output_options(s) -> None:
    """How to trace (``simulate()``'s run keywords) and what to write."""
    from ..run import simulate
    r = s.add_argument_group("rendering")
    opts.add_options(r, simulate, only=RUN_OPTIONS,
                     types_={"max_depth": max_depth_or_auto, "paths_per_shot": max_depth_or_auto},
                     metavars={"max_depth": "N|auto", "paths_per_shot": "N|auto",
                               "variant": "NAME"})
    r.add_argument("--full-tile", action="store_true",
                   help="mesh the whole tile instead of the track's corridor (same photons)")
    o = s.add_argument_group("output")
    o.add_argument("--out", required=True, metavar="FILE.h5", help="ATL03-like HDF5 output")
    o.add_argument("--plot", metavar="FILE.png", help="also write the photon cloud (Fig. 10)")
    o.add_argument("--window", type=positive_int, default=1000, metavar="SHOTS",
                   help="shots per statistics window (1000)")
    o.add_argument("--no-progress", action="store_true", help="no progress bar")
    o.add_argument("--explain", action="store_true",
                   help="print the modelling choices the run made (bounces, mesh, sampling)")


def run(a) -> int:
    """``lidar-mitsuba simulate``."""
    out = out_path(a.out, (".h5", ".hdf5"))
    plot = out_path(a.plot, (".png",), "--plot") if a.plot else None
    dem_only = {"--track": a.track, "--atl06": a.atl06, "--atl08": a.atl08,
                "--roughness-relief-m": a.roughness_relief_m}
    if a.dem is not None and a.water_wind_mps is not None:
        raise UsageError("--water-wind-mps", "does not apply to --dem")
    _forest_only_on_built_in(a)
    if a.like is not None:
        return _simulate_like(a, out, plot)
    if a.dem is not None:
        return _simulate_dem(a, out, plot)
    for flag, value in dem_only.items():
        if value is not None:
            raise UsageError(flag, "only applies to --dem")
    from ..products import atl03
    from ..products.retrieval import format_report
    from ..run import simulate

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
    water = _water_bsdf(a)
    surface = _forest(a, surface_given, water)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SimulationWarning)     # printed below, our way
        res = simulate(instrument=inst, surface=surface,
                       bsdf=water,
                       scene_file=a.scene, params=params or None,
                       track=Track(**opts.given(a, a._track_opts)),
                       progress=not a.no_progress, crop_to_track=not a.full_tile,
                       snow=_snow(a), snow_model=_snow_model(a), site=site,
                       **_cloud_kw(a), **opts.given(a, RUN_OPTIONS))
    inst = res.instrument           # as run (an XML <integrator> may set its geometry)
    for w in res.config["warnings"]:
        sys.stderr.write(f"{PROG} simulate: warning: {w}\n")
    atl03.write(res, out)
    rep = res.report(window_shots=a.window)
    what = a.scene or f"{res.config['surface']['kind']} surface"
    print(format_report(rep, title=f"{inst.beam} beam, {res.n_shots} shots over {what} "
                                   f"({res.timings_s['total_s']:.1f} s)"))
    if not res.detections.is_signal.all():
        print(rates_line(res.classification()))
    if a.explain:
        print("plan:")
        for line in res.config["plan"]:
            print(f"  - {line}")
        print("model:")
        for line in res.config["choices"]:
            print(f"  - {line}")
    print(f"wrote {out}")
    if plot is not None:
        from ..plotting import photon_cloud
        d = res.detections
        photon_cloud(along_track_m=res.along_track_m, surface_z_m=res.surface_z_m,
                     z_ref_m=res.z_ref_m, photon_along_m=res.along_track_m[d.shot],
                     photon_h_m=res.h_m, is_signal=d.is_signal, path=plot,
                     title=f"{inst.beam} beam over {what}: bias {100 * rep.overall.bias_m:.1f} cm, "
                           f"precision {100 * rep.overall.std_m:.1f} cm")
        print(f"wrote {plot}")
    return 0


def _forest_only_on_built_in(a) -> None:
    """``--forest`` is refused with ``--like`` (a twin's surface is the real granule's)."""
    if a.forest is not None and a.like is not None:
        raise UsageError("--forest", "applies to a built-in surface or --dem, not --like")


def _forest(a, surface_given: dict, water):
    """The run's surface: the ``--surface`` options' :class:`SurfaceSpec` (None with
    ``--scene``), or with ``--forest`` a
    :class:`~lidar_mitsuba.vegetation.forest.ForestSurface` over it (flat without
    ``--surface`` options)."""
    from ..ground.surface import SurfaceSpec
    if a.forest is None:
        return None if a.scene else SurfaceSpec(**surface_given)
    for flag, value in (("--scene", a.scene), ("--snow-grain-um", a.snow_grain_um),
                        ("--water-wind-mps", water)):
        if value is not None:
            raise UsageError(flag, "does not apply to --forest")
    from ..vegetation.forest import forest_from_spec
    return forest_from_spec(a.forest, ground=(SurfaceSpec(**surface_given).build()
                                              if surface_given else None))


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


def _snow_model(a) -> str:
    """``--snow-model`` (``auto`` when not given); only with ``--snow-grain-um``."""
    if a.snow_model is not None and a.snow_grain_um is None:
        raise UsageError("--snow-model", "only applies with --snow-grain-um")
    return a.snow_model or "auto"


def _snow(a):
    """The run's snow volume from the ``--snow-*`` options, or ``None`` (no --snow-grain-um)."""
    from ..ground import snow
    options = [(flag, key, getattr(a, flag[2:].replace("-", "_")))
               for flag, _, _, key, _ in SNOW_OPTIONS]
    given = [(flag, key, value) for flag, key, value in options if value is not None]
    if a.snow_grain_um is None:
        if given:
            raise UsageError(given[0][0], "only applies with --snow-grain-um")
        return None
    # options not given keep snow_from_grains' defaults
    vol = snow.snow_from_grains(grain_radius_um=a.snow_grain_um,
                                **{key: value for _, key, value in given if key})
    return vol if a.snow_similarity_g is None else vol.similar(a.snow_similarity_g)


def _cloud_kw(a) -> dict:
    """``{"cloud": ...}`` when ``--cloud-od`` is given (a clear run passes nothing)."""
    cloud = _cloud(a)
    return {} if cloud is None else {"cloud": cloud}


def _simulate_dem(a, out, plot) -> int:
    """``simulate --dem``: a granule of up to six beams along a ground track."""
    from ..startup import granule_process
    granule_process()               # the writer process, the first kernels, the renderer
    from .. import geotrack, granule
    atl06_out = out_path(a.atl06, (".h5", ".hdf5"), "--atl06") if a.atl06 else None
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
    atl08_out = _atl08_out(a, out)
    if a.forest is not None:                        # a stand over the DEM
        if a.snow_grain_um is not None:
            raise UsageError("--snow-grain-um", "does not apply to --forest")
        from ..vegetation.forest import forest_from_spec
        surface = forest_from_spec(a.forest, ground=surface)
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
            atl03_path=out, atl06_path=atl06_out, atl08_path=atl08_out, snow=_snow(a),
            snow_model=_snow_model(a), **_cloud_kw(a), **run)
    where = f"{surface.dem.path.name} ({surface.dem.crs.to_string()})"
    if a.forest is not None:
        where = f"a {surface.representation} {surface.stand.species} forest over {where}"
    print(f"{len(summaries)} beam(s), {shots} shots each ({shots * 0.7e-3:.1f} km), over {where}")
    code = _granule_report(a, summaries, out, atl06_out, plot)
    if atl08_out is not None:
        print(f"wrote {atl08_out}")
    return code


def _atl08_out(a, out):
    """``--atl08``'s file; with ``--forest`` and no ``--atl08``, ``NAME_ATL08.h5`` beside
    ``--out``; else None."""
    if a.atl08:
        return out_path(a.atl08, (".h5", ".hdf5"), "--atl08")
    if a.forest is not None:
        return out.with_name(f"{out.stem}_ATL08{out.suffix}")
    return None


def _dem_surface(a, seed: int):
    """``--dem``'s surface, with ``--roughness-*`` and ``--mesh-grid-m``."""
    from ..ground import dem as dems
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
        from ..plotting import granule_clouds
        granule_clouds(out, plot)
        print(f"wrote {plot}")
    return 0


def _simulate_like(a, out, plot) -> int:
    """``simulate --like REAL.h5``: the twin of a real granule over ``--dem`` or a built-in
    surface (:mod:`lidar_mitsuba.twin`)."""
    from .. import granule, twin
    from ..ground.surface import SurfaceSpec
    atl06_out = out_path(a.atl06, (".h5", ".hdf5"), "--atl06") if a.atl06 else None
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
    print(real.missing_line())
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
                atl06_path=atl06_out, snow=_snow(a), snow_model=_snow_model(a),
                **_cloud_kw(a), **run)
        else:
            surface_given = opts.given(a, a._surface_opts)
            if "kind" not in surface_given and "slope_deg" in surface_given:
                surface_given["kind"] = "slope"
            surface_given.setdefault("kind", "flat")
            g = twin.simulate_over_surface(
                real, surface=SurfaceSpec(**surface_given), beams=",".join(b.name for b in beams),
                shots=shots, instrument=preset, instrument_options=inst_opts,
                progress=not a.no_progress, snow=_snow(a), snow_model=_snow_model(a),
                water_wind_mps=a.water_wind_mps, **_cloud_kw(a), **run)
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


def _water_bsdf(a) -> dict | None:
    """``--water-wind-mps``: the water BSDF dict (None without it); refused with --scene."""
    if a.water_wind_mps is None:
        return None
    if a.scene is not None:
        raise UsageError("--water-wind-mps", "does not apply to --scene (give the XML a "
                         "<bsdf type=\"water\">)")
    from ..ground.water import water_bsdf
    try:
        return water_bsdf(wind_speed_mps=a.water_wind_mps)
    except ValueError as e:
        raise UsageError("--water-wind-mps", str(e)) from None
