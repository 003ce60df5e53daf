"""A reconstruction stored as arrays (an NPZ) and read back exactly.

``compensate`` reads the reconstruction a ``reconstruct`` job stored instead of building it
again: :func:`reconstruction_npz` writes everything a :class:`Reconstruction` holds except
its nominal (the trace's polyline, which the reader supplies), :func:`read_reconstruction`
gives the same reconstruction back: same curve, samples and cleaned points, and a height
along the trace that is bit for bit the one the job computed
(:mod:`app.reconstruction.heights`).

Pure: numpy.  Units: mm.
"""

from __future__ import annotations

import functools
import io
import json
import math
import re
import struct
import zipfile
import zlib
from typing import Any

import numpy as np

from app.geometry.nurbs import NurbsCurve
from app.geometry.tolerance import LENGTH_EPS_MM
from app.geometry.traces import TracePolyline
from app.reconstruction.heights import height_model
from app.reconstruction.preprocess import CleanPoints, ReconstructionError
from app.reconstruction.reconstruct import Reconstruction

FORMAT = 1
STORED = "reconstruction.npz"  # the artifact name a reconstruct job stores it under
_HEIGHT = "height."


def stored_name(trace_id: str | None = None) -> str:
    """The artifact name of a stored reconstruction: :data:`STORED` for a one-trace
    ``reconstruct`` job, ``reconstruction.<trace_id>.npz`` for each trace of a board job
    (``trace_ids``).  The one place both the writer and the readers take the name from."""
    return STORED if trace_id is None else f"reconstruction.{trace_id}.npz"


def reconstruction_arrays(rec: Reconstruction) -> dict[str, np.ndarray]:
    """Every number of ``rec`` but its nominal, as named arrays."""
    curve = rec.curve
    out = {
        "format": np.asarray(FORMAT), "method": np.asarray(rec.method),
        "height_kind": np.asarray(rec.height_model.kind),
        "curve_degree": np.asarray(curve.degree), "curve_knots": curve.knots,
        "curve_control_points": curve.control_points,
        "curve_weights": curve.w, "samples": np.asarray(rec.samples, dtype=float).reshape(-1, 2),
        "max_mm": np.asarray(rec.max_mm), "rms_mm": np.asarray(rec.rms_mm), "span_mm": np.asarray(rec.span_mm),
        "clean_points": np.asarray(rec.clean.points, dtype=float).reshape(-1, 3), "clean_s": rec.clean.s,
        "clean_dz": rec.clean.dz, "clean_outliers": np.asarray(rec.clean.outliers, dtype=np.int64),
        "clean_merged": np.asarray(rec.clean.merged), "refinement": np.asarray(json.dumps(rec.refinement)),
        "nominal_length_mm": np.asarray(rec.nominal.length_mm),
    }
    out.update({_HEIGHT + k: np.asarray(v) for k, v in rec.height_model.arrays().items()})
    return out


def reconstruction_from_arrays(arrays: dict[str, np.ndarray], nominal: TracePolyline) -> Reconstruction:
    """The reconstruction ``arrays`` hold, over ``nominal`` (the trace's polyline in the same
    frame).  ReconstructionError (422, field ``reconstruction``) when the arrays are of another
    format or the nominal is not the one the reconstruction was made on."""
    try:
        if int(arrays["format"]) != FORMAT:
            raise ReconstructionError(f"stored reconstruction format {int(arrays['format'])}, expected {FORMAT}",
                                      field="reconstruction", value=int(arrays["format"]))
        length = float(arrays["nominal_length_mm"])
        if not np.isclose(length, nominal.length_mm, rtol=0.0, atol=LENGTH_EPS_MM):
            raise ReconstructionError(f"the stored reconstruction was made on a {length:.6f} mm nominal, not on "
                                      f"this {nominal.length_mm:.6f} mm one", field="reconstruction", value=length)
        curve = NurbsCurve(int(arrays["curve_degree"]), arrays["curve_knots"], arrays["curve_control_points"],
                           arrays["curve_weights"])
        height = height_model(str(arrays["height_kind"]), nominal,
                              {k[len(_HEIGHT):]: v for k, v in arrays.items() if k.startswith(_HEIGHT)}, curve)
        clean = CleanPoints(arrays["clean_points"], arrays["clean_s"], arrays["clean_dz"],
                            tuple(int(i) for i in arrays["clean_outliers"]), int(arrays["clean_merged"]))
        refinement: Any = json.loads(str(arrays["refinement"]))
        s0, s1 = (float(v) for v in arrays["span_mm"])
        return Reconstruction(method=str(arrays["method"]), curve=curve, clean=clean, samples=arrays["samples"],
                              max_mm=float(arrays["max_mm"]), rms_mm=float(arrays["rms_mm"]), nominal=nominal,
                              _height_s=height, span_mm=(s0, s1), refinement=refinement)
    except KeyError as exc:
        raise ReconstructionError(f"the stored reconstruction lacks {exc}", field="reconstruction",
                                  value=str(exc)) from None


