"""What a real ICESat-2 file of any product says, beam by beam: ATL03 (geolocated photons),
ATL06 (land-ice segments), ATL07 (sea-ice segments) and ATL08 (land and vegetation segments),
of any release (v001-v006) and as subsetting tools leave them (groups dropped, attributes
rewritten as object arrays). Pure (h5py, numpy).

Each beam becomes a table of segments (:class:`RealBeam`): where and when (latitude,
longitude, time), the surface height above the ellipsoid, the spacecraft's altitude, the sun,
the transmitted pulse energy, and what the product measured there (background rate, signal
photons per shot, cloud flags, saturation). What a file lacks is left ``None`` and named in
:attr:`RealFile.missing`, said in one line by :meth:`RealFile.missing_line`.

Strong or weak comes from the beam group's ``atlas_beam_type`` attribute, trusted over
``orbit_info/sc_orient`` (a clip tool can rewrite the latter; ``sc_orient`` is the fallback).
"""
from __future__ import annotations

import pathlib
import re
from dataclasses import dataclass, field

import numpy as np

from ..constants import ParameterError

BEAM_NAMES = ("gt1l", "gt1r", "gt2l", "gt2r", "gt3l", "gt3r")
PRODUCT_GROUPS = {"ATL03": "geolocation", "ATL06": "land_ice_segments",
                  "ATL07": "sea_ice_segments", "ATL08": "land_segments"}
"""Each product's per-beam group that holds its segments."""
SURF_TYPES = ("land", "ocean", "sea ice", "land ice", "inland water")
"""ATL03 ``geolocation/surf_type``'s five columns (ATL03 data dictionary)."""
SURF_PRIORITY = (3, 2, 4, 0, 1)
"""Which of them names a segment flagged as several (the mask's regions overlap: sea ice is
also ocean): land ice, sea ice, inland water, land, ocean."""
CLEAR_TWO_WAY_TRANSMISSION = 0.5
"""A segment is clear when its apparent surface reflectance (ATL06 ``r_eff``, ATL07
``asr_25``) is at least this fraction of its surface's reflectance: a cloud's two-way
transmission ``exp(-2 tau)`` >= 0.5, i.e. optical depth <= 0.35 (ESTIMATE: a cloud that
halves the return is one the model must hold)."""
SNOW_REFLECTANCE = 0.9
"""The reflectance a clear snow segment's ``r_eff`` or ``asr_25`` is held against (the
reference plate's albedo; clean snow 0.9-0.98 at 532 nm: ICESat-2 science specifications)."""


