"""New groups of empty appendable datasets, copied by HDF5 from a template (issue 43).

A granule's ATL03 file makes ~750 datasets with ~4 300 attributes, its ATL06 ~215 with ~750,
the same ones for every beam and every granule: a beam's ``heights`` group is the same
twelve datasets, dtypes, chunks, filters, fill values and attributes each time, only its
rows differ. Made one by one (:func:`lidar_mitsuba.products.h5write.put` and
:func:`~lidar_mitsuba.products.h5write.set_attrs`) each dataset and attribute is a few HDF5
calls from Python. :func:`new_group` makes a group's datasets, with no rows, once per
process into an in-memory template file (HDF5's core driver, never written to disk), each
exactly as :func:`build` makes them in the file itself, and then copies the whole group into
each file that asks for it with one ``H5Ocopy`` (the objects and attributes copied in C, at
a tenth of the cost). The copies are registered with
:mod:`~lidar_mitsuba.products.h5write` as datasets it made, so the rows are appended with
``put(..., append=True)`` as before.

A template is keyed by everything that makes its objects (:class:`Spec`: each dataset's path,
dtype, row shape, fill value and attributes, in order), so a group that differs in any of
them (another dtype, a ``model_note``) gets a template of its own, and a copy holds the
very objects that :func:`build` would make (``tests/test_h5chunks.py`` and
``tests/test_granule.py`` compare every object and attribute, templates on and off).
``H5Ocopy`` does not carry object references (dimension scales' ``DIMENSION_LIST``,
``REFERENCE_LIST``) from one file to another, so templates hold none:
scales are attached in the file after the copy. :data:`TEMPLATES` ``False`` (the
environment's ``LIDAR_MITSUBA_H5_TEMPLATES=0``) makes every group with :func:`build`.
"""
from __future__ import annotations

import itertools
import os
from dataclasses import dataclass

import h5py
import numpy as np
from h5py import h5o

from . import h5write

#: make new groups by copying a template (``False``: make every object in the file itself)
TEMPLATES = os.environ.get("LIDAR_MITSUBA_H5_TEMPLATES", "1") != "0"


@dataclass(frozen=True)
class Spec:
    """One dataset of a new group: ``name`` its path in the group (``"fit_statistics/h_mean"``
    makes the subgroup), ``dtype`` (numpy dtype string), ``tail`` the shape of one row,
    ``fillvalue`` its HDF5 fill value (``None``: HDF5's default), ``attrs`` its attributes
    (name -> ``str`` or numpy value, as :func:`~lidar_mitsuba.products.h5write.set_attrs`
    takes them), ``units`` and ``description`` first."""
    name: str
    dtype: str
    tail: tuple
    fillvalue: object
    attrs: tuple               # ((name, value), ...): a dict's items, in order

    @staticmethod
    def of(name: str, dtype, tail: tuple, fillvalue, attrs: dict) -> "Spec":
        return Spec(name, np.dtype(dtype).str, tuple(tail), fillvalue, tuple(attrs.items()))

    def key(self) -> tuple:
        """What makes the dataset, hashable (numpy values as dtype, shape and bytes)."""
        fill = None if self.fillvalue is None else \
            np.asarray(self.fillvalue, self.dtype).tobytes()
        return (self.name, self.dtype, self.tail, fill,
                tuple((k, v if isinstance(v, str) else _value_key(v)) for k, v in self.attrs))


def _value_key(v) -> tuple:
    a = np.asarray(v)
    return (type(v).__name__, a.dtype.str, a.shape, a.tobytes())


def build(group, specs: list[Spec]) -> list:
    """Make ``specs``' datasets in ``group``, with no rows, as ``put(..., append=True)`` and
    ``set_attrs(..., new=True)`` make them. Returns the ``h5py.Dataset`` of each."""
    made = []
    for s in specs:
        sub, _, name = s.name.rpartition("/")
        g = group.require_group(sub) if sub else group
        attrs = dict(s.attrs)
        d = h5write.put(g, name, np.empty((0,) + s.tail, s.dtype), attrs.pop("units"),
                        attrs.pop("description"), append=True, fillvalue=s.fillvalue)
        h5write.set_attrs(d, attrs, new=True)
        made.append(d)
    return made