def reconstruction_npz(rec: Reconstruction) -> bytes:
    """``rec`` as NPZ bytes (no pickles): one ``<name>.npy`` member per array, stored
    uncompressed (a board stores a thousand, and deflating them cost more than the rest of
    writing them; they are ~1.3x larger), each member byte for byte what
    ``numpy.lib.format.write_array`` writes, so ``numpy.load`` reads them as usual; the
    archive byte for byte what ``zipfile`` writes for them (:func:`stored_archive`)."""
    return stored_archive([(name + ".npy", _npy_bytes(np.asarray(array)))
                           for name, array in reconstruction_arrays(rec).items()])


_FILE_HEADER = struct.Struct("<4s2B4HL2L2H")      # a member's local header (30 bytes), as zipfile packs it
_CENTRAL_ENTRY = struct.Struct("<4s4B4HL2L5H2L")  # its central directory entry (46 bytes)
_END_RECORD = struct.Struct("<4s4H2LH")           # the end of the central directory (22 bytes)
_ZIP_VERSION = 20        # made by and needed to extract: zipfile's default
_UNIX = 3                # made on: zipfile's create_system off Windows
_DOS_DATE_1980 = 33      # 1980-01-01 as a DOS date ((1980 - 1980) << 9 | 1 << 5 | 1), time 0: numpy's date
_OWNER_RW = 0o600 << 16  # the external attributes zipfile gives a member written from bytes
_SMALL = 2 ** 31 - 1     # zipfile's ZIP64_LIMIT: an archive near it is left to zipfile
_MANY = 0xFFFF          # zipfile's ZIP_FILECOUNT_LIMIT: as many members, too


def stored_archive(members: list[tuple[str, bytes]]) -> bytes:
    """A zip archive of ``members`` (name, bytes), each stored (not compressed) and dated
    1980-01-01: byte for byte what ``zipfile.ZipFile(..., "w", ZIP_STORED).writestr`` writes
    for a ``ZipInfo(name)`` of each, in order (tests/reconstruction/test_stored.py compares
    them), packed here because ``zipfile``'s bookkeeping per member cost more than the
    member's own bytes (a board job writes some 24 000).  ASCII names; an archive that
    would need ZIP64 (over 2 GiB or 65,535 members) is written by ``zipfile`` itself."""
    if sum(len(data) for _, data in members) * 1.05 > _SMALL or len(members) >= _MANY \
            or not all(name.isascii() for name, _ in members):
        out = io.BytesIO()
        with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as archive:
            for name, data in members:
                archive.writestr(zipfile.ZipInfo(name), data)
        return out.getvalue()
    parts: list[bytes] = []
    central: list[bytes] = []
    offset = 0
    for name, data in members:
        raw, crc, size = name.encode("ascii"), zlib.crc32(data), len(data)
        local = _FILE_HEADER.pack(b"PK\x03\x04", _ZIP_VERSION, 0, 0, zipfile.ZIP_STORED, 0, _DOS_DATE_1980,
                                  crc, size, size, len(raw), 0)
        central.append(_CENTRAL_ENTRY.pack(b"PK\x01\x02", _ZIP_VERSION, _UNIX, _ZIP_VERSION, 0, 0,
                                           zipfile.ZIP_STORED, 0, _DOS_DATE_1980, crc, size, size, len(raw),
                                           0, 0, 0, 0, _OWNER_RW, offset) + raw)
        parts += [local, raw, data]
        offset += len(local) + len(raw) + size
    directory = b"".join(central)
    end = _END_RECORD.pack(b"PK\x05\x06", 0, 0, len(central), len(central), len(directory), offset, 0)
    return b"".join([*parts, directory, end])


def _npy_bytes(array: np.ndarray) -> bytes:
    """``array`` as a ``.npy`` member in C order: numpy's own header for its dtype and shape
    (:func:`_npy_header`), then its bytes; no pickles (an object array is a ValueError, as
    ``numpy.lib.format.write_array`` with ``allow_pickle=False`` raises)."""
    array = np.asarray(array, order="C")
    if array.dtype.hasobject:
        raise ValueError("object arrays cannot be stored without pickles")
    return _npy_header(array.dtype, array.shape) + array.tobytes()


