"""Chunks compressed on the thread pool (lidar_mitsuba.products.h5write) against HDF5's own filters."""
import h5py
import numpy as np
import pytest

from lidar_mitsuba.products import atl03, h5write as h5chunks

C = h5chunks.CHUNK_ROWS


def _appended(path, parts, name="a"):
    with atl03.atomic_h5file(path) as f:
        for p in parts:
            h5chunks.put(f, name, p, "m", "test", append=True)


@pytest.mark.parametrize("dtype,cols", [(np.float64, None), (np.float32, None), (np.int8, 5),
                                        (np.uint32, None), (np.int64, 3), ("S3", None)])
def test_appended_rows_read_back_exactly(tmp_path, rng, dtype, cols):
    """Appends of every kind of length (empty, shorter than a chunk, exactly one, crossing
    several boundaries) read back as their concatenation."""
    lengths = (0, 100, C - 100, C, 5, 3 * C + 17, 1, 2 * C - 1, 0, C + 1)
    shape = lambda n: (n,) if cols is None else (n, cols)     # noqa: E731
    parts = [(rng.normal(size=shape(n)) * 1e3).astype(np.int64).astype(dtype) for n in lengths]
    path = tmp_path / "a.h5"
    _appended(path, parts)
    with h5py.File(path) as f:
        d = f["a"]
        assert d.compression == "gzip" and d.compression_opts == h5chunks.GZIP_LEVEL
        assert d.shuffle and d.chunks[0] == C
        np.testing.assert_array_equal(d[:], np.concatenate(parts))
        assert d.attrs["units"] == "m"


def test_chunks_inflate_to_the_bytes_hdf5_compresses(tmp_path, rng):
    """Every chunk compressed on the pool, the edge chunk padded at drain included, is a zlib
    stream (ISA-L's, or zlib's) that inflates to the very bytes HDF5's filter pipeline
    (shuffle, then deflate) compresses for the same rows, with no filter skipped; and HDF5's
    own filters read it back."""
    import zlib
    data = 3.3e6 + rng.normal(0, 5, 3 * C + 500)
    ours, theirs = tmp_path / "ours.h5", tmp_path / "theirs.h5"
    _appended(ours, [data[:10], data[10:C + 7], data[C + 7:]])
    with h5py.File(theirs, "w") as g:
        g.create_dataset("a", data=data, chunks=(C,), maxshape=(None,), compression="gzip",
                         compression_opts=h5chunks.GZIP_LEVEL, shuffle=True)
    with h5py.File(ours) as f, h5py.File(theirs) as g:
        for k in range(4):
            mask_f, bytes_f = f["a"].id.read_direct_chunk((k * C,))
            mask_g, bytes_g = g["a"].id.read_direct_chunk((k * C,))
            assert mask_f == mask_g == 0
            assert zlib.decompress(bytes_f) == zlib.decompress(bytes_g)
        np.testing.assert_array_equal(f["a"][:], data)
    if h5chunks._isal is not None:            # ISA-L: within 20 % of zlib's size
        size = lambda h: sum(len(h["a"].id.read_direct_chunk((k * C,))[1])  # noqa: E731
                             for k in range(4))
        with h5py.File(ours) as f, h5py.File(theirs) as g:
            assert size(f) < 1.2 * size(g)


def test_other_filter_pipelines_are_left_to_hdf5(tmp_path, rng):
    """A dataset with another pipeline (deflate without shuffle, or none) is written by HDF5."""
    data = rng.normal(size=2 * C + 3)
    with atl03.atomic_h5file(tmp_path / "b.h5") as f:
        for name, kw in (("gz", dict(compression="gzip")), ("raw", {})):
            d = f.create_dataset(name, shape=(data.size,), dtype=data.dtype, chunks=(C,), **kw)
            h5chunks.write_rows(d, 0, data)
        assert not h5chunks._pending
    with h5py.File(tmp_path / "b.h5") as f:
        for name in ("gz", "raw"):
            np.testing.assert_array_equal(f[name][:], data)