@dataclass
class RealBeam:
    """One beam of a real file as segments; arrays have shape (n_segments,), ``None`` where
    the file lacks them.

    Attributes:
        name, spot, strength: the beam (``gt1l``, its ATLAS spot, ``strong`` or ``weak``).
        strength_from: ``atlas_beam_type`` or ``sc_orient`` (where strength came from).
        delta_time_s, lat_deg, lon_deg: each segment's time [s since 2018-01-01] and place.
        surface_h_m: the surface height above the ellipsoid [m] (NaN where none).
        altitude_m: the spacecraft's height above the ellipsoid [m], or None.
        solar_elevation_deg, solar_azimuth_deg: the sun [deg], or None.
        pulse_energy_uj: transmitted energy per pulse of this beam [uJ] (ATL03
            ``tx_pulse_energy``), or None.
        background_hz: the product's background rate [Hz], or None.
        signal_per_shot: signal photons per shot the product measured, or None.
        clear: True where the sky is clear by the product's cloud flags, or None (no flag).
        reflectance: the apparent surface reflectance the product measured (ATL06 ``r_eff``,
            ATL07 ``asr_25``), or None: with the clear segments', the cloud's optical depth
            (:func:`~lidar_mitsuba.products.cloud_flags.implied_optical_depth`).
        reflectance_photons: a second apparent reflectance made from the altimetric photons
            whose rate is the signal (ATL07 ``heights/height_segment_asr_calc``:
            ``photon_rate`` over a constant of the beam), or None: independent of the
            background, not of the signal.
        ice_fraction: the sea-ice concentration where the product gives it (ATL07
            ``stats/ice_conc`` [%] / 100, from passive microwave), or None.
        layer_class: ATL09's multiple-scattering warning ``msw_flag`` copied by ATL06 and
            ATL07 (the height class of the lowest layer's base: 3 below 1 km, 2 1-3 km, 1
            above 3 km, 4-5 blowing snow, 0 none, -1 unknown), or None.
        layer_count: the number of layers ATL09's layer finder found (ATL06
            ``cloud_flg_atm``, ATL07 ``cloud_flag_atm``; ``msw_flag`` places only the lowest),
            or None.
        band_height_m, band_top_above_surface_m, signal_span_m: the background histogram's
            band (ATL03 ``bckgrd_atlas``; ATL07 ``background_int_height``), or None.
        full_sat_fract, near_sat_fract: ATL03's saturation fractions, or None.
        surface: what the product says the surface is (``land ice``, ``sea ice``, ...).
        notes: what each measured quantity is, for a report.
    """
    name: str
    spot: int
    strength: str
    strength_from: str
    delta_time_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    surface_h_m: np.ndarray
    altitude_m: np.ndarray | None = None
    solar_elevation_deg: np.ndarray | None = None
    solar_azimuth_deg: np.ndarray | None = None
    pulse_energy_uj: np.ndarray | None = None
    background_hz: np.ndarray | None = None
    signal_per_shot: np.ndarray | None = None
    clear: np.ndarray | None = None
    reflectance: np.ndarray | None = None
    reflectance_photons: np.ndarray | None = None
    layer_class: np.ndarray | None = None
    layer_count: np.ndarray | None = None
    ice_fraction: np.ndarray | None = None
    band_height_m: np.ndarray | None = None
    band_top_above_surface_m: np.ndarray | None = None
    signal_span_m: np.ndarray | None = None
    full_sat_fract: np.ndarray | None = None
    near_sat_fract: np.ndarray | None = None
    surface: str = "unknown"
    notes: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.surface_h_m is None:         # (a subset that dropped the heights: NaN, and
            self.surface_h_m = np.full(np.shape(self.delta_time_s), np.nan)  # said so)
        self.drop_fill()

    def drop_fill(self) -> None:
        """Take a series that holds fill on every segment as absent (:data:`OPTIONAL_SERIES`),
        with a note for the file's line."""
        for name in OPTIONAL_SERIES:
            a = getattr(self, name)
            if a is not None and not np.isfinite(np.asarray(a, np.float64)).any():
                setattr(self, name, None)
                self.notes.setdefault(f"{name}_missing".replace("_per_shot", ""),
                                      "fill everywhere")

    @property
    def n_segments(self) -> int:
        return int(self.delta_time_s.size)


@dataclass
class RealFile:
    """A real ICESat-2 file read by :func:`read_product`."""
    path: pathlib.Path
    product: str
    release: str | None
    sc_orient: int | None
    beams: list[RealBeam]
    missing: list[str]

    def missing_line(self) -> str:
        """What the file lacks that a twin or the realism matrix would use, in one line."""
        if not self.missing:
            return f"{self.path.name} ({self.product}): nothing missing"
        return f"{self.path.name} ({self.product}) lacks: " + "; ".join(self.missing)


# ------------------------------------------------------------------------------ helpers
def text(value) -> str:
    """An HDF5 attribute as text: bytes, numpy bytes, or a one-element (object) array."""
    if isinstance(value, np.ndarray):
        value = value.ravel()[0] if value.size else ""
    return value.decode() if isinstance(value, (bytes, np.bytes_)) else str(value)


