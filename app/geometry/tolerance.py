"""One explicit tolerance object for the geometry core (mm unless stated)."""

from __future__ import annotations

from dataclasses import dataclass

from app.checks import require_positive

__all__ = ["Tolerance", "DEFAULT_TOLERANCE", "DUPLICATE_POINT_MM", "STORED_DECIMALS"]

#: two consecutive polyline points closer than this (mm) are one point (a zero-length step)
DUPLICATE_POINT_MM = 1e-9
#: stored coordinates (a trace's nominal polyline) are rounded to this many decimals of a mm
STORED_DECIMALS = 6


@dataclass(frozen=True)
class Tolerance:
    """Tolerances passed explicitly to every geometry function that needs one.

    chord_mm: max distance of an emitted polyline from the curve it stands for.
    dedup_mm: two points closer than this are the same point (duplicates).
    snap_mm: max distance of a 3-D trace point from the surface it should lie on.
    param_rel: relative convergence of parameter searches (inversion, arc length).
    length_rel: relative accuracy of arc-length integration.
    """

    chord_mm: float = 0.001
    dedup_mm: float = 1e-6
    snap_mm: float = 0.05
    param_rel: float = 1e-12
    length_rel: float = 1e-10

    def __post_init__(self) -> None:
        from app.geometry.errors import GeometryError

        require_positive(self, ("chord_mm", "dedup_mm", "snap_mm", "param_rel", "length_rel"),
                         GeometryError)


DEFAULT_TOLERANCE = Tolerance()
