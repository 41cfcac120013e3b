"""The ISO 19115 ``METADATA`` group of every product file we write (ATL03, ATL06; an ATL07 or
ATL08 writer calls :func:`write_metadata` the same way), laid out as NSIDC's granules carry it
(ATL03 v006, as in the real subset ``lidar_mitsuba/data`` ships; ATL06 v001, v003, v005; ATL07
v003: the same groups and attribute names)::

    METADATA/                     attrs Description
      DatasetIdentification       shortName, VersionID ("001": the file name's release),
                                  uuid, fileName, abstract, purpose, credit, ...
      SeriesIdentification        shortName, VersionID, longName, format, formatVersion, ...
      Extent                      rangeBeginningDateTime, rangeEndingDateTime (UTC) and
                                  south/north/west/eastBoundLatitude/Longitude [deg]
                                  (grown as beams are written: :func:`extend_extent`)
      AcquisitionInformation/     lidar, platform: the simulated instrument
      Lineage/SIM                 the simulation the data come from: software, version, its
                                  configuration (JSON); Lineage/<product> for a product made
                                  from another file of ours (an ATL06's ATL03)
      ProcessStep/PGE             software title and version, runTimeParameters (the JSON
                                  configuration), processDescription: "simulated"

**What readers parse and what says "simulated".** icepyx (``is2ref.extract_version``) and NSIDC's
tools take ``DatasetIdentification/VersionID`` as the product release, a number; it must equal
the release in the file name (``_006_02.h5``: "006"), so it is the file name's release
(:func:`release_of`), "001" for a file named otherwise (:data:`RELEASE`). Provenance lives
where a reader looks for it: ``Lineage`` (a real granule lists its inputs there: ATL02
telemetry and ancillary files; ours, the simulation), ``ProcessStep/PGE`` (real: the ASAS
PGE, its version and control file; ours: lidar_mitsuba, its version and the run's
configuration), ``identifier``/``credit``/``longName`` and the root ``title`` and
``description``. The identifiers are reproducible: ``uuid`` is a name-based UUID (RFC 4122
version 5) of the product, file name and configuration, and no creation time is written (a
real granule's ``creationDate`` and ``stepDateTime``), so the same run writes the same file.
"""
from __future__ import annotations

import json
import os
import re
import uuid

import numpy as np
from h5py import h5a

from .. import __version__

RELEASE = 1
"""The product release (``VersionID``) of a file whose name carries none: our first."""

_NAME = re.compile(r"(ATL\d\d)_(\d{14})_(\d{8})_(\d{3})_(\d{2})\.h5")
"""An ICESat-2 granule name (``ATL03_20190601123456_01230302_001_01.h5``, as
:func:`lidar_mitsuba.campaign.tracks.product_name` writes it), anywhere in a file's name."""

#: Our products' long names (real granules' ``SeriesIdentification/longName``) and what they hold
PRODUCTS = {
    "ATL03": ("ATLAS/ICESat-2 L2A Global Geolocated Photon Data",
              "latitude, longitude, height and time of every detected photon, with its truth "
              "in /truth"),
    "ATL06": ("ATLAS/ICESat-2 L3A Land Ice Height",
              "land-ice heights of 40 m segments every 20 m along each beam, fitted to the "
              "simulated photons and corrected for the first-photon bias"),
    "ATL07": ("ATLAS/ICESat-2 L3A Sea Ice Height",
              "sea-ice heights of fixed-photon-count segments along each beam"),
    "ATL08": ("ATLAS/ICESat-2 L3A Land and Vegetation Height",
              "terrain and canopy heights of 100 m segments along each beam"),
}


def release_of(path: str | os.PathLike) -> tuple[str, str]:
    """``(file name, VersionID)`` of a product file: the ICESat-2 granule name in ``path``'s
    name and its release (``"001"`` of ``..._001_01.h5``; a name held inside a temporary name,
    ``.ATL03_..._001_01.h5.part.h5``, counts), else the name as it is and :data:`RELEASE`."""
    name = os.path.basename(os.fspath(path))
    m = _NAME.search(name)
    if m is None:
        return name, f"{RELEASE:03d}"
    return m.group(0), m.group(4)


