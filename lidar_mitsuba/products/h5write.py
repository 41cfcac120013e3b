"""Compressed HDF5 datasets whose chunks are compressed on every core.

HDF5 runs a dataset's filters (here byte shuffle, then deflate) in the writing thread, one
chunk after another. At gzip level 1 one core of the 2-core VM deflates photon floats at about
45 MB/s, so writing a granule's ATL03 heights and truth took ~0.9 s per 100 km of one strong
beam, more than the whole trace. :func:`put` instead cuts the rows it writes into the
dataset's chunks, shuffles and deflates each whole chunk on the host's thread pool (the
deflater releases the GIL, so the pool runs beside the simulation too), and stores it with
``H5Dwrite_chunk`` (h5py's ``write_direct_chunk``), bypassing the filter pipeline. HDF5's
shuffle is the byte-plane transpose of the chunk and its deflate filter stores a zlib stream;
the deflater is ISA-L's (``isal.isal_zlib`` at :data:`ISAL_LEVEL`: 6-10x faster than zlib at
level 1, and within a few per cent of its size), or zlib at the dataset's level where ISA-L
is not installed. Either stream inflates to the very bytes HDF5's pipeline would have
compressed, so every HDF5 reader decodes the same values with the standard filters the
dataset declares (``tests/test_h5chunks.py``); only the compressed bytes differ from zlib's.

The whole chunks one append completes are compressed as one job of the pool (a job per
chunk cost more in futures and locks than ISA-L took on a small chunk), and at
:func:`drain` the waiting rows of :data:`DRAIN_BATCH` datasets make a job; a job of at most
:data:`INLINE_BYTES` (a header's one-row datasets) is compressed in the calling thread. The
shuffle of 2-, 4- and 8-byte elements is compiled (:mod:`lidar_mitsuba.products.h5kernels`:
the same bytes as numpy's transposed copy, ~8x faster).

Rows that do not fill a chunk wait in memory (one partial chunk per dataset) for the next
append of the same dataset, so a granule streamed section by section never has HDF5 read back,
merge and recompress a chunk; :func:`drain` stores them, padded beyond the dataset's extent
with its fill value, as HDF5 pads an edge chunk. The compressed chunks are stored by the
calling thread in the order they were cut: the finished ones at every later :func:`put`, all
once more than :data:`MAX_PENDING_BYTES` of rows wait, the rest at :func:`drain`, which
:func:`lidar_mitsuba.products.atl03.atomic_h5file` calls before it closes a file (and :func:`discard`
when the write fails); until then a dataset's last rows read as its fill value, and its extent
in the file may lag its rows (an appended dataset's extent is set only when needed, and at
:func:`drain`; :func:`rows` gives its rows). Datasets with any other filter pipeline, and rows
that begin a chunk HDF5 wrote, go through HDF5 as usual.
Writers are expected on one thread (the pool only compresses).
"""
from __future__ import annotations

import collections
import concurrent.futures
import sys
import threading
import zlib

import h5py
import numpy as np
from h5py import h5a, h5d, h5f, h5s, h5t

try:
    from isal import isal_zlib as _isal
except ImportError:        # (a platform without its wheel: zlib, slower)
    _isal = None

from . import h5kernels
from ..machine import host_pool

#: rows per chunk along axis 0 of the datasets :func:`put` creates (a (n, k) dataset's chunk
#: is (CHUNK_ROWS, k))
CHUNK_ROWS = 16384
#: gzip (deflate) level of the datasets :func:`put` creates; 1 is the fastest
GZIP_LEVEL = 1
#: ISA-L's deflate level (0-3) of the chunks :func:`put` compresses itself
ISAL_LEVEL = 2
#: bytes of uncompressed rows allowed to wait for compression before :func:`put` blocks
MAX_PENDING_BYTES = 256 * 2 ** 20
#: chunks of at most this many bytes (a job's, padded) are compressed in the calling thread:
#: a pool job (its future, lock and wake-up, ~30-50 us of CPU) costs more than ISA-L takes on
#: them (~1 GB/s here: ~4 us a 4 KiB job). ESTIMATE: the break-even, not measured finely; a
#: granule's header datasets (~120 a granule, a few to a few hundred bytes) fall under it
INLINE_BYTES = 4096

