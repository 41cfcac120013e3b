"""Campaign specs: a TOML file (or a dict of its tables) checked into a :class:`CampaignSpec`,
every error one line naming the key (:class:`~lidar_mitsuba.sweep.SpecError`). The format is
in :mod:`lidar_mitsuba.campaign`'s docstring."""
from __future__ import annotations

import math
import pathlib
from dataclasses import dataclass, field

from ..constants import ParameterError
from ..sweep.spec import FORMATS, SpecError, _read_source
from .tracks import RepeatOrbit

SECTIONS = ("campaign", "dem", "instrument", "run", "epochs", "orbit", "tracks", "surface",
            "snow", "cloud", "forest")
_KEYS = {
    "campaign": ("name", "seed", "format", "version", "revision", "kernel_cache", "map_bin_m",
                 "atl08"),
    "dem": ("path", "paths"),
    "instrument": ("preset", "beams", "sc_orient", "options"),
    "run": ("shots", "max_depth", "paths_per_shot", "section_shots"),
    "epochs": ("cycles", "dates"),
    "orbit": ("passes", "inclination_deg", "rgts", "days", "node_lon_deg", "cycle1_utc",
              "nodal_day_s", "min_length_km"),
    "tracks": ("start", "azimuth_deg", "polyline", "file", "rgt", "epoch_utc", "dem"),
    "surface": ("roughness_relief_m", "roughness_levels_m", "roughness_p"),
    "snow": ("grain_um", "grain_levels_um", "density_kg_m3", "density_levels_kg_m3", "model"),
    "cloud": ("optical_depth", "base_m", "top_m", "phase", "fraction", "optical_depth_median",
              "optical_depth_log_sigma"),
    "forest": ("species", "representation", "height_m", "cover", "stems_per_ha", "lai",
               "leaf_angle", "clumping", "crown_ratio", "crown_radius_m", "crown_shape",
               "leaf_width_m", "size_m", "seed"),
}
PASSES = ("ascending", "descending", "both")
SNOW_MODELS = ("auto", "kernel", "walk")


@dataclass(frozen=True)
class Property:
    """A surface property: a constant ``value``, or a GeoTIFF ``raster`` (absolute path)
    binned to ``levels`` (:func:`lidar_mitsuba.campaign.rasters.snap`)."""
    value: float | None = None
    raster: str | None = None
    levels: tuple[float, ...] = ()


@dataclass(frozen=True)
class CampaignSpec:
    """A checked campaign spec (fields as the TOML keys; paths absolute)."""
    name: str
    seed: int = 0
    format: str = "parquet"
    version: int = 1
    revision: int = 1
    kernel_cache: str | None = None
    map_bin_m: float = 1000.0
    dems: tuple[str, ...] = ()
    instrument: str = "paper"
    instrument_options: dict = field(default_factory=dict)
    beams: str = "all"
    sc_orient: int = 0
    run: dict = field(default_factory=dict)
    cycles: tuple[int, ...] = ()
    dates: tuple[str, ...] = ()
    orbit: RepeatOrbit | None = None
    passes: str = "both"
    min_length_m: float = 1000.0
    tracks: tuple[dict, ...] = ()
    roughness: Property | None = None
    roughness_p: float = 1.8
    grain: Property | None = None
    density: Property | None = None
    snow_model: str = "auto"
    cloud: dict | None = None
    forest: dict | None = None
    atl08: bool = False
    doc: dict = field(default_factory=dict)
    base_dir: str = "."

    def to_dict(self) -> dict:
        """The spec's tables as given (for ``spec.json``)."""
        return self.doc


def _int(key, v, lo, hi=2 ** 63 - 1):
    if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
        raise SpecError(key, f"must be an integer in [{lo}, {hi}] (got {v!r})")
    return v


def _num(key, v, lo=-math.inf, hi=math.inf, *, open_lo=False):
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) \
        and (v > lo if open_lo else v >= lo) and v <= hi
    if not ok:
        raise SpecError(key, f"must be a number in {'(' if open_lo else '['}{lo:g}, {hi:g}] "
                        f"(got {v!r})")
    return float(v)