def product_uuid(short_name: str, file_name: str, config: dict) -> str:
    """A product file's ``uuid``: RFC 4122 version 5 (name-based) of its product, file name
    and configuration: the same run gives the same identifier, another file another."""
    key = f"lidar_mitsuba:{short_name}:{file_name}:{json.dumps(config, sort_keys=True)}"
    return str(uuid.uuid5(uuid.NAMESPACE_URL, key))


def write_metadata(f, *, short_name: str, path: str | os.PathLike, config: dict,
                   instruments: list, t_first: str | bytes, t_last: str | bytes,
                   process: str, inputs: dict[str, str | os.PathLike] | None = None) -> None:
    """Write ``f``'s ``METADATA`` group (module docstring) for product ``short_name`` (a key
    of :data:`PRODUCTS`) to be found at ``path`` (its name gives ``fileName`` and
    ``VersionID``: :func:`release_of`). ``config``: the run's configuration (JSON-able);
    ``instruments``: ``[(beam, instrument), ...]``; ``t_first``, ``t_last``: the first and last
    shot times, ISO 8601 UTC; ``process``: how the product was made from the simulation (one
    sentence); ``inputs``: ``{short name: path}`` of the files of ours it was made from, each
    a ``Lineage`` entry. ``Extent`` holds the times here and grows in latitude and longitude
    with :func:`extend_extent`."""
    long_name, content = PRODUCTS[short_name]
    file_name, version = release_of(path)
    cfg = json.dumps(config)
    m = f.create_group("METADATA")
    m.attrs["Description"] = "ISO19115 Structured Metadata Represented within HDF5"
    abstract = (f"Simulated ICESat-2 {short_name}: {content}. Not ATLAS data: a first-principles "
                f"Monte Carlo simulation by lidar_mitsuba {__version__}; the configuration is in "
                "Lineage/SIM and ProcessStep/PGE.")
    credit = f"simulated by lidar_mitsuba {__version__} (not NASA ICESat-2 data)"
    _set_attrs(m.create_group("DatasetIdentification"), _text({
        "shortName": short_name, "VersionID": version, "fileName": file_name,
        "uuid": product_uuid(short_name, file_name, config), "abstract": abstract,
        "purpose": f"simulated {long_name}", "language": "eng", "characterSet": "utf8",
        "spatialRepresentationType": "along-track", "topicCategory": "geoscientificInformation",
        "status": "onGoing", "originatorOrganizationName": "lidar_mitsuba (simulation)",
        "credit": credit}), new=True)
    _set_attrs(m.create_group("SeriesIdentification"), _text({
        "shortName": short_name, "VersionID": version, "longName": f"{long_name} (simulated)",
        "format": "HDF", "formatVersion": "5", "abstract": abstract, "credit": credit,
        "mission": "ICESat-2 (simulated by lidar_mitsuba)"}), new=True)
    _acquisition(m, instruments)
    lin = m.create_group("Lineage")
    _set_attrs(lin.create_group("SIM"), _text({
        "shortName": "SIM", "version": __version__, "fileName": file_name,
        "description": "simulated by lidar_mitsuba: photons traced by a first-principles Monte "
        "Carlo simulation (Mitsuba 3) through a modelled ATLAS detector, not ATL02 telemetry; "
        "runTimeParameters: the simulation's configuration (JSON)",
        "runTimeParameters": cfg}), new=True)
    for name, p in (inputs or {}).items():
        in_name, in_version = release_of(p)
        _set_attrs(lin.create_group(name), _text({
            "shortName": name, "version": in_version, "fileName": in_name,
            "uuid": product_uuid(name, in_name, config),
            "description": f"simulated {PRODUCTS[name][0]} of the same run (lidar_mitsuba)"}),
            new=True)
    _set_attrs(m.create_group("ProcessStep/PGE"), _text({
        "identifier": "lidar_mitsuba", "softwareTitle": "lidar_mitsuba (simulation)",
        "softwareVersion": __version__, "runTimeParameters": cfg,
        "processDescription": f"SIMULATED DATA. {process}"}), new=True)
    _set_attrs(m.create_group("Extent"), _text({"rangeBeginningDateTime": t_first,
                                                "rangeEndingDateTime": t_last}), new=True)


