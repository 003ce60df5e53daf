"""The head-driver line protocol (pure codec, no I/O).

Piezo print-head driver boards (Ricoh GH2220-class heads on a driver with an encoder
input) take a bitmap per swath ahead of the pass and fire it from the scan axis' encoder:
each bitmap row is fired when a nozzle row crosses that row's position.  Vendors' host
interfaces are SDKs, not public text protocols, so Conforma speaks this small line protocol
of its own (one command at a time, each answered before the next; ASCII; LF-terminated):

* ``ID`` -> ``ID,<model>,<nozzles>,<rows>,<dpi>,<row_gap_um>``: the head (nozzle ``n`` sits
  ``n`` pitches along +x from nozzle 0, in row ``n % rows``, rows ``row_gap_um`` apart along
  +y);
* ``LOAD,<y0_mm>,<rows>,<first_nozzle>,<count>,<crc32>,<hex>`` -> ``LOAD,<drops>``: the
  swath's bitmap, ``rows`` x ``count`` bits row by row, each row packed MSB first into
  whole bytes, in hex; row ``i`` fires at scan position ``y0 + i * pitch``, column ``c``
  on nozzle ``first_nozzle + c``; ``crc32`` (8 hex digits) of the packed bytes;
* ``ARM`` -> ``ARM``: fire the loaded swath as the nozzles cross its rows (each drop once);
* ``ST`` -> ``ST,<armed>,<rows_done>,<rows>,<fired>``: rows every nozzle row has crossed,
  drops fired so far;
* ``DA`` -> ``DA,<fired>``: disarm, forget the swath.

A refused command answers ``ER,<command>,<code>``: 00 unknown command, 01 status error
(``ARM`` without a swath, ``LOAD`` while armed), 21 parameter count, 22 invalid parameter,
23 checksum mismatch.
"""

from __future__ import annotations

import zlib

import numpy as np

LF = b"\n"
ERROR_CODES = {"00": "unknown command", "01": "status error", "21": "parameter count error",
               "22": "invalid parameter", "23": "checksum mismatch"}
MAX_BITS = 64_000_000


class HdpFormatError(ValueError):
    """A bitmap field that does not decode."""


def pack_bitmap(bits: np.ndarray) -> tuple[str, str]:
    """(rows, count) bool -> (hex of the row-packed bytes, crc32 as 8 hex digits)."""
    packed = np.packbits(np.asarray(bits, dtype=bool), axis=1)
    data = packed.tobytes()
    return data.hex(), f"{zlib.crc32(data) & 0xFFFFFFFF:08x}"


def unpack_bitmap(text: str, rows: int, count: int, crc: str) -> np.ndarray:
    """The (rows, count) bool bitmap of a ``LOAD`` (``HdpFormatError`` when it does not decode
    or its checksum differs)."""
    if rows < 1 or count < 1 or rows * count > MAX_BITS:
        raise HdpFormatError("rows and count must be >= 1 and within the head's memory")
    try:
        data = bytes.fromhex(text)
    except ValueError:
        raise HdpFormatError("bitmap is not hex") from None
    width = (count + 7) // 8
    if len(data) != rows * width:
        raise HdpFormatError(f"bitmap has {len(data)} bytes, expected {rows * width}")
    if f"{zlib.crc32(data) & 0xFFFFFFFF:08x}" != crc.lower():
        raise HdpFormatError("checksum mismatch")
    packed = np.frombuffer(data, dtype=np.uint8).reshape(rows, width)
    bits: np.ndarray = np.unpackbits(packed, axis=1)[:, :count].astype(bool)
    return bits


def error_text(fields: list[str]) -> str:
    """``ER`` fields -> "<command>: <meaning>"."""
    code = fields[1] if len(fields) > 1 else "??"
    return f"{fields[0] if fields else '?'}: {ERROR_CODES.get(code, 'error ' + code)}"
