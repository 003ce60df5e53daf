"""Does a re-check agree with the previous calibration?  (mm, 1-sigma std per field)"""

from __future__ import annotations

import math
from collections.abc import Mapping

__all__ = ["disagreements"]


def disagreements(old: Mapping[str, float], new: Mapping[str, float], std_old: Mapping[str, float],
                  std_new: Mapping[str, float], *, k: float = 3.0, floor_mm: float = 0.002) -> dict[str, float]:
    """Fields (present in both) whose change ``new - old`` exceeds ``k sqrt(s_old^2 + s_new^2) + floor_mm``.

    Returns {field: change mm}.  A missing std counts as 0 (only the floor then).  The floor
    covers what the std leaves out (temperature, re-seating the stylus).
    """
    out: dict[str, float] = {}
    for key in sorted(set(old) & set(new)):
        change = float(new[key]) - float(old[key])
        bound = k * math.hypot(float(std_old.get(key, 0.0)), float(std_new.get(key, 0.0))) + floor_mm
        if not math.isfinite(change) or abs(change) > bound:
            out[key] = change
    return out