def _num(g, key: str) -> np.ndarray | None:
    """Dataset ``key`` of group ``g`` as float64 with fill values NaN (its ``_FillValue``:
    ATL07's int8 ``bsnow_con`` fills with 127; beyond 1e30 or at int32's maximum where it
    has none); None when absent."""
    if key not in g:
        return None
    a = np.asarray(g[key][()])
    fill = getattr(g[key], "attrs", {}).get("_FillValue")
    fill = None if fill is None or np.size(fill) != 1 else np.asarray(fill).ravel()[0]
    own = (a == fill) if (fill is not None and fill != 0 and a.dtype.kind in "iuf") else False
    # (a fill of 0 would take every zero: ICESat-2's are their types' extremes)
    if a.dtype.kind in "iu":
        bad = a >= np.iinfo(np.int32).max if a.dtype.itemsize >= 4 else np.zeros(a.shape, bool)
        a = a.astype(np.float64)
        a[bad | own] = np.nan
        return a
    a = a.astype(np.float64)
    a[(np.abs(a) > 1e30) | own] = np.nan
    return a


#: a background rate's ``units`` attribute (lower case, spaces removed) -> its factor to Hz:
#: NASA writes ``hz`` (ATL06) and ``counts / second`` (ATL03); a tool, or our ATL06 before
#: session 29 (``MHz``), may write another
RATE_UNITS_TO_HZ = {"mhz": 1e6, "khz": 1e3, "hz": 1.0, "counts/second": 1.0, "1/s": 1.0,
                    "counts/s": 1.0, "s-1": 1.0, "1/second": 1.0}


def _rate_hz(g, key: str) -> np.ndarray | None:
    """Rate dataset ``key`` of group ``g`` [Hz] (:func:`_num`), scaled by its ``units``
    attribute where that names MHz or kHz (:data:`RATE_UNITS_TO_HZ`; no or an unknown unit:
    Hz, NASA's)."""
    a = _num(g, key)
    if a is None:
        return None
    unit = text(g[key].attrs.get("units", "")).lower().replace(" ", "")
    factor = RATE_UNITS_TO_HZ.get(unit, 1.0)
    return a * factor if factor != 1.0 else a


def sc_orient(f) -> int | None:
    """0 backward, 1 forward: ``orbit_info/sc_orient`` or a beam's ``sc_orientation``;
    None when neither is there, or ``sc_orient`` is empty (a time subset that cut its
    ``sc_orient_time`` rows) or neither 0 nor 1 (2: the yaw flip's transition; its fill,
    127): no beam layout to take the strengths from."""
    if "orbit_info/sc_orient" in f:
        v = np.asarray(f["orbit_info/sc_orient"][()]).ravel()
        return int(v[0]) if v.size and v[0] in (0, 1) else None
    for name in BEAM_NAMES:
        if name in f and "sc_orientation" in f[name].attrs:
            return 1 if text(f[name].attrs["sc_orientation"]).lower() == "forward" else 0
    return None


def product_of(f, path: pathlib.Path) -> str:
    """The product: from the beam groups' contents (a subset keeps those), else the name."""
    import h5py
    for name in BEAM_NAMES:
        if name not in f or not isinstance(f[name], h5py.Group):
            continue
        if "heights" in f[name] or f"{name}/geolocation/reference_photon_lat" in f:
            return "ATL03"
        for product, group in PRODUCT_GROUPS.items():
            if product != "ATL03" and group in f[name]:
                return product
    flat = _flattened(f)
    for product, group in PRODUCT_GROUPS.items():
        if flat and any(k[5:].startswith(group) for k in f.keys()):
            return product                   # read_product says why it cannot read them
    m = re.search(r"ATL0[3678]", path.name.upper())
    if m:
        return m.group(0)
    named = text(f.attrs.get("short_name", "")) or next(iter(re.findall(r"ATL\d\d(?!\d)",
                                                                      path.name.upper())), "")
    # (two digits and no third: "atl012.nc", a user's name for an ATL12, is not an ATL01)
    if named in PRODUCT_GROUPS:        # (one of ours whose segment groups a subset dropped)
        return named
    if named:
        raise ParameterError("like", f"{path}: {named} is not read (only ATL03, ATL06, ATL07 "
                             "and ATL08)")
    raise ParameterError("like", f"{path}: not an ICESat-2 ATL03, ATL06, ATL07 or ATL08 file "
                         f"(it holds {_holds(f)})")