_H5Z_FILTER_DEFLATE, _H5Z_FILTER_SHUFFLE = 1, 2
_LITTLE = sys.byteorder == "little"     # (the compiled shuffle reads words as this host's)
_lock = threading.Lock()
_pending: collections.deque = collections.deque()  # (file key, [(dataset, offset)], future
                                                    # of their compressed chunks, bytes)
_queued = [0]                                        # bytes of rows in _pending
_tails: dict = {}     # (file key, dataset name) -> (dataset, first row, rows, level, chunk
                      # rows, fill value, its _Entry or None)
_open: dict = {}            # (HDF5 file number, dataset name) -> _Entry of put(append=True)
_made: dict = {}            # what a new dataset is made of -> (HDF5 type, creation plist, level)


def put(group, name: str, data, units: str, description: str, *, append: bool = False,
        fillvalue=None):
    """Write ``data`` as dataset ``group[name]`` (attributes ``units`` and ``description``),
    or with ``append=True`` add its rows after those of an existing one. ``fillvalue``: the
    new dataset's HDF5 fill value (what pads its last chunk).

    A new dataset of ``ndim >= 1`` is chunked along axis 0 (:data:`CHUNK_ROWS` rows, fewer
    for a short array that will not grow), byte-shuffled and gzip-compressed at
    :data:`GZIP_LEVEL`, and resizable along axis 0 when ``append`` is set. A scalar is stored
    as is. Returns the ``h5py.Dataset``. Its rows are stored in the background: call
    :func:`drain` before closing the file (``atomic_h5file`` does).
    """
    data = np.asarray(data)
    if data.ndim == 0:
        d = group.create_dataset(name, data=data)
    elif append:
        key = (group.id.fileno, f"{group.name}/{name}")
        entry = _open.get(key)
        if entry is not None and not entry.dset.id.valid:   # (a file closed without drain)
            entry = None
        if entry is None and name in group:         # a dataset this module did not make
            entry = _open[key] = _Entry(group[name])
        if entry is not None:
            start = entry.rows
            entry.grow(data.shape[0])
            entry.write(start, data)
            return entry.dataset()
        d, level = _create(group, name, data, CHUNK_ROWS, fillvalue)
        path = key[1] if not key[1].startswith("//") else key[1][1:]     # (d.name)
        entry = _open[key] = _Entry(d, level=level, key=(_file_key(group), path),
                                    shape=(0,) + data.shape[1:], dtype=data.dtype,
                                    chunk_rows=CHUNK_ROWS, fill=_fill(fillvalue, data.dtype))
        entry.grow(data.shape[0])
        entry.write(0, data)
    else:                   # (its level, chunk rows and fill value known: not asked of HDF5)
        rows = max(1, min(CHUNK_ROWS, data.shape[0]))
        d, level = _create(group, name, data, rows, fillvalue)
        d.id.set_extent(data.shape)
        if level is None:
            write_rows(d, 0, data)
        else:
            _write(d, 0, data, dtype=d.dtype, level=level, key=(_file_key(d), d.name),
                   chunk_rows=rows, fill=_fill(fillvalue, d.dtype))
    set_attrs(d, {"units": units, "description": description}, new=True)
    return d


def _create(group, name, data, rows, fillvalue):
    """A new empty chunked dataset ``group[name]`` for rows like ``data``, and its deflate
    level (:func:`_level`). The first of a kind (dtype, row shape, chunk rows, fill value) is
    made by h5py; the later ones with HDF5's own call and the first one's type and creation
    property list (the same dataset, at a fifth of h5py's cost per dataset)."""
    tail = data.shape[1:]
    kind = (data.dtype.str, tail, rows, None if fillvalue is None else
            np.asarray(fillvalue, data.dtype).tobytes())
    made = _made.get(kind)
    if made is None:
        d = group.create_dataset(name, shape=(0,) + tail, dtype=data.dtype,
                                 maxshape=(None,) + tail, chunks=(rows,) + tail,
                                 compression="gzip", compression_opts=GZIP_LEVEL,
                                 shuffle=True, fillvalue=fillvalue)
        made = _made[kind] = (d.id.get_type(), d.id.get_create_plist(), _level(d))
        return d, made[2]
    tid, dcpl, level = made
    space = h5s.create_simple((0,) + tail, (h5s.UNLIMITED,) + tail)
    return h5py.Dataset(h5d.create(group.id, name.encode(), tid, space, dcpl=dcpl)), level


