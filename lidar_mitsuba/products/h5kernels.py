"""HDF5's byte shuffle of a chunk, compiled (numba; issue 43: the writer's CPU).

HDF5's shuffle filter stores byte ``k`` of every element of a chunk together: plane ``k``
holds byte ``k`` of elements ``0 .. n - 1``, then plane ``k + 1`` (HDF5's ``H5Z_shuffle``).
numpy's form, the transposed copy of the chunk's ``(n, size)`` byte matrix
(:func:`lidar_mitsuba.products.h5write._encode`), reads its source a byte at a time with a
stride of ``size``: ~50-80 us for a 128 KiB chunk of float64, a fifth of the chunk's deflate.
:func:`shuffle` moves the same bytes a word at a time: ``size`` elements of ``size`` bytes
(a ``size`` x ``size`` byte matrix held in ``size`` words) are transposed in registers by
shifts and masks and stored as one word of each plane (~10 us a 128 KiB chunk). The bytes
are the same (a permutation: ``tests/test_h5chunks.py`` compares them with numpy's for each
size and for element counts that are and are not a multiple of the size). ``cache=True``
keeps the compiled code beside the package (:mod:`lidar_mitsuba.precompile`'s ``"h5"``
stage).
"""
from __future__ import annotations

import numba
import numpy as np

#: element sizes [bytes] :func:`shuffle` takes (others: numpy's form)
SIZES = (2, 4, 8)


@numba.njit(cache=True, nogil=True)
def _planes_by_byte(src, size, out):
    """The shuffle a byte at a time (any element count): plane ``k`` of ``out`` is byte ``k``
    of each of the ``src.size // size`` elements of ``src``."""
    n = src.size // size
    for k in range(size):
        base = k * n
        for i in range(n):
            out[base + i] = src[i * size + k]


@numba.njit(cache=True, nogil=True)
def _shuffle8(src, out):
    """8-byte elements, their count a multiple of 8: eight elements (words ``x0 .. x7``) give
    one 8-byte word of each plane, byte ``j`` of plane ``k``'s word being byte ``k`` of ``xj``."""
    s = src.view(np.uint64)
    o = out.view(np.uint64)
    m = s.size // 8
    ff = np.uint64(0xFF)
    for j in range(m):
        x0, x1, x2, x3 = s[8 * j], s[8 * j + 1], s[8 * j + 2], s[8 * j + 3]
        x4, x5, x6, x7 = s[8 * j + 4], s[8 * j + 5], s[8 * j + 6], s[8 * j + 7]
        for k in range(8):
            sh = np.uint64(8 * k)
            o[k * m + j] = (((x0 >> sh) & ff) | (((x1 >> sh) & ff) << np.uint64(8))
                            | (((x2 >> sh) & ff) << np.uint64(16))
                            | (((x3 >> sh) & ff) << np.uint64(24))
                            | (((x4 >> sh) & ff) << np.uint64(32))
                            | (((x5 >> sh) & ff) << np.uint64(40))
                            | (((x6 >> sh) & ff) << np.uint64(48))
                            | (((x7 >> sh) & ff) << np.uint64(56)))


@numba.njit(cache=True, nogil=True)
def _shuffle4(src, out):
    """4-byte elements, their count a multiple of 4 (as :func:`_shuffle8`, four at a time)."""
    s = src.view(np.uint32)
    o = out.view(np.uint32)
    m = s.size // 4
    ff = np.uint32(0xFF)
    for j in range(m):
        x0, x1, x2, x3 = s[4 * j], s[4 * j + 1], s[4 * j + 2], s[4 * j + 3]
        for k in range(4):
            sh = np.uint32(8 * k)
            o[k * m + j] = (((x0 >> sh) & ff) | (((x1 >> sh) & ff) << np.uint32(8))
                            | (((x2 >> sh) & ff) << np.uint32(16))
                            | (((x3 >> sh) & ff) << np.uint32(24)))


@numba.njit(cache=True, nogil=True)
def _shuffle2(src, out):
    """2-byte elements, their count even (as :func:`_shuffle8`, two at a time)."""
    s = src.view(np.uint16)
    o = out.view(np.uint16)
    m = s.size // 2
    ff = np.uint16(0xFF)
    for j in range(m):
        x0, x1 = s[2 * j], s[2 * j + 1]
        o[j] = (x0 & ff) | ((x1 & ff) << np.uint16(8))
        o[m + j] = (x0 >> np.uint16(8)) | ((x1 >> np.uint16(8)) << np.uint16(8))


@numba.njit(cache=True, nogil=True)
def shuffle(src, size, out):
    """HDF5's byte shuffle of ``src`` (uint8 (n * size,): n elements of ``size`` bytes, one of
    :data:`SIZES`) into ``out`` (uint8, the same size): byte ``k`` of element ``i`` to
    ``out[k * n + i]``."""
    n = src.size // size
    if n % size != 0:
        _planes_by_byte(src, size, out)
    elif size == 8:
        _shuffle8(src, out)
    elif size == 4:
        _shuffle4(src, out)
    elif size == 2:
        _shuffle2(src, out)
    else:
        _planes_by_byte(src, size, out)