def _acquisition(m, instruments) -> None:
    """``AcquisitionInformation/{lidar,platform}``: the simulated instrument and spacecraft."""
    beams = ", ".join(f"{b.name} ({b.strength})" for b, _ in instruments)
    inst = instruments[0][1]
    acq = m.create_group("AcquisitionInformation")
    _set_attrs(acq.create_group("lidar"), _text({
        "identifier": "ATLAS (simulated)", "type": "Laser Altimeter",
        "wavelength": f"{inst.wavelength_nm:g} nm", "pulse_rate": f"{inst.prf_hz:g} pps",
        "description": f"simulated photon-counting lidar, beams {beams}"}), new=True)
    _set_attrs(acq.create_group("platform"), _text({
        "identifier": "ICESat-2 (simulated)", "type": "Spacecraft",
        "description": f"nadir-pointing, {inst.altitude_m / 1e3:g} km above the heights' datum"}),
        new=True)


def _set_attrs(obj, values: dict, *, new: bool = False) -> None:
    """:func:`lidar_mitsuba.products.h5write.set_attrs` (h5py's attributes' types, at a third
    of h5py's cost: a file's METADATA has ~60 attributes)."""
    from .h5write import set_attrs
    set_attrs(obj, values, new=new)


def _text(attrs: dict) -> dict:
    """Text attributes as fixed-length byte strings, as real granules store them (h5py reads
    them as ``bytes``, which icepyx and read-ICESat-2 decode)."""
    return {k: np.bytes_(v if isinstance(v, bytes) else str(v).encode()) for k, v in attrs.items()}


#: the bounds :func:`extend_extent` last wrote to each of the files it wrote last, by HDF5's
#: file number (never reused in a process): ``{fileno: {attribute: value}}``, oldest first
_BOUNDS: dict = {}
_BOUNDS_FILES = 8


def extend_extent(f, lat_deg, lon_deg) -> None:
    """Widen the file's latitude and longitude bounds (``METADATA/Extent`` and the root
    ``geospatial_*`` attributes) to take in these shots (longitudes as they are: a track
    across the antimeridian gets -180 to 180). Only the bounds that move are written again
    (the root's copy with each); the bounds written last are remembered (:data:`_BOUNDS`),
    else read back: a granule calls this once a section and file, and h5py's attribute
    objects cost ~1 ms a call."""
    if np.size(lat_deg) == 0:
        return
    g = f.require_group("METADATA/Extent")
    fileno = f.id.fileno
    known = _BOUNDS.pop(fileno, None)
    if known is None:
        known = {k: _float_attr(g, k) for k in _PICKS}
        known.update((copy, _float_attr(f, copy)) for copy in _COPIES.values())
    values = {"southBoundLatitude": np.min(lat_deg), "northBoundLatitude": np.max(lat_deg),
              "westBoundLongitude": np.min(lon_deg), "eastBoundLongitude": np.max(lon_deg)}
    extent, root = {}, {}
    for key, v in values.items():
        was, copy = known[key], _COPIES[key]
        now = np.float64(v if was is None else _PICKS[key](float(v), was))
        if was is None or now != was or known[copy] is None:
            extent[key] = root[copy] = now
            known[key] = known[copy] = float(now)
    for key, units in (("geospatial_lat_units", "degrees_north"),
                       ("geospatial_lon_units", "degrees_east")):
        if not known.get(key):
            if not h5a.exists(f.id, key.encode()):
                root[key] = units
            known[key] = True
    _set_attrs(g, extent)
    _set_attrs(f, root)
    _BOUNDS[fileno] = known
    while len(_BOUNDS) > _BOUNDS_FILES:
        del _BOUNDS[next(iter(_BOUNDS))]


_PICKS = {"southBoundLatitude": min, "northBoundLatitude": max, "westBoundLongitude": min,
          "eastBoundLongitude": max}
_COPIES = {"southBoundLatitude": "geospatial_lat_min", "northBoundLatitude":
           "geospatial_lat_max", "westBoundLongitude": "geospatial_lon_min",
           "eastBoundLongitude": "geospatial_lon_max"}


def _float_attr(obj, name: str) -> float | None:
    """The scalar float attribute ``name`` of ``obj`` (``None``: it has none)."""
    b = name.encode()
    if not h5a.exists(obj.id, b):
        return None
    out = np.empty((), np.float64)
    h5a.open(obj.id, b).read(out)
    return float(out)