def test_a_small_queue_bound_blocks_and_keeps_every_row(tmp_path, rng, monkeypatch):
    """With the bound below one chunk every put waits for its chunks: same rows."""
    monkeypatch.setattr(h5chunks, "MAX_PENDING_BYTES", 1)
    parts = [rng.normal(size=n) for n in (C + 5, 4 * C, 7)]
    _appended(tmp_path / "c.h5", parts)
    with h5py.File(tmp_path / "c.h5") as f:
        np.testing.assert_array_equal(f["a"][:], np.concatenate(parts))


def test_a_failed_write_leaves_no_file_and_spares_another(tmp_path, rng):
    """A failure inside atomic_h5file removes its file and forgets its waiting chunks; a
    file open beside it keeps its own and is complete."""
    data = rng.normal(size=4 * C)
    with atl03.atomic_h5file(tmp_path / "kept.h5") as kept:
        h5chunks.put(kept, "a", data, "m", "kept", append=True)
        with pytest.raises(RuntimeError, match="boom"):
            with atl03.atomic_h5file(tmp_path / "failed.h5") as failed:
                h5chunks.put(failed, "a", data, "m", "failed", append=True)
                raise RuntimeError("boom")
        assert all(e[0] == h5chunks._file_key(kept) for e in h5chunks._pending)
    assert not h5chunks._pending
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept.h5"]
    with h5py.File(tmp_path / "kept.h5") as f:
        np.testing.assert_array_equal(f["a"][:], data)


def test_rows_begun_elsewhere_and_another_fill_value(tmp_path, rng):
    """A dataset HDF5 filled to a length off the chunk grid is continued through HDF5 up to
    the next boundary; an edge chunk is padded with the dataset's own fill value, so rows
    added later by HDF5 beyond it read as that value until written."""
    data = rng.normal(size=3 * C)
    path = tmp_path / "e.h5"
    with atl03.atomic_h5file(path) as f:
        d = f.create_dataset("a", shape=(100,), maxshape=(None,), dtype=np.float64,
                             chunks=(C,), compression="gzip", compression_opts=1,
                             shuffle=True, fillvalue=-9.0)
        d[:] = data[:100]
        h5chunks.put(f, "a", data[100:C + 300], "m", "x", append=True)
    with h5py.File(path, "a") as f:
        np.testing.assert_array_equal(f["a"][:], data[:C + 300])
        f["a"].resize(2 * C, axis=0)
        np.testing.assert_array_equal(f["a"][C + 300:], -9.0)


def _described(obj):
    """Every attribute of ``obj`` as (HDF5 type class, size, variable-length, charset, shape,
    value bytes)."""
    out = {}
    for k in obj.attrs:
        a = obj.attrs.get_id(k)
        t = a.get_type()
        s = t.get_class() == h5py.h5t.STRING
        v = obj.attrs[k]
        out[k] = (t.get_class(), t.get_size(), s and t.is_variable_str(),
                  t.get_cset() if s else None, a.shape,
                  v.encode() if isinstance(v, str) else np.asarray(v).tolist()
                  if np.asarray(v).dtype == object else np.asarray(v).tobytes())
    return out