class _Template:
    """A group made once in the template file (``source``: its name there), and what
    :func:`lidar_mitsuba.products.h5write.register` needs of its datasets."""

    def __init__(self, source: bytes, specs: list[Spec], datasets: list):
        self.source = source
        self.paths = [s.name for s in specs]
        self.dtypes = [np.dtype(s.dtype) for s in specs]
        self.tails = [s.tail for s in specs]
        self.fills = [h5write._fill(s.fillvalue, s.dtype) for s in specs]
        self.levels = [h5write._level(d) for d in datasets]


_file: list = [None, None]      # the template file, the process that made it
_templates: dict = {}           # key of the specs -> _Template
_keyed: dict = {}               # a caller's key of its specs -> _Template (new_group's key)
_count = itertools.count()


def _template_file() -> h5py.File:
    """This process's template file (a forked child makes its own and its own templates)."""
    if _file[0] is None or _file[1] != os.getpid():
        _templates.clear()
        _keyed.clear()
        _file[:] = [h5py.File(f"lidar_mitsuba-templates-{os.getpid()}-{next(_count)}.h5", "w",
                              driver="core", backing_store=False), os.getpid()]
    return _file[0]


def _template(specs: list[Spec]) -> _Template:
    f = _template_file()
    key = tuple(s.key() for s in specs)
    t = _templates.get(key)
    if t is None:
        name = f"t{next(_count)}"
        t = _templates[key] = _Template(name.encode(), specs, build(f.create_group(name), specs))
        h5write.forget(f)                       # (the template's own entries)
    return t


def new_group(parent, name: str, specs, *, key=None):
    """``parent[name]``: a new group of ``specs``' datasets with no rows (intermediate groups
    made as ``require_group`` makes them), ready for ``put(..., append=True)``; the objects
    of :func:`build`, copied from a template when :data:`TEMPLATES`. ``specs``: a list of
    :class:`Spec`, or a function giving it; ``key``: the caller's hashable name for what
    makes the specs (the same key, the same specs), so that a template made once is found
    again without the specs being made and keyed (a group's ~12-40 specs and their keys cost
    ~0.3 ms)."""
    sub, _, leaf = name.rpartition("/")
    where = parent.require_group(sub) if sub else parent
    if not TEMPLATES:
        g = where.create_group(leaf)
        build(g, specs() if callable(specs) else specs)
        return g
    f = _template_file()
    t = None if key is None else _keyed.get(key)
    if t is None:
        t = _template(specs() if callable(specs) else specs)
        if key is not None:
            _keyed[key] = t
    h5o.copy(f.id, t.source, where.id, leaf.encode())
    g = where[leaf]
    h5write.register(g, t.paths, levels=t.levels, dtypes=t.dtypes, tails=t.tails,
                     fills=t.fills)
    return g


def put_group(parent, name: str, columns: list, *, key=None, group=None) -> tuple:
    """Append each column ``(path, data, units, description, attrs, fillvalue)`` to the
    dataset ``path`` of group ``parent[name]`` (``data``: rows along axis 0). A new group is
    made first (:func:`new_group`, with ``key``), each dataset of its column's dtype, row
    shape, fill value, ``units``, ``description`` and ``attrs`` (a dict, or a function giving
    it: asked for a new group only). ``group``: ``parent[name]`` when the caller holds it
    (not looked up). Returns ``(group, new)``."""
    new = group is None and name not in parent
    if new:
        g = new_group(parent, name, lambda: [_spec(c) for c in columns], key=key)
    else:
        g = parent[name] if group is None else group
    missing = h5write.append(g, [(c[0], c[1]) for c in columns])
    if missing:                    # (datasets a later section adds to an existing group)
        late = [c for c in columns if c[0] in missing]
        build(g, [_spec(c) for c in late])
        h5write.append(g, [(c[0], c[1]) for c in late])
    return g, new


def _spec(column) -> Spec:
    path, data, units, desc, attrs, fill = column
    attrs = attrs() if callable(attrs) else attrs
    return Spec.of(path, np.asarray(data).dtype, np.shape(data)[1:], fill,
                   {"units": units, "description": desc, **attrs})


__all__ = ["TEMPLATES", "Spec", "build", "new_group", "put_group"]
