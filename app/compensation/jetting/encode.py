"""Byte encodings of jetting outputs (no file system): 1-bit PNG patterns, NPZ archives."""

from __future__ import annotations

import io

import numpy as np
from PIL import Image


def pattern_png(pattern: np.ndarray, dpi: float | None = None) -> bytes:
    """(L, W) bool drop pattern -> 1-bit PNG bytes (white = drop), one pixel per cell."""
    image = Image.fromarray(np.asarray(pattern, dtype=bool))
    out = io.BytesIO()
    kwargs = {"dpi": (dpi, dpi)} if dpi else {}
    image.save(out, format="PNG", optimize=False, **kwargs)
    return out.getvalue()


def png_pattern(data: bytes) -> np.ndarray:
    """Inverse of ``pattern_png``: (L, W) bool."""
    return np.asarray(Image.open(io.BytesIO(data)).convert("1"), dtype=bool)


def npz_bytes(**arrays: np.ndarray) -> bytes:
    """Compressed NPZ of the named arrays, as bytes (deterministic content)."""
    out = io.BytesIO()
    np.savez_compressed(out, **arrays)
    return out.getvalue()


def npz_arrays(data: bytes) -> dict[str, np.ndarray]:
    """Inverse of ``npz_bytes``."""
    with np.load(io.BytesIO(data), allow_pickle=False) as archive:
        return {name: archive[name] for name in archive.files}
