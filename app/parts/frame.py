"""A part's frame at intake: the file's units and which of its axes is up (pure).

Every stored part is in millimetres with +Z up.  A file declares its units (3MF ``unit``,
glTF/GLB metres by specification) or does not (STL, OBJ, PLY, OFF: millimetres unless the
upload says otherwise); glTF is Y-up by specification.  :func:`part_frame` turns those
facts plus the user's choices into one linear map ``x_part = scale * R @ x_file``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from app.domain.errors import InvalidInput

Units = Literal["mm", "cm", "m", "um", "inch", "ft"]
Up = Literal["+z", "-z", "+y", "-y", "+x", "-x"]
MM_PER_UNIT: dict[str, float] = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "um": 0.001, "inch": 25.4, "ft": 304.8}
# 3MF <model unit="..."> values (3MF core spec 1.3, section 3.4) -> our names
THREEMF_UNITS = {"micron": "um", "millimeter": "mm", "centimeter": "cm", "inch": "inch", "foot": "ft",
                 "meter": "m"}
SMALLEST_SANE_MM = 1.0
LARGEST_SANE_MM = 1000.0


def _rx(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def _ry(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def _rz(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


# the rotation that brings the file's up axis to +Z (a quarter or half turn, exact)
_UP_TO_Z = {"+z": np.eye(3), "-z": _rx(180.0), "+y": _rx(90.0), "-y": _rx(-90.0), "+x": _ry(-90.0),
            "-x": _ry(90.0)}


@dataclass(frozen=True)
class PartFrame:
    """``x_part = scale * rotation @ x_file`` (mm).

    ``units``: the file's units; ``units_source``: "file" (declared by the format), "upload"
    (the user's ``units`` field) or "default" (none declared: mm); ``up``: the file's axis
    that becomes +Z; ``rotate_deg``: further rotations about X, then Y, then Z (deg);
    ``rotation``: (3, 3) the whole rotation.
    """

    units: str
    units_source: str
    up: str
    rotate_deg: tuple[float, float, float]
    scale: float
    rotation: np.ndarray

    @property
    def is_identity(self) -> bool:
        """True when the file's coordinates already are the part's."""
        return self.scale == 1.0 and bool(np.array_equal(self.rotation, np.eye(3)))

    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous transform from file to part coordinates."""
        out = np.eye(4)
        out[:3, :3] = self.scale * self.rotation
        return out

    def describe(self) -> dict:
        """What the part record stores (JSON)."""
        return {"units": self.units, "units_source": self.units_source, "up": self.up,
                "rotate_deg": list(self.rotate_deg), "scale_to_mm": self.scale,
                "rotation": np.round(self.rotation, 12).tolist()}


def declared_units(fmt: str, declared: str | None) -> str | None:
    """The units a file of format ``fmt`` declares (3MF: its ``unit`` attribute, already
    read; GLB: metres by specification); None when the format declares none."""
    if fmt == "3mf":
        return THREEMF_UNITS.get((declared or "millimeter").lower(), "mm")
    if fmt == "glb":
        return "m"
    return None


def part_frame(fmt: str, file_units: str | None, units: str | None = None, up: str | None = None,
               rotate_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> PartFrame:
    """The map from a file's coordinates to the part's (mm, +Z up).

    ``units``: the user's choice, overriding what the file declares; ``up``: the file's
    axis that points up (default ``+y`` for GLB, as glTF specifies, else ``+z``).
    Raises :class:`InvalidInput` naming ``units``, ``up`` or ``rotate_deg``.
    """
    if units is not None and units not in MM_PER_UNIT:
        raise InvalidInput(f"unknown units {units!r}; use one of {', '.join(MM_PER_UNIT)}", field="units",
                           value=units)
    chosen_up = up or ("+y" if fmt == "glb" else "+z")
    if chosen_up not in _UP_TO_Z:
        raise InvalidInput(f"unknown up axis {chosen_up!r}; use one of {', '.join(_UP_TO_Z)}", field="up",
                           value=chosen_up)
    angles = tuple(float(a) for a in rotate_deg)
    if len(angles) != 3 or not all(np.isfinite(angles)) or any(abs(a) > 360 for a in angles):
        raise InvalidInput("rotate_deg needs three finite angles within +-360 deg (about X, Y, Z)",
                           field="rotate_deg", value=list(rotate_deg))
    if units is not None:
        name, source = units, "upload"
    elif file_units is not None:
        name, source = file_units, "file"
    else:
        name, source = "mm", "default"
    rotation = _rz(angles[2]) @ _ry(angles[1]) @ _rx(angles[0]) @ _UP_TO_Z[chosen_up]
    rotation = np.where(np.abs(rotation) < 1e-15, 0.0, rotation)  # quarter turns stay exact
    return PartFrame(units=name, units_source=source, up=chosen_up, rotate_deg=angles,
                     scale=MM_PER_UNIT[name], rotation=rotation)


def size_warnings(extent_mm: np.ndarray, frame: PartFrame) -> list[str]:
    """Warnings when the part's largest extent (mm) looks like a units mistake."""
    largest = float(np.max(extent_mm)) if len(extent_mm) else 0.0
    hint = (f"read as {frame.units} ({frame.units_source}); if that is wrong, upload again with "
            f"units set (mm, cm, m, um, inch, ft)")
    if largest < SMALLEST_SANE_MM:
        return [f"the part is only {largest:.4g} mm across: {hint}"]
    if largest > LARGEST_SANE_MM:
        return [f"the part is {largest:.4g} mm across (over 1 m): {hint}"]
    return []


def parse_angles(text: str | None) -> tuple[float, float, float]:
    """``"rx,ry,rz"`` (deg) -> a tuple; None or "" -> no rotation.  InvalidInput names
    ``rotate_deg``."""
    if not text or not text.strip():
        return (0.0, 0.0, 0.0)
    try:
        values = tuple(float(v) for v in text.replace(" ", "").strip("[]").split(","))
    except ValueError:
        raise InvalidInput(f"rotate_deg must be three numbers 'rx,ry,rz', got {text!r}", field="rotate_deg",
                           value=text) from None
    if len(values) != 3:
        raise InvalidInput(f"rotate_deg must be three numbers 'rx,ry,rz', got {text!r}", field="rotate_deg",
                           value=text)
    return values