@functools.lru_cache(maxsize=4096)
def _npy_header(dtype: np.dtype, shape: tuple[int, ...]) -> bytes:
    """The header ``numpy.lib.format.write_array`` writes before an array of ``dtype`` and
    ``shape`` (format 1.0, C order), made by numpy's own header writer once per dtype and
    shape (a board's members repeat a few dozen: building it per member cost as much as the
    member's bytes)."""
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(out, {"descr": np.lib.format.dtype_to_descr(dtype),
                                               "fortran_order": False, "shape": shape})
    return out.getvalue()


# the header numpy writes (``numpy.lib.format``): a dict of descr, fortran_order and shape
_NPY_HEADER = re.compile(rb"\{'descr': '([<>|=][a-zA-Z]\d*)', 'fortran_order': False, 'shape': \(([\d, ]*)\), \}\s*$")


def _npy_array(member: bytes) -> np.ndarray:
    """One ``.npy`` member's array.  The header numpy itself writes (version 1.0, C order, a
    plain dtype) is matched directly: numpy's reader evaluates every header as a Python
    literal, which cost more than the rest of reading a board's reconstructions.  Anything
    else (another version, Fortran order, a structured dtype) goes to numpy's reader; object
    arrays (pickles) are refused either way."""
    if member[:8] == b"\x93NUMPY\x01\x00":
        size = int.from_bytes(member[8:10], "little")
        match = _NPY_HEADER.match(member[10:10 + size])
        if match is not None:
            dtype = np.dtype(match.group(1).decode())
            if not dtype.hasobject:
                shape = tuple(int(n) for n in match.group(2).split(b",") if n.strip())
                return np.frombuffer(member, dtype=dtype, count=math.prod(shape),
                                     offset=10 + size).reshape(shape).copy()
    return np.lib.format.read_array(io.BytesIO(member), allow_pickle=False)


def read_reconstruction(data: bytes, nominal: TracePolyline) -> Reconstruction:
    """Inverse of :func:`reconstruction_npz` over ``nominal``."""
    try:
        members = _stored_members(data)
        if members is None:  # deflated (stored before they were stored uncompressed), or another writer's
            with zipfile.ZipFile(io.BytesIO(data)) as archive:
                members = {name: archive.read(name) for name in archive.namelist()}
        arrays = {name[:-4]: _npy_array(member) for name, member in members.items() if name.endswith(".npy")}
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, struct.error) as exc:
        raise ReconstructionError(f"the stored reconstruction is not a readable NPZ ({exc})",
                                  field="reconstruction", value=len(data)) from None
    return reconstruction_from_arrays(arrays, nominal)


_LOCAL_HEADER = struct.Struct("<4s2xHH4xIIIHH")  # a zip member's local header: signature, flags,
# method, CRC-32, compressed and uncompressed size, name and extra field lengths (30 bytes)
_DATA_DESCRIPTOR = 0x08  # flag: the sizes follow the data instead of being in the header
_UTF8_NAME = 0x800  # flag: the name is UTF-8 (else code page 437)


def _stored_members(data: bytes) -> dict[str, bytes] | None:
    """{name: bytes} of an archive of stored (uncompressed) members, as
    :func:`reconstruction_npz` writes it, read member after member from the local headers,
    each CRC-32 checked as ``zipfile`` checks it (``zipfile`` parsing the central directory
    and opening each member cost more than the rest of reading a reconstruction); None when
    a member is compressed or its sizes are not in its header, or when the members are not
    followed by the central directory (``zipfile`` then reads it, or refuses it).
    BadZipFile when a member is cut or its CRC-32 does not match."""
    members: dict[str, bytes] = {}
    at = 0
    while data[at:at + 4] == b"PK\x03\x04":
        _, flags, method, crc, size, plain_size, name_len, extra_len = _LOCAL_HEADER.unpack_from(data, at)
        if method != zipfile.ZIP_STORED or flags & _DATA_DESCRIPTOR or size != plain_size or size == 0xFFFFFFFF:
            return None
        begin = at + _LOCAL_HEADER.size
        name = data[begin:begin + name_len].decode("utf-8" if flags & _UTF8_NAME else "cp437")
        begin += name_len + extra_len
        member = data[begin:begin + size]
        if len(member) != size or zlib.crc32(member) != crc:
            raise zipfile.BadZipFile(f"member {name!r} is cut or its CRC-32 does not match")
        members[name] = member
        at = begin + size
    return members if members and data[at:at + 4] == b"PK\x01\x02" else None
