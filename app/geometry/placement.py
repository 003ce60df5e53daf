"""The one rigid placement of the core: where a part frame sits in a machine frame (pure).

A :class:`Placement` is a rotation ``rz`` about the vertical axis through the pivot
``(pivot_x, pivot_y, 0)`` followed by a translation ``(dx, dy, dz)``:

    machine = R(rz) (part - pivot) + pivot + (dx, dy, dz),

i.e. ``machine = rotation() @ part + translation()`` with ``rotation()`` (3, 3) and
``translation()`` (3,) mm; ``matrix()`` is the same as a (4, 4) homogeneous transform.
Lengths mm, angles rad inside (``rz_deg`` / :meth:`Placement.from_deg` at the boundary).

Rotations about z and translations form a group, so :meth:`Placement.inverse` and
:meth:`Placement.compose` stay Placements (with the same pivot as the operand applied
first).  Users: registration (the fitted placement of a part), the reference part's
as-made variants (about the part centre), and the G-code bed placement (a translation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.geometry.errors import GeometryError

__all__ = ["Placement", "PlacementInputError", "apply_placement", "remove_placement"]


class PlacementInputError(GeometryError):
    """Points that cannot be placed (not a finite (n, 2) or (n, 3) array): 422."""


def _as_points(points: Any, field: str) -> np.ndarray:
    """``points`` as a finite float (n, 2|3) array, else :class:`PlacementInputError`."""
    try:
        p = np.asarray(points, dtype=float)
    except (TypeError, ValueError) as exc:
        raise PlacementInputError(f"{field} must be numeric", field=field, value=str(points)[:60]) from exc
    if p.ndim != 2 or p.shape[1] not in (2, 3) or not np.isfinite(p).all():
        raise PlacementInputError(f"{field} must be a finite (n, 2) or (n, 3) array", field=field,
                                  value=list(p.shape))
    return p


@dataclass(frozen=True)
class Placement:
    """Rigid placement part -> machine: rotation ``rz_rad`` about the vertical axis through
    (``pivot_x``, ``pivot_y``), then translation (``dx``, ``dy``, ``dz``); mm and rad."""

    dx: float = 0.0
    dy: float = 0.0
    dz: float = 0.0
    rz_rad: float = 0.0
    pivot_x: float = 0.0
    pivot_y: float = 0.0

    @property
    def rz_deg(self) -> float:
        return math.degrees(self.rz_rad)

    @classmethod
    def from_deg(cls, dx: float = 0.0, dy: float = 0.0, dz: float = 0.0, rz_deg: float = 0.0,
                 pivot_xy: tuple[float, float] = (0.0, 0.0)) -> Placement:
        """The placement with ``rz`` given in degrees (counter-clockwise seen from +z)."""
        return cls(dx, dy, dz, math.radians(rz_deg), float(pivot_xy[0]), float(pivot_xy[1]))

    @classmethod
    def translation_by(cls, shift: Any) -> Placement:
        """A pure translation by ``shift`` (3,) mm."""
        d = np.asarray(shift, dtype=float).reshape(3)
        return cls(float(d[0]), float(d[1]), float(d[2]))

    def rotation(self) -> np.ndarray:
        """(3, 3) rotation matrix R(rz)."""
        c, s = math.cos(self.rz_rad), math.sin(self.rz_rad)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def translation(self) -> np.ndarray:
        """(3,) mm: ``t`` in ``machine = R part + t`` (pivot folded in)."""
        rot = self.rotation()
        pivot = np.array([self.pivot_x, self.pivot_y, 0.0])
        out: np.ndarray = pivot - rot @ pivot + np.array([self.dx, self.dy, self.dz])
        return out

    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous part -> machine transform."""
        out = np.eye(4)
        out[:3, :3] = self.rotation()
        out[:3, 3] = self.translation()
        return out

    def apply(self, points: Any) -> np.ndarray:
        """Part-frame points (n, 2|3) mm -> machine frame (same shape); xy-only input ignores dz."""
        p = _as_points(points, "points")
        full = np.column_stack([p, np.zeros(len(p))]) if p.shape[1] == 2 else p
        m = self.matrix()
        out: np.ndarray = full @ m[:3, :3].T + m[:3, 3]
        return out[:, :p.shape[1]]

    def remove(self, points: Any) -> np.ndarray:
        """Machine-frame points (n, 2|3) mm -> part frame (the inverse of :meth:`apply`)."""
        p = _as_points(points, "points")
        full = np.column_stack([p, np.zeros(len(p))]) if p.shape[1] == 2 else p
        m = self.matrix()
        out: np.ndarray = (full - m[:3, 3]) @ m[:3, :3]
        return out[:, :p.shape[1]]

    def rotate(self, vectors: Any) -> np.ndarray:
        """Directions (n, 3) (e.g. unit normals) in the part frame -> machine frame (no translation)."""
        out: np.ndarray = np.asarray(vectors, dtype=float) @ self.rotation().T
        return out

    def inverse(self) -> Placement:
        """The placement machine -> part: R(-rz) about the same pivot, translation -R(-rz) d."""
        back = Placement(0.0, 0.0, 0.0, -self.rz_rad, self.pivot_x, self.pivot_y).rotation()
        d = -(back @ np.array([self.dx, self.dy, self.dz]))
        return Placement(float(d[0]), float(d[1]), float(d[2]), -self.rz_rad, self.pivot_x, self.pivot_y)

    def compose(self, first: Placement) -> Placement:
        """``self`` after ``first``: the placement p -> self(first(p)); its matrix is
        ``self.matrix() @ first.matrix()``.  Pivot: ``first``'s."""
        pivot = np.array([first.pivot_x, first.pivot_y, 0.0])
        t = self.rotation() @ first.translation() + self.translation()
        rz = self.rz_rad + first.rz_rad
        # translation() of the result is pivot - R pivot + d = t  ->  d = t - pivot + R pivot
        d = t - pivot + Placement(rz_rad=rz).rotation() @ pivot
        return Placement(float(d[0]), float(d[1]), float(d[2]), rz, first.pivot_x, first.pivot_y)

    def to_dict(self) -> dict[str, Any]:
        """The API / stored form: {dx, dy, dz (mm), rz_deg, pivot [x, y] (mm)}."""
        return {"dx": self.dx, "dy": self.dy, "dz": self.dz, "rz_deg": self.rz_deg,
                "pivot": [self.pivot_x, self.pivot_y]}


def apply_placement(points: Any, placement: Placement) -> np.ndarray:
    """Part-frame points (n, 2|3) -> machine frame: ``placement.apply(points)``."""
    return placement.apply(points)


def remove_placement(points: Any, placement: Placement) -> np.ndarray:
    """Machine-frame points (n, 2|3) -> part frame: ``placement.remove(points)``."""
    return placement.remove(points)
