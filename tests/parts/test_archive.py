"""3MF archives are inflated with a hard cap whatever their headers say."""

from __future__ import annotations

import io
import struct
import tracemalloc
import zipfile

import pytest

from app.domain.errors import TooLarge
from app.parts.archive import ArchiveError, inflate_zip, threemf_unit
from app.parts.intake import intake
from tests.helpers.real_parts import inch_3mf


def zeros_zip(megabytes: int) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("3D/3dmodel.model", b"\0" * (megabytes << 20))
    return buffer.getvalue()


def lie_about_packed_size(data: bytes) -> bytes:
    """Patch the central directory so each member claims compress_size == file_size (a 1:1
    ratio in the headers), as the attack file did to slip past a header-only ratio check."""
    out = bytearray(data)
    at = out.find(b"PK\x01\x02")
    while at >= 0:
        real_size = struct.unpack_from("<I", out, at + 24)[0]
        struct.pack_into("<I", out, at + 20, real_size)
        at = out.find(b"PK\x01\x02", at + 4)
    return bytes(out)


def test_a_zip_lying_about_its_packed_size_is_refused_without_inflating_it():
    bomb = lie_about_packed_size(zeros_zip(200))
    assert len(bomb) < 1 << 20
    header_ratio = sum(i.file_size for i in zipfile.ZipFile(io.BytesIO(bomb)).infolist()) / sum(
        i.compress_size for i in zipfile.ZipFile(io.BytesIO(bomb)).infolist())
    assert header_ratio == 1.0                          # the headers alone look harmless
    tracemalloc.start()
    try:
        with pytest.raises(ArchiveError) as err:
            intake(bomb, "3mf", max_unzipped_bytes=1 << 30)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert "zip bomb" in err.value.message
    assert peak < 16 << 20                              # the 200 MB were never produced


def test_real_inflated_bytes_are_capped_chunk_by_chunk():
    data = zeros_zip(12)
    with pytest.raises((TooLarge, ArchiveError)):
        inflate_zip(data, max_bytes=4 << 20)
    members = inflate_zip(inch_3mf(), max_bytes=1 << 20)
    assert threemf_unit(members) == "inch"


def test_a_member_declaring_less_than_it_holds_is_refused_clearly():
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("3D/3dmodel.model", bytes(range(256)) * 4096)
    out = bytearray(buffer.getvalue())
    for signature, offset in ((b"PK\x01\x02", 24), (b"PK\x03\x04", 22)):   # uncompressed size fields
        at = out.find(signature)
        struct.pack_into("<I", out, at + offset, 100)
    with pytest.raises(ArchiveError) as err:
        inflate_zip(bytes(out), max_bytes=1 << 30)
    assert "cannot be inflated" in err.value.message