def test_set_attrs_and_new_datasets_are_what_h5py_makes(tmp_path):
    """``set_attrs`` writes each value as ``obj.attrs[name] = value`` would (type, size,
    charset, shape, value; an existing one replaced; fixed-length byte strings by HDF5's own
    calls too; other kinds of value, ``bytes`` among them, through h5py), and
    a dataset ``put`` makes from the first one's creation properties (the second of a kind)
    has h5py's type, chunks, filters, fill value and extent."""
    values = {"units": "meters", "long_name": "hauteur é", "_FillValue": np.float32(3.4e38),
              "valid_max": np.asarray(120, np.int8), "flag_values": np.asarray([0, 1, 2],
                                                                              np.int16),
              "frame": np.asarray([1.5, -2.0]), "n": 3, "x": 0.5, "words": ["a", "bc"],
              "fixed": np.bytes_(b"2019-06-01T00:00Z"), "fixed_rows": np.array([b"a", b"bcd"]),
              "vlen": b"bytes"}
    with h5py.File(tmp_path / "a.h5", "w") as f:
        ours, theirs = f.create_group("ours"), f.create_group("theirs")
        ours.attrs["units"] = np.int64(7)              # replaced
        h5chunks.set_attrs(ours, values)
        for k, v in values.items():
            theirs.attrs[k] = v
        assert _described(ours) == _described(theirs)
        fill = np.float32(3.4e38)
        first = h5chunks.put(ours, "a", np.ones(5, np.float32), "m", "d", append=True,
                             fillvalue=fill)
        second = h5chunks.put(ours, "b", np.ones(7, np.float32), "m", "d", append=True,
                              fillvalue=fill)
        ref = theirs.create_dataset("b", shape=(0,), dtype=np.float32, maxshape=(None,),
                                    chunks=(C,), compression="gzip",
                                    compression_opts=h5chunks.GZIP_LEVEL, shuffle=True,
                                    fillvalue=fill)
        for d in (first, second):
            p, q = d.id.get_create_plist(), ref.id.get_create_plist()
            assert d.id.get_type().equal(ref.id.get_type())
            assert (d.chunks, d.maxshape, d.compression, d.compression_opts, d.shuffle,
                    d.fillvalue) == (ref.chunks, ref.maxshape, ref.compression,
                                     ref.compression_opts, ref.shuffle, ref.fillvalue)
            assert [p.get_filter(i) for i in range(p.get_nfilters())] == \
                [q.get_filter(i) for i in range(q.get_nfilters())]
            assert (p.get_fill_time(), p.get_alloc_time(), p.get_obj_track_times()) == \
                (q.get_fill_time(), q.get_alloc_time(), q.get_obj_track_times())
        assert _described(second) == _described(first)
        h5chunks.drain(f)
    with h5py.File(tmp_path / "a.h5") as f:
        np.testing.assert_array_equal(f["ours/b"][:], np.ones(7, np.float32))


def _made(f) -> dict:
    """Every group and dataset of file ``f``: attributes (:func:`_described`) and, for a
    dataset, its type, extent, chunks, filters, fill value and times, and bytes."""
    out = {"/": _described(f)}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            p, t = obj.id.get_create_plist(), obj.id.get_type()
            out[name] = (_described(obj), obj.dtype.str, t.get_class(), t.get_size(),
                         obj.shape, obj.maxshape, obj.chunks,
                         [p.get_filter(i) for i in range(p.get_nfilters())],
                         repr(obj.fillvalue), p.get_fill_time(), p.get_alloc_time(),
                         p.get_obj_track_times(), obj[()].tobytes())
        else:
            out[name] = _described(obj)
    f.visititems(visit)
    return out


def test_groups_copied_from_a_template_are_the_groups_made_in_place(tmp_path, monkeypatch):
    """``h5template.put_group`` with templates (a group's empty datasets copied by HDF5)
    and without (each made by ``put`` and ``set_attrs``) writes the same file: every object,
    attribute (type, size, charset, shape, value), dtype, extent, chunking, filter, fill
    value and byte, over two appends to a group, a second group from the same template, a
    dataset added to an existing group, and a group whose attributes differ in one value
    (a template of its own)."""
    from lidar_mitsuba.products import h5template
    monkeypatch.setattr(h5template, "_templates", {})

    def columns(rng, n, note="", extra=False):
        cols = [("h", rng.normal(size=n).astype(np.float32), "meters", "height",
                 {"long_name": "h", "_FillValue": np.float32(3.4e38),
                  **({"model_note": note} if note else {})}, np.float32(3.4e38)),
                ("conf", rng.integers(-1, 5, (n, 5)).astype(np.int8), "1", "confidence",
                 lambda: {"flag_values": np.arange(-1, 5, dtype=np.int8),
                          "valid_max": np.int8(4)}, np.int8(127)),
                ("sub/t", np.cumsum(rng.random(n)), "seconds", "time", {}, None)]
        if extra:
            cols.append(("late", np.arange(n, dtype=np.int32), "1", "added later", {}, None))
        return cols

    files = {}
    for templates in (False, True):
        monkeypatch.setattr(h5template, "TEMPLATES", templates)
        rng = np.random.default_rng(1)
        path = tmp_path / f"{templates}.h5"
        with atl03.atomic_h5file(path) as f:
            for group, n, kw in (("gt1l/heights", 1000, {}), ("gt1l/heights", C + 7, {}),
                                 ("gt2l/heights", 10, {}), ("gt2l/heights", 30, {"extra": True}),
                                 ("gt3l/heights", 20, {"note": "not modelled"})):
                h5template.put_group(f, group, columns(rng, n, **kw))
        # two templates (the groups with and without the note), or none
        assert len(h5template._templates) == (2 if templates else 0)
        with h5py.File(path) as f:
            files[templates] = _made(f)
    assert len(files[True]) == 20
    assert files[True] == files[False]