def _table(doc, name) -> dict:
    t = doc.get(name, {})
    if not isinstance(t, dict):
        raise SpecError(f"[{name}]", "must be a table")
    for k in t:
        if k not in _KEYS[name]:
            raise SpecError(f"[{name}] {k}", f"unknown key (known: {', '.join(_KEYS[name])})")
    return t


def _path(base: pathlib.Path, key: str, v) -> str:
    if not isinstance(v, str) or not v:
        raise SpecError(key, f"must be a file name (got {v!r})")
    p = (base / v).resolve()
    if not p.is_file():
        raise SpecError(key, f"{str(p)!r} not found")
    return str(p)


def load_spec(source, *, base_dir: str | None = None) -> CampaignSpec:
    """A :class:`CampaignSpec` from a TOML file, a dict of its tables, or a CampaignSpec
    (returned as is). Paths are relative to the file's folder (for a dict: ``base_dir``,
    default the current folder). Raises :class:`~lidar_mitsuba.sweep.SpecError` naming the
    key."""
    if isinstance(source, CampaignSpec):
        return source
    doc, base, name = _read_source(source)
    if base_dir is not None and isinstance(source, dict):
        base = pathlib.Path(base_dir)
    base = base.resolve()
    for k in doc:
        if k not in SECTIONS:
            raise SpecError(f"[{k}]", f"unknown section (known: {', '.join(SECTIONS)})")
    kw = _campaign(_table(doc, "campaign"), base, name if name != "sweep" else "campaign")
    kw.update(_dems(_table(doc, "dem"), base), **_instrument(_table(doc, "instrument")),
              run=_run(_table(doc, "run")), **_epochs(_table(doc, "epochs")),
              **_orbit(doc), tracks=_tracks(doc, base), **_surface(doc, base),
              cloud=_cloud(doc), forest=_forest(doc))
    kw["atl08"] = _atl08(_table(doc, "campaign"), kw["forest"])
    if kw["forest"] is not None and (kw.get("grain") is not None
                                     or getattr(kw["roughness"], "raster", None)):
        raise SpecError("[forest]", "a forest stands on the DEM alone: leave out [snow] and a "
                        "roughness raster")
    if kw.get("grain") is not None and kw["run"]["max_depth"] != "auto":
        raise SpecError("[run] max_depth", "does not apply with [snow] (a snow volume traces "
                        "its own interactions per photon): leave it out")
    if kw["orbit"] is None and not kw["tracks"]:
        raise SpecError("spec", "no tracks: give [[tracks]] or an [orbit] (the repeat-orbit "
                        "tracks crossing the DEM)")
    if kw["orbit"] is not None and not kw["cycles"] and not kw["dates"]:
        raise SpecError("[epochs] cycles", "the [orbit]'s tracks need cycles (or dates)")
    if not kw["cycles"] and not kw["dates"] and any(t.get("epoch_utc") is None
                                                    for t in kw["tracks"]):
        raise SpecError("[epochs]", "give cycles or dates (or each track's epoch_utc)")
    return CampaignSpec(**kw, doc=doc, base_dir=str(base))


def _campaign(t: dict, base: pathlib.Path, default_name: str) -> dict:
    name = t.get("name", default_name)
    if not isinstance(name, str) or not name:
        raise SpecError("[campaign] name", f"must be a non-empty string (got {name!r})")
    fmt = t.get("format", "parquet")
    if fmt not in FORMATS:
        raise SpecError("[campaign] format", f"must be one of {', '.join(FORMATS)} (got {fmt!r})")
    cache = t.get("kernel_cache")
    if cache is not None and (not isinstance(cache, str) or not cache):
        raise SpecError("[campaign] kernel_cache", f"must be a folder name (got {cache!r})")
    return dict(name=name, seed=_int("[campaign] seed", t.get("seed", 0), 0),
                format=fmt, version=_int("[campaign] version", t.get("version", 1), 0, 999),
                revision=_int("[campaign] revision", t.get("revision", 1), 0, 99),
                kernel_cache=None if cache is None else str((base / cache).resolve()),
                map_bin_m=_num("[campaign] map_bin_m", t.get("map_bin_m", 1000.0), 40.0, 1e6))


