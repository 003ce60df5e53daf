"""Probe paths over pads and areas, so their fills are compensated from stations ON them.

A pad or area is not a trace, so a closed loop over the import's traces alone would only
extrapolate the measured deviation under it.  Each pad / area gets a *probe path*: a closed
ring inside its outline, halfway between its rim and its middle (the outline shrunk by half
its inradius, approximated as 2 A / P: exact for a disk and a square), left open by its
closing segment (so a planner's first and last stations are distinct points), stored as a
trace the closed loop probes like any other (the circuit program prints it only as the
pad's fill).

Units: mm, top view.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from shapely.geometry import Polygon

__all__ = ["probe_ring"]

MIN_RING_MM = 0.02


def probe_ring(outline_xy: npt.NDArray[np.float64],
               holes: list[npt.NDArray[np.float64]] | None = None) -> npt.NDArray[np.float64] | None:
    """The ring (k, 2) mm inside the outline (n, 2) mm, half way in from its rim, open by its
    closing segment (see the module doc); None when the outline encloses no area."""
    poly = Polygon(np.asarray(outline_xy, float), [np.asarray(h, float) for h in holes or []])
    if not poly.is_valid:
        poly = poly.buffer(0)
    if poly.is_empty or poly.area <= 0.0:
        return None
    inradius = 2.0 * poly.area / poly.length
    inner = poly.buffer(-0.5 * inradius)
    if inner.is_empty:
        return None
    if inner.geom_type == "MultiPolygon":
        inner = max(inner.geoms, key=lambda g: g.area)
    ring = np.asarray(inner.simplify(1e-4).exterior.coords)[:-1, :2]
    if inner.length < MIN_RING_MM or len(ring) < 3:
        return None
    return ring
