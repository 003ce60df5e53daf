"""NPY/NPZ checked from their headers; inflation capped whatever the zip directory says."""

from __future__ import annotations

import functools
import io
import struct
import tracemalloc
import zipfile
import zlib

import numpy as np
import pytest

from app.platform.array_files import ArrayFileError, inspect_npy, inspect_npz, load_npz

MIB = 2**20


def npz(**arrays: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


def npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


@functools.cache
def bomb(mb: int) -> bytes:
    """A deflated NPZ holding an ``mb`` MiB float64 zero array (~1000:1); made once per test
    process (deflating 800 MiB costs ~2.6 s of CPU) and shared, read-only (``bytes``), by the
    tests that refuse it."""
    return npz(heights=np.zeros(mb * MIB // 8))


def test_a_round_trip_keeps_names_shapes_dtypes_and_values():
    heights = np.random.default_rng(0).normal(size=(40, 30))
    data = npz(heights=heights, layers=np.arange(3, dtype=np.int32))
    infos = inspect_npz(data, MIB)
    assert infos["heights"].shape == (40, 30) and infos["heights"].nbytes == 40 * 30 * 8
    assert infos["layers"].dtype == np.int32
    arrays = load_npz(data, MIB)
    np.testing.assert_array_equal(arrays["heights"], heights)
    np.testing.assert_array_equal(arrays["layers"], np.arange(3))
    assert inspect_npy(npy(heights), MIB).shape == (40, 30)


def test_a_small_npz_declaring_a_huge_array_is_refused_without_allocating_it():
    data = bomb(800)
    assert len(data) < MIB  # 0.8 MB on the wire
    tracemalloc.start()  # numpy reports its buffers to tracemalloc
    try:
        with pytest.raises(ArrayFileError) as refused:
            inspect_npz(data, 200 * MIB)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert refused.value.field == "file" and "800.0 MiB" in refused.value.message
    assert peak < MIB  # nothing inflated beyond the header


def _lying_zip(true_array: np.ndarray, declared: np.ndarray) -> bytes:
    """A stored .npy whose header declares ``declared``'s shape but whose data is ``true_array``'s."""
    header = npy(declared)[: len(npy(declared)) - declared.nbytes]
    payload = header + true_array.tobytes()
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("heights.npy", payload)
    return buffer.getvalue()


def test_a_member_larger_than_its_header_is_refused_and_never_inflated_past_the_header():
    data = _lying_zip(np.zeros(4 * MIB // 8), np.zeros(16))  # header: 16 values; data: 4 MiB
    with pytest.raises(ArrayFileError, match="declares"):
        inspect_npz(data, 200 * MIB)
    # a zip directory that lies as well (its size fields patched to match the header): the
    # stream stops at the declared size, so the extra data is never inflated (CRC mismatch)
    patched = _patch_sizes(data, len(npy(np.zeros(16))))
    tracemalloc.start()
    try:
        with pytest.raises(ArrayFileError, match="unreadable member|inflates beyond"):
            load_npz(patched, 200 * MIB)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < MIB  # the 4 MiB of data were never inflated


def _patch_sizes(data: bytes, size: int) -> bytes:
    """Overwrite the uncompressed size in the local header and the central directory."""
    out = bytearray(data)
    local = out.find(b"PK\x03\x04")
    struct.pack_into("<I", out, local + 22, size)
    central = out.find(b"PK\x01\x02")
    struct.pack_into("<I", out, central + 24, size)
    return bytes(out)


@pytest.mark.parametrize(("data", "needle"), [
    (npz(obj=np.array([{"a": 1}], dtype=object)), "object arrays"),
    (b"PK\x03\x04" + b"\x00" * 40, "not a readable zip"),
    (zipfile.ZipFile.__name__.encode(), "not a readable zip"),
])
def test_malformed_or_pickled_npz_is_refused(data, needle):
    with pytest.raises(ArrayFileError, match=needle):
        inspect_npz(data, MIB)


def test_a_truncated_npy_is_refused():
    data = npy(np.arange(100.0))
    with pytest.raises(ArrayFileError, match="declares 800 data bytes"):
        inspect_npy(data[:-8], MIB)
    assert zlib.crc32(data)  # the intact file passes
    inspect_npy(data, MIB)
