"""Sweep specs: loading a TOML spec (or a dict of its tables) with one-line errors naming the
key, and expanding it into tasks with their ids and seeds (see :mod:`lidar_mitsuba.sweep`)."""
from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import os
import pathlib
from dataclasses import dataclass, field

import numpy as np

from ..instrument import Instrument
from ..ground.surface import SurfaceSpec
from ..track import Track

_TERRAIN_STREAM = 0x54455252        # 'TERR': keeps the terrain seeds apart from photon seeds
FORMATS = ("parquet", "csv")
SWEEP_KEYS = ("name", "replicates", "seed", "format")
SECTIONS = ("sweep", "fixed", "grid", "list")
RUN_KEYS = ("shots", "seed", "paths_per_shot", "max_depth", "chunk_shots", "crop_to_track",
            "variant")


class SpecError(ValueError):
    """A bad spec: ``key`` names where (``[grid] p``), ``message`` says what."""

    def __init__(self, key: str, message: str):
        super().__init__(f"{key}: {message}")
        self.key, self.message = key, message


def parameter_names() -> dict[str, str]:
    """``{name: group}`` of every parameter a task takes (group: ``instrument``, ``surface``,
    ``track`` or ``run``); ``params.NAME`` (group ``xml``) is one of the XML's ``<default>``
    parameters."""
    out = {f.name: "instrument" for f in dataclasses.fields(Instrument)}
    out.update({("surface" if f.name == "kind" else f.name): "surface"
                for f in dataclasses.fields(SurfaceSpec)})
    out.update({f.name: "track" for f in dataclasses.fields(Track)})
    out.update({k: "run" for k in RUN_KEYS}, scene="run")
    return out


@dataclass(frozen=True)
class Spec:
    """A loaded spec (see the module docstring); ``where[name]`` is the section of a key."""
    name: str
    replicates: int = 1
    seed: int = 0
    format: str = "parquet"
    fixed: dict = field(default_factory=dict)
    grid: dict = field(default_factory=dict)
    list: list = field(default_factory=list)
    base_dir: str = "."
    where: dict = field(default_factory=dict)

    @property
    def parameters(self) -> list[str]:
        """Every parameter the spec names, in the order given."""
        return list(self.where)

    @property
    def swept(self) -> list[str]:
        """The parameters that take more than one value."""
        values = {k: {_key(e[k]) for e in self.list if k in e} for k in self.where}
        return [k for k in self.where if k in self.grid and len(self.grid[k]) > 1
                or self.where[k] == "[[list]]" and (len(values[k]) > 1 or any(
                    k not in e for e in self.list))]

    def to_dict(self) -> dict:
        return {"sweep": {"name": self.name, "replicates": self.replicates, "seed": self.seed,
                          "format": self.format},
                "fixed": self.fixed, "grid": self.grid, "list": self.list}


def _key(value) -> str:
    return json.dumps(value, sort_keys=True)


def _plain(value) -> bool:
    """A number, string, boolean or a list of them (what a parameter can be)."""
    if isinstance(value, list):
        return all(_plain(v) for v in value)
    return isinstance(value, (str, int, float, bool))


def _flatten(section: str, table: dict) -> dict:
    """``params = {a = 1}`` -> ``{"params.a": 1}``; other tables are refused."""
    out = {}
    for k, v in table.items():
        if isinstance(v, dict):
            if k != "params":
                raise SpecError(f"{section} {k}", "a table is only allowed for params (the "
                                "XML's <default> parameters)")
            out.update({f"params.{name}": value for name, value in v.items()})
        else:
            out[k] = v
    for k, v in out.items():
        if not _plain(v):
            raise SpecError(f"{section} {k}", f"must be a number, string, boolean or a list "
                            f"of them (got {v!r})")
    return out


def _check_names(section: str, table: dict, known: dict) -> None:
    import difflib
    for k in table:
        if k not in known and not (k.startswith("params.") and len(k) > 7):
            close = difflib.get_close_matches(k, list(known), n=1)
            hint = f"did you mean {close[0]}? " if close else ""
            raise SpecError(f"{section} {k}", f"unknown parameter ({hint}parameters are the "
                            "names of the Python API: the fields of Instrument, SurfaceSpec "
                            "(surface for its kind) and Track, simulate()'s "
                            f"{', '.join(RUN_KEYS)}; scene, params.NAME)")


def load_spec(source) -> Spec:
    """A :class:`Spec` from a TOML file, a dict of its tables, or a Spec (returned as is).
    A scene's path is relative to the file's folder (to the current folder for a dict).
    Raises :class:`SpecError` naming the key."""
    if isinstance(source, Spec):
        return source
    doc, base, name = _read_source(source)
    for k in doc:
        if k not in SECTIONS:
            raise SpecError(f"[{k}]", f"unknown section (known: {', '.join(SECTIONS)})")
    sw = _sweep_table(doc, name)
    fixed, grid, entries, where = _parameter_tables(doc)
    if not where and not entries:
        raise SpecError("spec", "no parameters: give [fixed], [grid] or [[list]]")
    if sw["replicates"] > 1 and "seed" in where and "terrain_seed" in where:
        raise SpecError("[sweep] replicates", "every replicate would be the same run: seed "
                        "and terrain_seed are both given (leave one out to vary it)")
    return Spec(**sw, fixed=fixed, grid=grid, list=entries, base_dir=str(base), where=where)