def _flattened(f) -> str | None:
    """The words for a file whose beam groups were flattened into dataset names
    (``gt1l_land_ice_segments_h_li``: OPeNDAP's CF option, a netCDF conversion), or None."""
    flat = sorted(k for k in f.keys() if re.match(r"gt[123][lr]_", k))
    if not flat:
        return None
    return (f"its groups are flattened into names ({flat[0]}, ...: an OPeNDAP or netCDF "
            "conversion); only the groups NASA writes (gt1l/land_ice_segments/h_li) are read")


def _holds(f) -> str:
    """The first few top-level names of an HDF5 file, for a one-line message."""
    keys = list(f.keys())
    return (", ".join(keys[:6]) + (", ..." if len(keys) > 6 else "")) if keys else "nothing"


def _beam_holds(f, group: str) -> str:
    """What a file without a usable beam holds, for a one-line message: its first beam
    group's names where it has beam groups (``gt1l holds h_li, lat, ...; no
    land_ice_segments``: a restructured file keeps the groups' names, not their layout),
    else its top-level names (``it holds ph_index_beg``)."""
    import h5py
    names = [n for n in BEAM_NAMES if n in f and isinstance(f[n], h5py.Group)]
    if not names:
        return _flattened(f) or f"it holds {_holds(f)}"
    name = next((n for n in names if len(f[n])), names[0])     # an empty group last
    g = f[name]
    if group not in g or not isinstance(g[group], h5py.Group):
        return f"{name} holds {_holds(g)}; no {group}"
    if "delta_time" not in g[group]:
        return f"{name}/{group} holds {_holds(g[group])}; no delta_time"
    return f"{name}/{group} holds {g[group]['delta_time'].shape[0]} segment(s)"


HDF5_SUFFIXES = (".h5", ".hdf5", ".he5", ".hdf", ".nc", ".nc4")
"""The names a folder's HDF5 files go by (any case): NASA's ``.h5``, ``.hdf`` as some tools
name their ATL03 cuts (``ATL03_Ground_..._gt1l.hdf``; an HDF4 file of that name is passed by
as not HDF5), and the NetCDF-4 (an HDF5 file) that the NSIDC subsetter's reformatting writes
(``processed_ATL03_..._01.nc``, ``processed_ATL10-01_..._01.nc``) or OPeNDAP serves
(``.nc4``); :func:`release_of` reads the release from names of these."""

_RELEASE_IN_NAME = re.compile(r"_(\d{3})_\d{2}(?:_[^.]*)?\.(?:"
                              + "|".join(x.lstrip(".") for x in HDF5_SUFFIXES) + ")$",
                              re.IGNORECASE)


def release_of(f, path: pathlib.Path) -> str | None:
    """The release (``006``): ``ancillary_data/release`` or ``version``, else the file name's
    ``_RRR_VV.h5`` tail, else the ``VersionID`` of ``METADATA/DatasetIdentification`` (a
    trajectory subsetter keeps ``METADATA`` and the beam, drops ``ancillary_data`` and
    renames the file: ``ATL03_gt1l.h5``); None when none says."""
    for key in ("ancillary_data/release", "ancillary_data/version"):
        if key in f:
            v = text(np.asarray(f[key][()])).strip()
            if v:
                return v
    m = _RELEASE_IN_NAME.search(path.name)
    if m:
        return m.group(1)
    ident = f.get("METADATA/DatasetIdentification")
    v = text(ident.attrs.get("VersionID", "")).strip() if ident is not None else ""
    return v or None