def _dems(t: dict, base: pathlib.Path) -> dict:
    if "path" in t and "paths" in t:
        raise SpecError("[dem] paths", "give path or paths, not both")
    given = [t["path"]] if "path" in t else t.get("paths")
    if not isinstance(given, list) or not given:
        raise SpecError("[dem] path", "a GeoTIFF DEM is required (path = \"dem.tif\")")
    from ..ground.dem import DEM
    out = []
    for k, v in enumerate(given):
        key = "[dem] path" if "path" in t else f"[dem] paths[{k}]"
        p = _path(base, key, v)
        try:
            DEM.open(p)
        except ParameterError as e:
            raise SpecError(key, e.message) from None
        out.append(p)
    if len(set(out)) < len(out):
        raise SpecError("[dem] paths", "names a DEM twice")
    return {"dems": tuple(out)}


def _instrument(t: dict) -> dict:
    from ..geotrack import select_beams
    from ..instrument import INSTRUMENT_PRESETS, Instrument
    preset = t.get("preset", "paper")
    if preset not in INSTRUMENT_PRESETS:
        raise SpecError("[instrument] preset", f"must be one of {', '.join(INSTRUMENT_PRESETS)} "
                        f"(got {preset!r})")
    sc = _int("[instrument] sc_orient", t.get("sc_orient", 0), 0, 1)
    beams = t.get("beams", "all")
    opts = t.get("options", {})
    if not isinstance(opts, dict):
        raise SpecError("[instrument] options", "must be a table of Instrument fields")
    if "beam" in opts:
        raise SpecError("[instrument] options.beam", "is set per beam (use beams)")
    try:
        select_beams(beams if isinstance(beams, str) else "", sc)
        Instrument.atlas("strong", **opts) if preset == "atlas" else Instrument(**opts)
    except ParameterError as e:
        key = "[instrument] beams" if e.name == "beams" else f"[instrument] options.{e.name}"
        raise SpecError(key, e.message) from None
    except TypeError as e:
        raise SpecError("[instrument] options", f"not an Instrument field ({e})") from None
    return dict(instrument=preset, instrument_options=dict(opts), beams=beams, sc_orient=sc)


def _run(t: dict) -> dict:
    shots = t.get("shots", 2000)
    if shots != "all":
        _int("[run] shots", shots, 1, 10 ** 8)
    out = {"shots": shots, "section_shots": _int("[run] section_shots",
                                                  t.get("section_shots", 1 << 16), 1)}
    for k, lo, hi in (("max_depth", 1, 64), ("paths_per_shot", 1, 1 << 16)):
        v = t.get(k, "auto")
        out[k] = v if v == "auto" else _int(f"[run] {k}", v, lo, hi)
    return out


def _epochs(t: dict) -> dict:
    from ..geotrack import parse_utc
    cycles = t.get("cycles", [])
    dates = t.get("dates", [])
    if not isinstance(cycles, list) or not isinstance(dates, list):
        raise SpecError("[epochs]", "cycles and dates must be lists")
    for c in cycles:
        _int("[epochs] cycles", c, 1, 99)
    for d in dates:
        try:
            parse_utc(d if isinstance(d, str) else repr(d))
        except ParameterError as e:
            raise SpecError("[epochs] dates", e.message) from None
    if len(set(cycles)) < len(cycles) or len(set(dates)) < len(dates):
        raise SpecError("[epochs]", "repeats a cycle or date")
    return dict(cycles=tuple(cycles), dates=tuple(dates))


def _orbit(doc: dict) -> dict:
    if "orbit" not in doc:
        return {"orbit": None}
    t = _table(doc, "orbit")
    passes = t.get("passes", "both")
    if passes not in PASSES:
        raise SpecError("[orbit] passes", f"must be one of {', '.join(PASSES)} (got {passes!r})")
    kw = {k: t[k] for k in ("inclination_deg", "rgts", "days", "node_lon_deg", "cycle1_utc",
                            "nodal_day_s") if k in t}
    try:
        orbit = RepeatOrbit(**kw)
    except (ParameterError, TypeError) as e:
        name = getattr(e, "name", "orbit")
        raise SpecError(f"[orbit] {name}", getattr(e, "message", str(e))) from None
    if orbit.days <= 0:
        raise SpecError("[orbit] days", "must be > 0")
    length = _num("[orbit] min_length_km", t.get("min_length_km", 1.0), 0.0, 1e5, open_lo=True)
    return dict(orbit=orbit, passes=passes, min_length_m=1e3 * length)