def test_extents_follow_the_rows_lazily(tmp_path, rng):
    """An append counts its rows (``h5write.rows``) and the dataset's extent in the file
    follows only when HDF5 stores a chunk at or beyond it, or at drain: it never exceeds the
    rows, lags them between, and the closed file holds every row, through the pool's chunks
    and through HDF5's own pipeline (a dataset without shuffle)."""
    parts = [rng.normal(size=n) for n in (10, C - 20, 30, 2 * C, 7)]
    path = tmp_path / "x.h5"
    lagged = False
    with atl03.atomic_h5file(path) as f:
        f.create_dataset("plain", shape=(0,), maxshape=(None,), chunks=(C,), dtype=np.float64)
        total = 0
        for p in parts:
            h5chunks.put(f, "a", p, "m", "x", append=True)
            assert h5chunks.append(f, [("plain", p)]) == []
            total += p.size
            assert h5chunks.rows(f, "a") == h5chunks.rows(f, "plain") == total
            assert f["a"].shape[0] <= total
            lagged |= f["a"].shape[0] < total
        assert lagged and h5chunks.rows(f, "missing") == 0
    with h5py.File(path) as f:
        for name in ("a", "plain"):
            np.testing.assert_array_equal(f[name][:], np.concatenate(parts))


@pytest.mark.parametrize("size", (2, 4, 8, 3))
def test_the_compiled_shuffle_is_numpys_byte_transpose(size):
    """HDF5's byte shuffle by words (products.h5kernels) moves the very bytes of numpy's
    transposed copy of the (n, size) byte matrix (what _encode did), for element counts
    that are and are not a multiple of the size (a byte loop then), one chunk's included."""
    from lidar_mitsuba.products import h5kernels
    gen = np.random.default_rng(size)
    for n in (0, 1, size - 1, size, 7, 8, 9, 64, 1001, C, C + 3):
        src = gen.integers(0, 256, n * size).astype(np.uint8)
        out = np.full_like(src, 7)
        h5kernels.shuffle(src, size, out)
        np.testing.assert_array_equal(out, np.ascontiguousarray(src.reshape(-1, size).T)
                                      .reshape(-1))


def test_extend_extent_keeps_the_running_bounds_with_or_without_its_memory(tmp_path, rng):
    """``metadata.extend_extent`` writes only the bounds that move and remembers what it
    wrote: after calls on interleaved files (more than it remembers, so some are read back
    from the file), each file's ``METADATA/Extent`` bounds and root ``geospatial_*`` copies
    are the running minima and maxima of every call's shots, as float64, with the units."""
    from lidar_mitsuba.products import metadata
    files = [h5py.File(tmp_path / f"{i}.h5", "w") for i in range(metadata._BOUNDS_FILES + 3)]
    want = [None] * len(files)
    for _ in range(3):
        for i, f in enumerate(files):
            lat, lon = rng.uniform(-80, 80, 50), rng.uniform(-180, 180, 50)
            metadata.extend_extent(f, lat, lon)
            now = (lat.min(), lat.max(), lon.min(), lon.max())
            want[i] = now if want[i] is None else (min(want[i][0], now[0]),
                                                  max(want[i][1], now[1]),
                                                  min(want[i][2], now[2]),
                                                  max(want[i][3], now[3]))
    for f, (s, n, w, e) in zip(files, want):
        ext = f["METADATA/Extent"].attrs
        got = [ext[k] for k in ("southBoundLatitude", "northBoundLatitude",
                                "westBoundLongitude", "eastBoundLongitude")]
        assert got == [s, n, w, e] and all(isinstance(v, np.float64) for v in got)
        assert [f.attrs[k] for k in ("geospatial_lat_min", "geospatial_lat_max",
                                     "geospatial_lon_min", "geospatial_lon_max")] == got
        assert (f.attrs["geospatial_lat_units"], f.attrs["geospatial_lon_units"]) == \
            ("degrees_north", "degrees_east")
        f.close()