def _read_source(source) -> tuple[dict, pathlib.Path, str]:
    """:func:`load_spec`'s ``source`` as ``(tables, folder scenes are relative to, default
    name)``: a TOML file read and parsed, or a dict as is."""
    if isinstance(source, (str, os.PathLike)):
        path = pathlib.Path(source)
        try:
            import tomllib
        except ImportError:                              # Python 3.10
            import tomli as tomllib
        try:
            doc = tomllib.loads(path.read_text())
        except OSError as e:
            raise SpecError(str(path), f"cannot read ({e.strerror})") from None
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
            raise SpecError(str(path), f"not valid TOML ({e})") from None
        return doc, path.resolve().parent, path.stem
    if isinstance(source, dict):
        return source, pathlib.Path("."), "sweep"
    raise SpecError("spec", f"must be a TOML file, a dict or a Spec (got "
                    f"{type(source).__name__})")


def _sweep_table(doc: dict, name: str) -> dict:
    """The checked ``[sweep]`` table as :class:`Spec` fields: ``name`` (default ``name``),
    ``replicates``, ``seed`` and ``format``."""
    sw = doc.get("sweep", {})
    if not isinstance(sw, dict):
        raise SpecError("[sweep]", "must be a table")
    for k in sw:
        if k not in SWEEP_KEYS:
            raise SpecError(f"[sweep] {k}", f"unknown key (known: {', '.join(SWEEP_KEYS)})")
    name = sw.get("name", name)
    if not isinstance(name, str) or not name:
        raise SpecError("[sweep] name", f"must be a non-empty string (got {name!r})")
    for k, lo in (("replicates", 1), ("seed", 0)):
        v = sw.get(k, lo)
        if not isinstance(v, int) or isinstance(v, bool) or not lo <= v < 2 ** 63:
            raise SpecError(f"[sweep] {k}", f"must be an integer >= {lo} (got {v!r})")
    fmt = sw.get("format", "parquet")
    if fmt not in FORMATS:
        raise SpecError("[sweep] format", f"must be one of {', '.join(FORMATS)} (got {fmt!r})")
    return dict(name=name, replicates=sw.get("replicates", 1), seed=sw.get("seed", 0),
                format=fmt)


def _parameter_tables(doc: dict) -> tuple[dict, dict, list[dict], dict[str, str]]:
    """The checked ``[fixed]``, ``[grid]`` and ``[[list]]`` tables, flattened (``params.NAME``
    keys), and the section each parameter is given in: ``(fixed, grid, entries, where)``.
    Refuses unknown names, a parameter in two sections, an empty or repeating grid and
    repeated entries."""
    known = parameter_names()
    fixed = doc.get("fixed", {})
    grid = doc.get("grid", {})
    entries = doc.get("list", [])
    if not isinstance(fixed, dict) or not isinstance(grid, dict):
        raise SpecError("[fixed]" if not isinstance(fixed, dict) else "[grid]", "must be a table")
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise SpecError("[[list]]", "must be an array of tables ([[list]] entries)")
    fixed, grid = _flatten("[fixed]", fixed), _flatten("[grid]", grid)
    entries = [_flatten("[[list]]", e) for e in entries]
    where: dict[str, str] = {}
    for section, tables in (("[fixed]", [fixed]), ("[grid]", [grid]), ("[[list]]", entries)):
        for table in tables:
            _check_names(section, table, known)
            for k in table:
                if where.setdefault(k, section) != section:
                    raise SpecError(f"{section} {k}", f"is also given in {where[k]}: give a "
                                    "parameter in one section")
    for k, values in grid.items():
        if not isinstance(values, list) or not values:
            raise SpecError(f"[grid] {k}", f"must be a non-empty list of values (got {values!r})")
        keys = [_key(v) for v in values]
        if len(set(keys)) < len(keys):
            raise SpecError(f"[grid] {k}", f"repeats a value ({values!r})")
    keys = [_key(e) for e in entries]
    if len(set(keys)) < len(keys):
        i = next(i for i, k in enumerate(keys) if keys.index(k) < i)
        raise SpecError("[[list]]", f"entry {i + 1} repeats entry {keys.index(keys[i]) + 1}")
    return fixed, grid, entries, where


@dataclass(frozen=True)
class Task:
    """One run of a sweep (what is sent to a worker, as a dict)."""
    task_id: str
    task_index: int
    replicate: int
    parameters: dict
    seed: int
    terrain_seed: int
    base_dir: str


def task_id(parameters: dict, replicate: int, sweep_seed: int) -> str:
    doc = {"parameters": parameters, "replicate": replicate, "sweep_seed": sweep_seed}
    return hashlib.sha256(_key(doc).encode()).hexdigest()[:16]


def expand(spec) -> list[Task]:
    """The tasks of a spec, in order: list entries x grid points x replicates."""
    spec = load_spec(spec)
    names = list(spec.grid)
    tasks = []
    for entry in spec.list or [{}]:
        for point in itertools.product(*(spec.grid[k] for k in names)):
            params = {**spec.fixed, **entry, **dict(zip(names, point))}
            for r in range(spec.replicates):
                tid = task_id(params, r, spec.seed)
                seed = params.get("seed", int(np.random.SeedSequence(
                    [spec.seed, int(tid, 16)]).generate_state(1)[0]))
                terrain = params.get("terrain_seed", int(np.random.SeedSequence(
                    [spec.seed, _TERRAIN_STREAM, r]).generate_state(1)[0]))
                tasks.append(Task(tid, len(tasks), r, params, seed, terrain, spec.base_dir))
    return tasks
