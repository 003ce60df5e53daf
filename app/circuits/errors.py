"""The circuits core's exceptions (all 422): each names the file and the line or entity."""

from __future__ import annotations

from typing import Any

from app.domain.errors import InvalidInput

__all__ = ["CircuitFileError", "LayoutError", "WarpError"]


class CircuitFileError(InvalidInput):
    """A circuit file that cannot be read: ``value`` names the file's line or entity."""

    def __init__(self, message: str, *, file: str, where: Any = None, field: str = "file") -> None:
        where_text = f" ({where})" if where is not None else ""
        super().__init__(f"{file}{where_text}: {message}", field=field,
                         value={"file": file, "at": where} if where is not None else {"file": file})


class LayoutError(InvalidInput):
    """Placement or mapping options (or the layout against the part) that cannot be used."""


class WarpError(InvalidInput):
    """A program that cannot be warped: ``value`` names the line (1-based) and its text."""
