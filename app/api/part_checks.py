"""What an uploaded part must be before it is stored: finite, bounded and not degenerate.

The mesh parser (``app.parts.intake``) already refuses NaN/inf and unparsable files; this
refuses what parses but cannot be worked on: coordinates beyond ``COORDINATE_LIMIT_MM``
(1e200 overflows every area, normal and distance computed later) and meshes whose every
face has zero area (nothing to drape a trace onto).
"""

from __future__ import annotations

import math

from app.domain.errors import InvalidInput
from app.platform.models import Part

# A shared bound for coordinates in millimetres (1 km): far beyond any printer's work
# volume, far below where squares and cross products overflow or lose all precision.
COORDINATE_LIMIT_MM = 1e6


def check_part_geometry(part: Part) -> None:
    """InvalidInput (field ``file``) unless the part's bounds are finite and within
    ±``COORDINATE_LIMIT_MM`` and its surface area is positive and finite."""
    corners = [float(v) for corner in part.bounds for v in corner]
    worst = max((abs(v) for v in corners), default=0.0)
    if not all(math.isfinite(v) for v in corners) or worst > COORDINATE_LIMIT_MM:
        raise InvalidInput(f"the mesh's coordinates reach {worst:.6g} mm; they must be finite and within "
                           f"±{COORDINATE_LIMIT_MM:g} mm", field="file", value=worst)
    area = float(part.area_mm2)
    if not math.isfinite(area) or area <= 0.0:
        raise InvalidInput(f"the mesh has no surface: every face is degenerate (area {area:g} mm²)",
                           field="file", value=area)
    if part.volume_mm3 is not None and not math.isfinite(float(part.volume_mm3)):
        raise InvalidInput("the mesh's volume is not finite", field="file", value=str(part.volume_mm3))
