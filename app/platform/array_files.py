"""NPY / NPZ files checked from their headers, and read with a hard cap on what is inflated.

An NPZ is a zip of ``.npy`` members; each member starts with a small header that declares
the array's shape and dtype.  A 0.8 MB NPZ can declare (and, deflated, really hold) an
800 MB array, and a zip's directory can lie about the sizes it holds.  So:

* :func:`inspect_npz` / :func:`inspect_npy` read only the headers (at most a few KiB of each
  member is inflated) and refuse object dtypes, too many members, a declared total over
  ``max_bytes`` and members whose declared zip size disagrees with their header;
* :func:`load_npz` reads every member through a stream that stops at the size the header
  declared (plus the header) whatever the zip says, and never beyond ``max_bytes`` in total,
  then builds each array from exactly those bytes (no pickles).

Pure: bytes in, arrays or :class:`ArrayFileError` (naming ``file``) out.
"""

from __future__ import annotations

import io
import zipfile
from dataclasses import dataclass
from typing import IO

import numpy as np
from numpy.lib import format as npy_format

from app.domain.errors import InvalidInput

MAX_MEMBERS = 64
_HEADER_READ = 65_536  # numpy headers are < 64 KiB
_CHUNK = 1 << 20


class ArrayFileError(InvalidInput):
    """An NPY/NPZ that cannot be accepted (malformed, object dtype, too large, lying sizes)."""


@dataclass(frozen=True)
class ArrayInfo:
    """What a ``.npy`` header declares: shape, dtype, data bytes and header length (bytes)."""

    shape: tuple[int, ...]
    dtype: np.dtype
    nbytes: int
    header_bytes: int


def _header(stream: io.BufferedIOBase | io.BytesIO, field: str, name: str) -> ArrayInfo:
    try:
        version = npy_format.read_magic(stream)
        if version not in ((1, 0), (2, 0)):
            raise ValueError(f".npy format version {version} is not accepted (1.0 or 2.0)")
        reader = npy_format.read_array_header_1_0 if version == (1, 0) else npy_format.read_array_header_2_0
        shape, _, dtype = reader(stream)
    except (ValueError, OSError, EOFError, SyntaxError) as exc:
        raise ArrayFileError(f"{name}: not a readable .npy header ({exc})", field=field, value=name) from None
    if dtype.hasobject:
        raise ArrayFileError(f"{name}: object arrays (pickles) are not accepted", field=field, value=str(dtype))
    count = int(np.prod(shape, dtype=object)) if shape else 1
    return ArrayInfo(tuple(int(n) for n in shape), dtype, count * dtype.itemsize, stream.tell())


def _too_large(total: int, max_bytes: int, field: str) -> ArrayFileError:
    return ArrayFileError(f"the arrays declare {total / 2**20:,.1f} MiB; at most {max_bytes / 2**20:,.0f} MiB "
                          "(CONFORMA_MAX_UPLOAD_MB)", field=field, value=total)


def inspect_npy(data: bytes, max_bytes: int, field: str = "file") -> ArrayInfo:
    """The header of an NPY file; its data must be exactly what the header declares."""
    info = _header(io.BytesIO(data[:_HEADER_READ]), field, "array")
    if info.nbytes > max_bytes:
        raise _too_large(info.nbytes, max_bytes, field)
    if len(data) != info.header_bytes + info.nbytes:
        raise ArrayFileError(f"the .npy header declares {info.nbytes} data bytes, the file holds "
                             f"{len(data) - info.header_bytes}", field=field, value=len(data))
    return info


def inspect_npz(data: bytes, max_bytes: int, field: str = "file") -> dict[str, ArrayInfo]:
    """The headers of every member of an NPZ (only headers are inflated)."""
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
    except (zipfile.BadZipFile, ValueError) as exc:
        raise ArrayFileError(f"not a readable zip/NPZ ({exc})", field=field, value=len(data)) from None
    with archive:
        members = archive.infolist()
        if len(members) > MAX_MEMBERS:
            raise ArrayFileError(f"{len(members)} members; an NPZ may hold at most {MAX_MEMBERS}", field=field,
                                 value=len(members))
        infos: dict[str, ArrayInfo] = {}
        total = 0
        for member in members:
            if not member.filename.endswith(".npy"):
                raise ArrayFileError(f"{member.filename!r} is not a .npy member: not an NPZ", field=field,
                                     value=member.filename)
            try:
                with archive.open(member) as stream:
                    info = _header(io.BytesIO(stream.read(_HEADER_READ)), field, member.filename)
            except (zipfile.BadZipFile, OSError, EOFError, NotImplementedError) as exc:
                raise ArrayFileError(f"{member.filename}: unreadable member ({exc})", field=field,
                                     value=member.filename) from None
            total += info.nbytes
            if total > max_bytes:
                raise _too_large(total, max_bytes, field)
            if member.file_size != info.header_bytes + info.nbytes:
                raise ArrayFileError(f"{member.filename}: the zip declares {member.file_size} bytes, its header "
                                     f"{info.header_bytes + info.nbytes}", field=field, value=member.filename)
            infos[member.filename[:-4]] = info
        return infos


def _read_capped(stream: IO[bytes], limit: int, name: str, field: str) -> bytes:
    """At most ``limit`` bytes of ``stream``; an error if there is more (a lying zip)."""
    parts: list[bytes] = []
    size = 0
    while True:
        chunk = stream.read(min(_CHUNK, limit + 1 - size))
        if not chunk:
            return b"".join(parts)
        parts.append(chunk)
        size += len(chunk)
        if size > limit:
            raise ArrayFileError(f"{name}: inflates beyond what its header declares", field=field, value=name)


def load_npz(data: bytes, max_bytes: int, field: str = "file") -> dict[str, np.ndarray]:
    """The arrays of an NPZ, inflated under a hard cap (see the module doc)."""
    infos = inspect_npz(data, max_bytes, field)
    arrays: dict[str, np.ndarray] = {}
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        for name, info in infos.items():
            expected = info.header_bytes + info.nbytes
            try:
                with archive.open(f"{name}.npy") as stream:
                    raw = _read_capped(stream, expected, name, field)
            except (zipfile.BadZipFile, OSError, EOFError) as exc:
                raise ArrayFileError(f"{name}: unreadable member ({exc})", field=field, value=name) from None
            if len(raw) != expected:
                raise ArrayFileError(f"{name}: holds {len(raw)} bytes, its header declares {expected}", field=field,
                                     value=name)
            arrays[name] = npy_format.read_array(io.BytesIO(raw), allow_pickle=False)
    return arrays


def check_upload(media_type: str, data: bytes, max_bytes: int, field: str = "file") -> None:
    """Refuse an uploaded NPY/NPZ (by media type) whose headers do not hold up; others pass."""
    if media_type == "application/x-npy":
        inspect_npy(data, max_bytes, field)
    elif media_type == "application/zip":
        inspect_npz(data, max_bytes, field)
