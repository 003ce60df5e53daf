"""Byte encodings of jetting outputs (no file system): 1-bit PNG patterns, NPZ archives.

Both are byte-identical for identical inputs (the NPZ members carry a fixed timestamp),
so re-running a job reproduces its artifacts exactly.
"""

from __future__ import annotations

import io
import zipfile

import numpy as np
import numpy.typing as npt
from PIL import Image

FIXED_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def pattern_png(pattern: npt.NDArray[np.bool_], dpi: float | None = None) -> bytes:
    """(L, W) bool drop pattern -> 1-bit PNG bytes (white = drop), one pixel per cell."""
    image = Image.fromarray(np.asarray(pattern, dtype=bool))
    out = io.BytesIO()
    kwargs = {"dpi": (dpi, dpi)} if dpi else {}
    image.save(out, format="PNG", optimize=False, **kwargs)
    return out.getvalue()


def png_pattern(data: bytes) -> npt.NDArray[np.bool_]:
    """Inverse of ``pattern_png``: (L, W) bool."""
    return np.asarray(Image.open(io.BytesIO(data)).convert("1"), dtype=bool)


def npz_bytes(**arrays: npt.NDArray[np.generic] | np.generic) -> bytes:
    """Compressed NPZ (readable by ``numpy.load``) of the named arrays, as bytes."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, value in arrays.items():
            member = io.BytesIO()
            np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=FIXED_ZIP_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, member.getvalue())
    return out.getvalue()


def npz_arrays(data: bytes) -> dict[str, npt.NDArray[np.generic]]:
    """Inverse of ``npz_bytes`` (any NPZ without pickled objects)."""
    with np.load(io.BytesIO(data), allow_pickle=False) as archive:
        return {name: archive[name] for name in archive.files}
