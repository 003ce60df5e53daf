"""The one home of the core's tolerances (mm unless stated).

:class:`Tolerance`: the tolerances a caller may choose, passed explicitly to the geometry
functions that need them.  The module constants: the fixed thresholds that mean the same
thing wherever they are used (named here so that one meaning has one value):

* lengths: :data:`LENGTH_EPS_MM` (equal lengths, duplicate points, "inside" checks),
  :data:`DEGENERATE_LENGTH_MM` (a segment or span that is no length; division floors);
* parameters and round-off: :data:`DOMAIN_SLACK_REL`, :data:`ROUNDOFF_SLACK`,
  :data:`ROUNDOFF_REL`, :data:`DIVISION_FLOOR`;
* directions: :data:`VERTICAL_NZ` (a face is vertical);
* solvers: :data:`COVARIANCE_JITTER_REL` (kriging / Gaussian-process solves);
* storage: :data:`STORED_DECIMALS`.

Thresholds that are a documented parameter of one algorithm stay beside it (e.g. the
registration's ``step_tol_mm``, the joint planner's ``MIN_GAIN``, the surface fit's
``_LINE_REL``).
"""

from __future__ import annotations

from dataclasses import dataclass

from app.domain.checks import require_positive

__all__ = [
    "COVARIANCE_JITTER_REL", "DEFAULT_TOLERANCE", "DEGENERATE_LENGTH_MM", "DIVISION_FLOOR", "DOMAIN_SLACK_REL",
    "LENGTH_EPS_MM", "ROUNDOFF_REL", "ROUNDOFF_SLACK", "STORED_DECIMALS", "Tolerance", "VERTICAL_NZ",
]

#: lengths (mm) closer than this are equal: consecutive duplicate points (a zero-length
#: step), stations on top of each other, a bound "inside" a limit, a stored length matching
LENGTH_EPS_MM = 1e-9
#: a segment length or span (mm) at or below this is degenerate; also the floor of a
#: division by such a length
DEGENERATE_LENGTH_MM = 1e-12
#: relative slack (of the domain's size, at least 1) of "this parameter lies in its domain"
DOMAIN_SLACK_REL = 1e-9
#: absolute slack against round-off of unit-interval checks and of ceil() to a count
ROUNDOFF_SLACK = 1e-12
#: a quantity below this fraction of its own scale is round-off (parallel lines, a
#: vanishing derivative)
ROUNDOFF_REL = 1e-14
#: a unit normal with |n_z| at or below this is horizontal: its face is vertical
VERTICAL_NZ = 1e-12
#: the positive floor that keeps a ratio finite when its denominator may be exactly 0
DIVISION_FLOOR = 1e-300
#: diagonal jitter of a covariance solve, relative to the prior's variance (kriging, GP)
COVARIANCE_JITTER_REL = 1e-10
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