def set_attrs(obj, values: dict, *, new: bool = False) -> None:
    """Set the attributes ``values`` (name -> value) of the HDF5 object ``obj``, as
    ``obj.attrs[name] = value`` does (an existing one replaced): a ``str`` as a scalar
    variable-length UTF-8 string, a numeric or fixed-length byte string numpy array or scalar
    with its dtype and shape. These go straight to HDF5 with
    types and dataspaces made once (h5py's own path costs ~3x more per attribute, and an ATL03
    granule has ~4 600); any other value through h5py. ``new``: ``obj`` was just made and has
    none of them (none is looked for)."""
    oid = obj.id
    for name, value in values.items():
        if isinstance(value, str):
            data, (htype, mtype) = np.array(value, dtype=_STR), _str_types()
        elif isinstance(value, (np.ndarray, np.generic)) and value.dtype.kind in "biufS":
            data = np.asarray(value, order="C")      # (a 0-d array stays 0-d)
            htype, mtype = _num_types(data.dtype)
        else:
            obj.attrs[name] = value
            continue
        b = name.encode()
        if not new and h5a.exists(oid, b):
            h5a.delete(oid, b)
        space = _spaces.get(data.shape)
        if space is None:
            space = _spaces[data.shape] = h5s.create_simple(data.shape)
        attr = h5a.create(oid, b, htype, space)
        try:
            attr.write(data, mtype=mtype)
        finally:
            attr.close()


_STR = h5py.string_dtype()
_types: dict = {}
_spaces: dict = {}          # shape -> HDF5 dataspace of an attribute (H5Acreate copies it)


def _str_types():
    """(file type, memory type) of a str attribute: what h5py makes for one."""
    if "str" not in _types:
        _types["str"] = (h5t.py_create(_STR, logical=True), h5t.py_create(_STR))
    return _types["str"]


def _num_types(dtype):
    if dtype.str not in _types:
        _types[dtype.str] = (h5t.py_create(dtype, logical=True), h5t.py_create(dtype))
    return _types[dtype.str]


class _Bare:
    """A dataset's HDF5 id where h5py's object is not needed (:func:`register`'s: an
    ``h5py.Dataset`` costs ~35 us to make, its transfer property list among it); h5py's
    object is made only to write rows through HDF5 (rare: a chunk begun by HDF5)."""
    __slots__ = ("id",)

    def __init__(self, did):
        self.id = did

    def __setitem__(self, index, value):
        h5py.Dataset(self.id)[index] = value


class _Entry:
    """A dataset :func:`put` appends to, with what each append needs: its rows so far, dtype,
    filters and file. (h5py's lookup of a dataset by name, and of its shape, chunks and
    filters, cost tens of microseconds each; a granule's ATL03 makes thousands of appends.)

    Its extent in the file (``extent``) follows its rows (``rows``) lazily: an append only
    counts them, and HDF5's extent is set (:meth:`sync`) before HDF5 writes rows or stores a
    chunk beginning at or beyond it, and at :func:`drain`: once a dataset per few chunks
    instead of once per append (a granule's ~2 700 ``H5Dset_extent`` calls)."""

    __slots__ = ("dset", "rows", "extent", "tail_shape", "dtype", "level", "key", "chunk_rows",
                 "fill")

    def __init__(self, dset, *, level=..., key=None, shape=None, dtype=None, chunk_rows=None,
                 fill=None):
        self.dset = dset
        shape = dset.shape if shape is None else shape     # (known for a dataset just made)
        self.rows = self.extent = shape[0]
        self.tail_shape = shape[1:]
        self.dtype = dset.dtype if dtype is None else np.dtype(dtype)
        self.level = _level(dset) if level is ... else level
        self.key = (_file_key(dset), dset.name) if key is None else key
        self.chunk_rows, self.fill = chunk_rows, fill     # (None: asked of HDF5 when needed)

    def grow(self, n: int) -> None:
        self.rows += n

    def dataset(self) -> h5py.Dataset:
        """The dataset, as h5py's object."""
        d = self.dset
        return d if isinstance(d, h5py.Dataset) else h5py.Dataset(d.id)

    def sync(self) -> None:
        """Set the dataset's extent in the file to its rows."""
        if self.extent != self.rows:
            self.dset.id.set_extent((self.rows,) + self.tail_shape)
            self.extent = self.rows

    def write(self, start: int, data, *, chunks: list | None = None) -> None:
        """Rows ``start ..`` (:func:`_write`; ``chunks``: where their whole chunks go)."""
        if self.level is not None and self.chunk_rows is None:
            self.chunk_rows, self.fill = self.dset.chunks[0], self.dset.fillvalue
        _write(self.dset, start, data, dtype=self.dtype, level=self.level, key=self.key,
               chunk_rows=self.chunk_rows, fill=self.fill, entry=self, out=chunks)