def _strength(f, name: str, orient: int | None) -> tuple[int, str | None, str]:
    """``(spot, strength, from)``: the group's ``atlas_beam_type`` and ``atlas_spot_number``
    where given, else the layout of ``sc_orient``; ``(spot or 0, None, "unknown")`` where
    neither says (:mod:`~lidar_mitsuba.products.real_strength` reads the pairs then)."""
    from ..geotrack import beam_layout
    attrs = f[name].attrs
    layout = {b.name: b for b in beam_layout(orient if orient in (0, 1) else 0)}
    spot = layout[name].spot
    if "atlas_spot_number" in attrs:
        try:
            spot = int(text(attrs["atlas_spot_number"]))
        except ValueError:
            pass
    if "atlas_beam_type" in attrs and text(attrs["atlas_beam_type"]).lower() in ("strong",
                                                                                 "weak"):
        return spot, text(attrs["atlas_beam_type"]).lower(), "atlas_beam_type"
    if orient is None:                            # the pairs' signal rates tell, if any
        return (spot if "atlas_spot_number" in attrs else 0), None, "unknown"
    return spot, layout[name].strength, "sc_orient"


# ------------------------------------------------------------------------------ the reader
def read_product(path, *, beams: str = "all") -> RealFile:
    """The beams of a real ATL03, ATL06, ATL07 or ATL08 file (``beams``: ``all``,
    ``strong``, ``weak`` or names) as :class:`RealBeam` segment tables. Raises
    ``ParameterError`` (``like``) for a file it cannot read."""
    import h5py
    from .real_readers import READERS
    path = pathlib.Path(path)
    if not path.is_file():
        raise ParameterError("like", f"{path}: no such file")
    try:
        with h5py.File(path, "r") as f:
            product = product_of(f, path)
            orient = sc_orient(f)
            missing = [] if orient is not None else ["orbit_info/sc_orient"]
            out, unplaced = [], []
            for name in BEAM_NAMES:
                if f"{name}/{PRODUCT_GROUPS[product]}" not in f:
                    continue
                spot, strength, source = _strength(f, name, orient)
                if strength is not None and not _wanted(name, strength, beams):
                    continue
                b = READERS[product](f[name], name=name, spot=spot, strength=strength,
                                     strength_from=source)
                if b is not None and b.n_segments >= 2:
                    b.drop_fill()           # (series the reader set after the beam was made)
                    why = _unplaced(b, product)
                    if why:             # (a beam with no time or place cannot be twinned)
                        unplaced.append((name, why))
                    else:
                        out.append(b)
            release = release_of(f, path)
            holds = _beam_holds(f, PRODUCT_GROUPS[product])
    except OSError as e:
        raise ParameterError("like", f"{path}: not an HDF5 file we can read "
                             f"({str(e).splitlines()[0]})") from None
    except ParameterError:
        raise
    except (KeyError, ValueError) as e:
        raise ParameterError("like", f"{path}: not an ICESat-2 product we can read "
                             f"({str(e).splitlines()[0]})") from None
    from .real_strength import infer, orientation
    if any(b.strength is None for b in out):
        orient = infer(out, path)
        out = [b for b in out if _wanted(b.name, b.strength, beams)]
    orient, contradiction = orientation(out, orient)
    missing += [contradiction] if contradiction else []
    if not out:
        raise ParameterError("like", f"{path}: no beam group (gt1l-gt3r) with two "
                             f"{PRODUCT_GROUPS[product]} segments"
                             + (f" with a time and place ({_reasons(unplaced)})" if unplaced
                                else f" ({holds})" if beams == "all"
                                else f" among {beams!r}"))
    missing += _missing(out, product)
    if release is None:
        missing.append("release (ancillary_data/release, METADATA's VersionID)")
    return RealFile(path=path, product=product, release=release, sc_orient=orient,
                    beams=out, missing=missing)


PLACE_DATASETS = {"ATL03": ("geolocation/delta_time",
                             "geolocation/reference_photon_lat (or heights/lat_ph)",
                             "geolocation/reference_photon_lon (or heights/lon_ph)")}
"""Where a product gives each segment's time and place (the others: their segment group's
``delta_time``, ``latitude``, ``longitude``)."""


