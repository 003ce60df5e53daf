"""Zip archives (3MF) inflated with a hard cap on the bytes actually produced.

A zip's central directory may lie about member sizes (or several entries may share one
compressed stream), so nothing it declares is trusted: every member is inflated in chunks
and the running total of real output bytes is checked after each chunk.  The declared
sizes are only used to refuse early.  Pure: bytes in, bytes out.
"""

from __future__ import annotations

import io
import re
import zipfile
import zlib

from app.domain.errors import InvalidInput, TooLarge

CHUNK = 1 << 20
MAX_ZIP_RATIO = 200.0          # inflated / packed, refused beyond this once past BOMB_FLOOR
BOMB_FLOOR = 10_000_000        # bytes: small archives may compress as well as they like
MAX_MEMBERS = 10_000
_UNIT = re.compile(rb"<(?:\w+:)?model\b[^>]*?\bunit\s*=\s*[\"']([A-Za-z]+)[\"']", re.S)


class ArchiveError(InvalidInput):
    """The archive cannot be used; the message says why."""


def _bomb(inflated: int, packed: int) -> ArchiveError:
    return ArchiveError(f"3MF archive has a compression ratio of {inflated / max(packed, 1):.0f}:1, refused as "
                        f"a zip bomb", field="file", value=round(inflated / max(packed, 1)))


def inflate_zip(data: bytes, max_bytes: int) -> dict[str, bytes]:
    """Every member of the zip ``data`` inflated, {name: bytes}.

    Raises :class:`TooLarge` (413) once the real inflated total passes ``max_bytes``,
    :class:`ArchiveError` (422) for a broken archive or a zip bomb (ratio > 200:1 beyond
    10 MB), whatever the headers say.  Peak memory: the output so far plus one chunk.
    """
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
        infos = archive.infolist()
    except (zipfile.BadZipFile, ValueError, OSError, EOFError):
        raise ArchiveError("3MF file is not a valid zip archive", field="file") from None
    if len(infos) > MAX_MEMBERS:
        raise ArchiveError(f"the archive has {len(infos)} members (at most {MAX_MEMBERS})", field="file",
                           value=len(infos))
    declared = sum(info.file_size for info in infos)
    if declared > max_bytes:
        raise TooLarge(f"3MF archive would inflate to {declared} bytes (limit {max_bytes})", field="file",
                       value=declared)
    if declared > BOMB_FLOOR and declared / max(1, len(data)) > MAX_ZIP_RATIO:
        raise _bomb(declared, len(data))
    out: dict[str, bytes] = {}
    total = 0
    for info in infos:
        if info.is_dir():
            continue
        pieces = []
        try:
            with archive.open(info) as member:
                while chunk := member.read(CHUNK):
                    total += len(chunk)
                    if total > max_bytes:
                        raise TooLarge(f"3MF archive inflates to more than {max_bytes} bytes (the limit), "
                                       f"whatever its headers declare", field="file", value=total)
                    if total > BOMB_FLOOR and total / max(1, len(data)) > MAX_ZIP_RATIO:
                        raise _bomb(total, len(data))
                    pieces.append(chunk)
        except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError, ValueError,
                OSError) as exc:
            raise ArchiveError(f"3MF member {info.filename!r} cannot be inflated: {exc}"[:300], field="file",
                               value=info.filename) from None
        out[info.filename] = b"".join(pieces)
    return out


def stored_zip(members: dict[str, bytes]) -> bytes:
    """The members re-packed without compression (sizes are then honest)."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as archive:
        for name, payload in members.items():
            archive.writestr(name, payload)
    return buffer.getvalue()


def threemf_unit(members: dict[str, bytes]) -> str | None:
    """The ``unit`` attribute of the 3MF model element (None when absent)."""
    for name, payload in members.items():
        if name.lower().endswith(".model"):
            found = _UNIT.search(payload[:65536])
            if found:
                return found.group(1).decode("ascii").lower()
            return None
    return None