def _fill(fillvalue, dtype) -> np.ndarray:
    """The value HDF5 pads a chunk with: ``fillvalue``, or zero bytes where none is set."""
    if fillvalue is None:
        return np.zeros((), dtype)
    return np.asarray(fillvalue, dtype)


def register(group, paths: list, *, levels: list, dtypes: list, tails: list,
             fills: list) -> None:
    """Take the new datasets ``group[path]`` (empty, made as ``put(..., append=True)`` makes
    them; ``levels``: each one's :func:`_level`, ``fills`` its fill value) as datasets
    :func:`put` made, so their rows are appended the same way
    (:mod:`lidar_mitsuba.products.h5template` copies them)."""
    fileno, gname, fkey, gid = group.id.fileno, group.name, _file_key(group), group.id
    for path, level, dtype, tail, fill in zip(paths, levels, dtypes, tails, fills):
        name = f"{gname}/{path}"
        d = _Bare(h5d.open(gid, path.encode()))
        _open[(fileno, name)] = _Entry(d, level=level, key=(fkey, name.replace("//", "/", 1)),
                                       shape=(0,) + tuple(tail), dtype=dtype,
                                       chunk_rows=CHUNK_ROWS, fill=fill)


def append(group, columns: list) -> list:
    """Append each ``(path, data)`` of ``columns`` to the dataset ``group[path]`` (one
    :func:`put` made, or :func:`register` took), as ``put(..., append=True)`` does. Returns
    the paths of those that do not exist (nothing appended to them)."""
    fileno, gname = group.id.fileno, group.name
    missing, chunks, fkey = [], [], None
    for path, data in columns:
        data = np.asarray(data)
        entry = _open.get((fileno, f"{gname}/{path}"))
        if entry is None or not entry.dset.id.valid:
            sub, _, leaf = path.rpartition("/")
            g = group[sub] if sub else group
            if leaf in g:
                put(g, leaf, data, "", "", append=True)    # (an existing one: no attributes)
            else:
                missing.append(path)
            continue
        start = entry.rows
        entry.grow(data.shape[0])
        entry.write(start, data, chunks=chunks)
        fkey = entry.key[0]
    if chunks:            # (the whole chunks of every dataset: one pool job, as one append's)
        _submit(fkey, chunks)
        _store(block_above=MAX_PENDING_BYTES)
    return missing


def dataset_id(fileno: int, path: str):
    """``(HDF5 id, row shape)`` of the open dataset at ``path`` (its full name) of the file
    numbered ``fileno`` (``group.id.fileno``) that :func:`put` or :func:`register` made, or
    ``None``."""
    entry = _open.get((fileno, path))
    if entry is None or not entry.dset.id.valid:
        return None
    return entry.dset.id, entry.tail_shape


def rows(group, path: str) -> int:
    """The rows of dataset ``group[path]``: appended so far (:func:`put`, :func:`append`:
    their extent in the file may lag until :func:`drain`), else its extent; 0 if it does not
    exist."""
    entry = _open.get((group.id.fileno, f"{group.name}/{path}"))
    if entry is not None and entry.dset.id.valid:
        return entry.rows
    return group[path].shape[0] if path in group else 0


def forget(f) -> None:
    """Forget the datasets :func:`put` made in file ``f`` (it holds no waiting rows)."""
    _forget(_file_key(f))