def _reasons(named: list[tuple[str, str]]) -> str:
    """``[(beam, why), ...]`` as one phrase: beams that share a reason named together."""
    by: dict[str, list[str]] = {}
    for name, why in named:
        by.setdefault(why, []).append(name)
    return "; ".join(f"{', '.join(names)}: {why}" for why, names in by.items())


def _unplaced(b: RealBeam, product: str) -> str | None:
    """Why a beam's segments cannot be placed (no or fewer than two segments with a finite
    time, latitude and longitude: a subset that dropped them, or fill values), else None."""
    names = PLACE_DATASETS.get(product, tuple(f"{PRODUCT_GROUPS[product]}/{k}" for k in
                                              ("delta_time", "latitude", "longitude")))
    arrays = (b.delta_time_s, b.lat_deg, b.lon_deg)
    absent = [n for n, a in zip(names, arrays) if a is None]
    if absent:
        return f"no {', '.join(absent)}"
    ok = np.isfinite(b.delta_time_s) & np.isfinite(b.lat_deg) & np.isfinite(b.lon_deg)
    if int(ok.sum()) < 2:
        return f"fewer than two segments with a finite {', '.join(names)}"
    return None


OPTIONAL_SERIES = ("altitude_m", "solar_elevation_deg", "solar_azimuth_deg", "pulse_energy_uj",
                   "background_hz", "signal_per_shot", "reflectance", "reflectance_photons",
                   "layer_class", "layer_count", "ice_fraction", "band_height_m",
                   "band_top_above_surface_m", "signal_span_m", "full_sat_fract",
                   "near_sat_fract")
""":class:`RealBeam`'s per-segment series that may be absent: one that holds fill (NaN) on
every segment is taken as absent (its stand-in used, said in the file's line)."""


def _wanted(name: str, strength: str, beams: str) -> bool:
    """Whether a beam is among ``beams`` (``all``, ``strong``, ``weak`` or names)."""
    return beams in ("all", strength) or name in beams.split(",")


RATE_DATASETS = {("ATL03", "background_hz"): "no bckgrd_atlas/bckgrd_rate",
                 ("ATL06", "background_hz"): "no geophysical/bckgrd",
                 ("ATL07", "background_hz"): "no stats/backgr_r_200",
                 ("ATL08", "background_hz"): "ATL08 has none",
                 ("ATL03", "signal_per_shot"): "no photons with their ids",
                 ("ATL06", "signal_per_shot"): "no fit_statistics/n_fit_photons, n_seg_pulses",
                 ("ATL07", "signal_per_shot"): "no stats/photon_rate",
                 ("ATL08", "signal_per_shot"): "no terrain/photon_rate_te"}
"""What a product's rates are read from, for a file's line where it lacks them."""


def _missing(beams: list[RealBeam], product: str) -> list[str]:
    """Names of what every beam lacks, with what stands in for it."""
    out = []
    checks = (("altitude_m", "altitude_sc (range: ATLAS's nominal)"),
              ("solar_elevation_deg", "solar_elevation (the sun from the time and place)"),
              ("pulse_energy_uj", "tx_pulse_energy (ATLAS's energy history, ESTIMATE)"),
              ("background_hz", "a background rate"),
              ("signal_per_shot", "a signal rate"),
              ("clear", "cloud flags (all segments taken as clear)"),
              ("band_height_m", "the background histogram's band (polar defaults)"),
              ("full_sat_fract", "saturation fractions"))
    for attr, words in checks:
        if all(getattr(b, attr) is None for b in beams):
            why = {b.notes.get(f"{attr}_missing".replace("_per_shot", "")) for b in beams}
            why.discard(None)
            why = why or {RATE_DATASETS.get((product, attr))} - {None}
            out.append(words + (f" ({'; '.join(sorted(why))})" if why else ""))
    if all(not np.isfinite(b.surface_h_m).any() for b in beams):
        out.append("surface heights")
    out += [w for w in beams[0].notes.get("stand_ins", ())          # what every beam lacks
            if all(w in b.notes.get("stand_ins", ()) for b in beams)]
    if product == "ATL03" and all(b.surface == "unknown" for b in beams):
        out.append("surf_type (the surface: a flat plate of albedo 0.1)")
    bad = [b.name for b in beams if b.strength_from == "sc_orient"]
    if bad:
        out.append(f"atlas_beam_type on {', '.join(bad)} (strength from sc_orient)")
    from .real_strength import missing_words
    inferred = missing_words(beams)
    return out + ([inferred] if inferred else [])