def _tracks(doc: dict, base: pathlib.Path) -> tuple[dict, ...]:
    """``[[tracks]]`` as GeoTrack keywords plus ``rgt``, ``dem`` (an index) and ``epoch_utc``
    (or None)."""
    from ..geotrack import GeoTrack
    entries = doc.get("tracks", [])
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise SpecError("[[tracks]]", "must be an array of tables ([[tracks]] entries)")
    dems = doc.get("dem", {}).get("paths") or [doc.get("dem", {}).get("path")]
    out = []
    for k, e in enumerate(entries):
        where = f"[[tracks]] {k + 1}"
        for key in e:
            if key not in _KEYS["tracks"]:
                raise SpecError(f"{where} {key}", f"unknown key (known: "
                                f"{', '.join(_KEYS['tracks'])})")
        kinds = [key for key in ("start", "polyline", "file") if key in e]
        if len(kinds) != 1:
            raise SpecError(where, "give one of start (with azimuth_deg), polyline or file")
        t = {"rgt": _int(f"{where} rgt", e.get("rgt", 0), 0, 9999),
             "epoch_utc": e.get("epoch_utc"), "dem": 0}
        if "dem" in e:
            if e["dem"] not in dems:
                raise SpecError(f"{where} dem", f"must be one of [dem]'s ({dems})")
            t["dem"] = dems.index(e["dem"])
        try:
            if "start" in e:
                s = e["start"]
                if not (isinstance(s, list) and len(s) == 2):
                    raise SpecError(f"{where} start", f"must be [lat, lon] (got {s!r})")
                g = GeoTrack(start_lat_deg=s[0], start_lon_deg=s[1],
                             azimuth_deg=e.get("azimuth_deg", 0.0))
            elif "polyline" in e:
                g = GeoTrack(polyline=tuple(map(tuple, e["polyline"])))
            else:
                g = GeoTrack.from_file(_path(base, f"{where} file", e["file"]))
            if t["epoch_utc"] is not None:
                GeoTrack(start_lat_deg=0.0, start_lon_deg=0.0, epoch_utc=t["epoch_utc"])
        except ParameterError as e2:
            raise SpecError(f"{where} {'epoch_utc' if e2.name == 'epoch' else kinds[0]}",
                            e2.message) from None
        except (TypeError, ValueError) as e2:
            raise SpecError(f"{where} {kinds[0]}", str(e2)) from None
        d = g.to_dict()
        d.pop("epoch_utc")
        out.append({**t, "track": d})
    return tuple(out)


def _property(t: dict, key: str, levels_key: str | None, base: pathlib.Path, section: str,
              lo: float, hi: float) -> Property | None:
    if key not in t:
        if levels_key and levels_key in t:
            raise SpecError(f"[{section}] {levels_key}", f"only applies with {key}")
        return None
    v = t[key]
    if isinstance(v, str):
        path = _path(base, f"[{section}] {key}", v)
        from .rasters import PropertyRaster
        try:
            PropertyRaster(path)
        except ParameterError as e:
            raise SpecError(f"[{section}] {key}", e.message) from None
        levels = t.get(levels_key) if levels_key else None
        if not isinstance(levels, list) or not levels:
            raise SpecError(f"[{section}] {levels_key}", f"a raster {key} needs the levels it "
                            "is binned to (a list of values: one snow kernel table each)")
        lv = tuple(sorted({_num(f"[{section}] {levels_key}", x, lo, hi) for x in levels}))
        return Property(raster=path, levels=lv)
    if levels_key and levels_key in t:
        raise SpecError(f"[{section}] {levels_key}", f"only applies to a raster {key}")
    return Property(value=_num(f"[{section}] {key}", v, lo, hi))