def write_rows(dset, start: int, data) -> None:
    """Store ``data`` in rows ``start`` to ``start + len(data)`` of the chunked dataset
    ``dset`` (already that long). When ``dset`` is byte shuffle then deflate and nothing else,
    whole chunks are compressed on the pool and a last partial chunk waits for the next rows
    (or :func:`drain`); otherwise HDF5 writes the rows now."""
    level = _level(dset)
    _write(dset, start, data, dtype=dset.dtype, level=level, key=(_file_key(dset), dset.name),
           chunk_rows=dset.chunks[0] if level is not None else None,
           fill=dset.fillvalue if level is not None else None)


def _level(dset) -> int | None:
    """The deflate level of whole chunks :func:`_write` compresses itself (``None``: HDF5
    writes the rows)."""
    level = _shuffle_deflate_level(dset)                 # (None: not chunked and filtered)
    return level if level is not None and dset.chunks[1:] == dset.shape[1:] else None


def _write(dset, start: int, data, *, dtype, level, key, chunk_rows, fill,
           entry=None, out: list | None = None) -> None:
    """Rows ``start ..`` of ``dset`` (``chunk_rows`` a chunk, padded with ``fill``): the
    whole chunks they complete compressed on the pool as one job, the rest held. ``entry``:
    its :class:`_Entry` (whose extent is set before HDF5 writes), if it has one. ``out``: a
    list the whole chunks are added to instead (the caller queues them: :func:`append`'s
    datasets' chunks make one pool job, as the chunks of one dataset's append do)."""
    data = np.ascontiguousarray(data, dtype=dtype)
    held = _tails.pop(key, None)
    if held is not None and held[1] + held[2].shape[0] != start:   # (rows written around us)
        _submit(key[0], [held])
        held = None
    stop = start + data.shape[0]
    if level is None:
        if stop > start:
            if entry is not None:
                entry.sync()
            dset[start:stop] = data
        return
    rows, chunks = chunk_rows, []
    if held is not None:       # the waiting rows begin a chunk: these rows continue it
        head = data[:rows - held[2].shape[0]]
        start, data = start + head.shape[0], data[head.shape[0]:]
        whole = (dset, held[1], np.concatenate([held[2], head]), level, rows, fill, entry)
        if whole[2].shape[0] < rows:                   # (still short of a chunk)
            _tails[key] = whole
            return
        chunks.append(whole)
    a = -(-start // rows) * rows                       # first chunk boundary at or after start
    if start < a:                                      # a chunk begun by someone else
        if entry is not None:
            entry.sync()
        dset[start:min(a, stop)] = data[:a - start]
    for c0 in range(a, stop - rows + 1, rows):
        chunks.append((dset, c0, data[c0 - start:c0 - start + rows], level, rows, fill, entry))
    b = max(a, stop // rows * rows)
    if b < stop:
        _tails[key] = (dset, b, data[b - start:].copy(), level, rows, fill, entry)
    if out is not None:
        out.extend(chunks)
        return
    _submit(key[0], chunks)
    _store(block_above=MAX_PENDING_BYTES)


#: waiting rows of this many datasets compressed as one job of the pool at :func:`drain`
#: (a choice, not a measurement: a six-beam granule's ~870 held chunks make ~28 jobs, enough
#: to keep every pool thread busy, each job ~2-3 MB of rows)
DRAIN_BATCH = 32


def drain(f) -> None:
    """Store the rows waiting for file ``f`` (the ``h5py.File`` about to close), and every
    compressed chunk still queued."""
    key = _file_key(f)
    held = [_tails.pop(k) for k in [k for k in _tails if k[0] == key]]
    for i in range(0, len(held), DRAIN_BATCH):
        _submit(key, held[i:i + DRAIN_BATCH])
    _store(block_above=0)
    for entry in list(_open.values()):           # every extent, once
        if entry.key[0] == key and entry.dset.id.valid:
            entry.sync()
    _forget(key)


def discard(f) -> None:
    """Forget the rows and chunks waiting for file ``f`` (its write failed); those of other
    open files are kept."""
    key = _file_key(f)
    for k in [k for k in _tails if k[0] == key]:
        del _tails[k]
    _forget(key)
    with _lock:
        keep = [e for e in _pending if e[0] != key]
        for e in _pending:
            if e[0] == key:
                e[2].cancel()
        _pending.clear()
        _pending.extend(keep)
        _queued[0] = sum(e[3] for e in keep)


def _submit(file_key: bytes, chunks: list) -> None:
    """Queue ``chunks`` of the file ``file_key`` names for compression, as one job of the
    pool: each ``(dataset, first row, rows, level, chunk rows, fill value, _Entry or None)``,
    ``rows`` all of the chunk or its first rows (then padded with the fill value to ``chunk
    rows``)."""
    if not chunks:
        return
    nbytes = sum(c[4] * (c[2].nbytes // c[2].shape[0]) for c in chunks)
    if nbytes <= INLINE_BYTES:         # (a pool job costs more than these bytes' deflate)
        future = concurrent.futures.Future()
        future.set_result(_encode_chunks([c[2:6] for c in chunks]))
    else:
        future = host_pool().submit(_encode_chunks, [c[2:6] for c in chunks])
    places = [(c[0], (c[1],) + (0,) * (c[2].ndim - 1), c[6]) for c in chunks]
    with _lock:
        _pending.append((file_key, places, future, nbytes))
        _queued[0] += nbytes


def _encode_chunks(chunks: list) -> list:
    """Each ``(rows, level, chunk rows, fill value)``, padded to a whole chunk, as HDF5's
    shuffle and deflate filters store it (:func:`_encode`)."""
    out = []
    for rows, level, n, fill in chunks:
        if rows.shape[0] < n:
            rows = np.concatenate([rows, np.full((n - rows.shape[0],) + rows.shape[1:],
                                                 fill, rows.dtype)])
        out.append(_encode(rows, level))
    return out


def _store(*, block_above: int) -> None:
    """Write the compressed chunks at the head of the queue: those done, and, waiting for
    them, as many more as bring the rows still queued to ``block_above`` bytes or fewer."""
    while True:
        with _lock:
            if not _pending:
                return
            key, places, future, nbytes = _pending[0]
            if not future.done() and _queued[0] <= block_above:
                return
            _pending.popleft()
            _queued[0] -= nbytes
        for (dset, offset, entry), blob in zip(places, future.result()):
            if entry is not None and entry.extent <= offset[0]:   # (the chunk within it)
                entry.sync()
            dset.id.write_direct_chunk(offset, blob)


def _encode(piece: np.ndarray, level: int) -> bytes:
    """One whole chunk as HDF5's shuffle and deflate filters store it."""
    size = piece.dtype.itemsize
    planes = piece.reshape(-1).view(np.uint8)
    if size in h5kernels.SIZES and _LITTLE:     # byte i of every element together (HDF5's
        out = np.empty_like(planes)             # shuffle filter), a word at a time
        h5kernels.shuffle(planes, size, out)
        planes = out
    elif size > 1:
        planes = np.ascontiguousarray(planes.reshape(-1, size).T)
    if _isal is not None:
        return _isal.compress(planes, ISAL_LEVEL)
    return zlib.compress(planes, level)


def _shuffle_deflate_level(dset) -> int | None:
    """The deflate level when ``dset``'s filters are exactly shuffle then deflate, else None."""
    plist = dset.id.get_create_plist()
    if plist.get_nfilters() != 2:
        return None
    codes = [plist.get_filter(i)[0] for i in range(2)]
    if codes != [_H5Z_FILTER_SHUFFLE, _H5Z_FILTER_DEFLATE]:
        return None
    values = plist.get_filter(1)[2]
    return int(values[0]) if values else None


def _forget(file_key: bytes) -> None:
    """Drop the appended datasets of the file ``file_key`` names (it is about to close)."""
    for k in [k for k, e in list(_open.items()) if e.key[0] == file_key]:
        del _open[k]


def _file_key(obj) -> bytes:
    """The name of the file holding the HDF5 object ``obj`` (a file, group or dataset)."""
    return h5f.get_name(obj.id)


__all__ = ["CHUNK_ROWS", "GZIP_LEVEL", "MAX_PENDING_BYTES", "put", "write_rows", "drain",
           "discard", "set_attrs", "register", "append", "rows", "dataset_id", "forget"]