# ------------------------------------------------------------------------------ trimming
READ_DATASETS = {
    "ATL06": tuple("land_ice_segments/" + k for k in (
        "delta_time", "latitude", "longitude", "h_li", "atl06_quality_summary",
        "geophysical/bckgrd", "geophysical/r_eff", "geophysical/cloud_flg_asr",
        "geophysical/cloud_flg_atm", "geophysical/msw_flag", "geophysical/solar_elevation",
        "geophysical/solar_azimuth", "dem/dem_flag", "dem/dem_h", "dem/geoid_h",
        "fit_statistics/n_fit_photons", "fit_statistics/n_seg_pulses",
        "fit_statistics/w_surface_window_final")),
    "ATL07": tuple("sea_ice_segments/" + k for k in (
        "delta_time", "latitude", "longitude", "heights/height_segment_height",
        "heights/height_segment_type", "heights/height_segment_asr_calc",
        "geophysical/height_segment_mss",
        "geolocation/solar_elevation", "geolocation/solar_azimuth", "stats/photon_rate",
        "stats/asr_25", "stats/cloud_flag_asr", "stats/cloud_flag_atm", "stats/msw_flag",
        "stats/ice_conc",
        "stats/backgr_r_200",
        "stats/background_int_height")),
    "ATL08": tuple("land_segments/" + k for k in (
        "delta_time", "latitude", "longitude", "terrain/h_te_best_fit",
        "terrain/photon_rate_te", "canopy/photon_rate_can", "solar_elevation",
        "solar_azimuth", "cloud_flag_atm")),
}
"""Per beam, the datasets :func:`read_product` reads of each segment product (what
:func:`trim` keeps); ATL03 is kept whole (its photons are what it is read for)."""
KEPT_GLOBAL = ("orbit_info/sc_orient", "ancillary_data/release", "ancillary_data/version",
               "ancillary_data/atlas_sdp_gps_epoch")


def trim(path, out) -> pathlib.Path:
    """A copy of a real ATL06, ATL07 or ATL08 file with only what :func:`read_product` reads
    (:data:`READ_DATASETS`, the beam groups' attributes, :data:`KEPT_GLOBAL`), compressed: a
    file small enough to ship, read to the same numbers."""
    import h5py
    path, out = pathlib.Path(path), pathlib.Path(out)
    with h5py.File(path, "r") as f, h5py.File(out, "w") as g:
        product = product_of(f, path)
        if product not in READ_DATASETS:
            raise ParameterError("real", f"{path.name}: only ATL06, ATL07 and ATL08 are trimmed "
                                 f"(it is {product})")
        for key in KEPT_GLOBAL:
            if key in f:
                g.create_dataset(key, data=f[key][()])
        for name in BEAM_NAMES:
            if name not in f:
                continue
            grp = g.create_group(name)
            for k, v in f[name].attrs.items():
                grp.attrs[k] = v
            for key in READ_DATASETS[product]:
                if key in f[name]:
                    src = f[name][key]
                    big = src.size > 4096          # small ones: contiguous, no chunk overhead
                    grp.create_dataset(key, data=src[()], **({"compression": "gzip",
                                       "compression_opts": 9, "shuffle": True} if big else {}))
                    for k, v in src.attrs.items():
                        if k not in ("DIMENSION_LIST", "REFERENCE_LIST", "CLASS", "NAME"):
                            grp[key].attrs[k] = v
    return out