def _cloud(doc: dict) -> dict | None:
    """``[cloud]``: one cloud over every granule (``optical_depth``, ``base_m``, ``top_m``,
    ``phase``) or a climatology each granule draws from with its own seed (``fraction``,
    ``optical_depth_median``, ``optical_depth_log_sigma``, ``base_m``, ``top_m``, ``phase``:
    :class:`~lidar_mitsuba.atmosphere.cloud_layer.CloudClimatology`); checked, as given."""
    if "cloud" not in doc:
        return None
    from ..atmosphere.cloud_layer import Cloud, CloudClimatology
    t = dict(_table(doc, "cloud"))
    fixed, clim = "optical_depth" in t, "fraction" in t
    if fixed == clim:
        raise SpecError("[cloud]", "give optical_depth (one cloud) or fraction (a "
                        "climatology), not both")
    phase = t.get("phase", "water")
    if phase not in ("water", "ice"):
        raise SpecError("[cloud] phase", f"must be water or ice (got {phase!r})")
    names = {"cloud_od": "optical_depth", "cloud_base_m": "base_m", "cloud_top_m": "top_m",
             "cloud_fraction": "fraction"}
    try:
        if fixed:
            make = Cloud.water if phase == "water" else Cloud.ice
            make(t["optical_depth"], t.get("base_m", 1000.0), t.get("top_m", 1500.0))
            bad = [k for k in ("fraction", "optical_depth_median", "optical_depth_log_sigma")
                   if k in t]
            if bad:
                raise SpecError(f"[cloud] {bad[0]}", "only applies to a climatology (fraction)")
        else:
            CloudClimatology(**{("cloud_fraction" if k == "fraction" else k): v
                                for k, v in t.items()})
    except ParameterError as e:
        raise SpecError(f"[cloud] {names.get(e.name, e.name)}", e.message) from None
    except TypeError as e:
        raise SpecError("[cloud]", str(e)) from None
    return t


def _surface(doc: dict, base: pathlib.Path) -> dict:
    s = _table(doc, "surface")
    rough = _property(s, "roughness_relief_m", "roughness_levels_m", base, "surface", 0.0, 100.0)
    p = _num("[surface] roughness_p", s.get("roughness_p", 1.8), 1.0, 3.0)
    if "snow" not in doc:
        return dict(roughness=rough, roughness_p=p)
    sn = _table(doc, "snow")
    if "grain_um" not in sn:
        raise SpecError("[snow] grain_um", "is required in [snow] (a number or a raster)")
    model = sn.get("model", "auto")
    if model not in SNOW_MODELS:
        raise SpecError("[snow] model", f"must be one of {', '.join(SNOW_MODELS)} (got {model!r})")
    return dict(roughness=rough, roughness_p=p, snow_model=model,
                grain=_property(sn, "grain_um", "grain_levels_um", base, "snow", 5.0, 5000.0),
                density=_property(sn, "density_kg_m3", "density_levels_kg_m3", base, "snow",
                                  10.0, 825.3))


def _forest(doc: dict) -> dict | None:
    """``[forest]``: a stand over every granule's DEM (the keywords of
    :func:`~lidar_mitsuba.vegetation.forest.forest`, ``size_m`` the side of its periodic
    square at the DEM's centre), checked, as given."""
    if "forest" not in doc:
        return None
    t = dict(_table(doc, "forest"))
    from ..ground.surface import Plane
    from ..vegetation.forest import forest
    kw = {k: v for k, v in t.items() if k != "size_m"}
    size = _num("[forest] size_m", t.get("size_m", 2048.0), 10.0, 1e5)
    try:                                   # the stand's values, on a small flat ground
        forest(ground=Plane(size_m=min(size, 50.0)), **kw)
    except ParameterError as e:
        raise SpecError(f"[forest] {e.name}", e.message) from None
    except TypeError as e:
        raise SpecError("[forest]", str(e)) from None
    return t


def _atl08(t: dict, forest: dict | None) -> bool:
    """``[campaign] atl08``: write our ATL08 of every granule (default: with a [forest])."""
    v = t.get("atl08", forest is not None)
    if not isinstance(v, bool):
        raise SpecError("[campaign] atl08", f"must be true or false (got {v!r})")
    return v
