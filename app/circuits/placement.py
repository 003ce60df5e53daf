"""Placing a flat layout in the part's top view: mirror (x -> -x), then rotate, then move.

A layout point x (2,) mm goes to ``origin + R(rotation) @ M @ (x - anchor)`` with
M = diag(-1, 1) when mirrored: the layout's ``anchor`` (its own (0, 0), or the board's centre:
:func:`board_center`) lands on ``origin``.  Curves are moved exactly (affine maps act on NURBS
control points).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from app.circuits.curves import transformed
from app.circuits.layout import Area, Layout, LayoutTrace, Pad, Via

__all__ = ["LayoutPlacement", "place_layout", "board_center"]


@dataclass(frozen=True)
class LayoutPlacement:
    """Where a flat layout lies in the part's top view (2-D, may mirror: not the rigid 3-D
    :class:`app.geometry.placement.Placement`).  origin_mm: where the layout's (0, 0) lands
    (top view, mm); rotation_deg CCW; mirror x; anchor_mm: the layout point that lands on
    origin_mm (layout mm)."""

    origin_mm: tuple[float, float] = (0.0, 0.0)
    rotation_deg: float = 0.0
    mirror: bool = False
    anchor_mm: tuple[float, float] = (0.0, 0.0)

    @property
    def matrix(self) -> npt.NDArray[np.float64]:
        """The linear part (2, 2): rotation after mirror."""
        a = np.radians(self.rotation_deg)
        rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        return rot @ np.diag([-1.0 if self.mirror else 1.0, 1.0])

    def apply(self, points: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Points (k, 2) layout mm -> top view mm."""
        top: npt.NDArray[np.float64] = ((np.asarray(points, float) - np.asarray(self.anchor_mm, float)) @ self.matrix.T
                                         + np.asarray(self.origin_mm, float))
        return top


def _ccw(ring: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    x, y = ring[:, 0], ring[:, 1]
    area2 = float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))
    return ring if area2 >= 0 else ring[::-1]


def place_layout(layout: Layout, placement: LayoutPlacement, *, relative: bool = False) -> Layout:
    """The layout moved by ``placement``; ``relative`` leaves out the origin (vectors from it)."""
    m = placement.matrix
    offset = (np.zeros(2) if relative else np.asarray(placement.origin_mm, float)) - m @ np.asarray(
        placement.anchor_mm, float)
    traces = [LayoutTrace(transformed(t.curve, m, offset), t.source) for t in layout.traces]
    pads = [Pad(p.shape, m @ p.center + offset, _ccw(p.exterior @ m.T + offset), p.source, p.name)
            for p in layout.pads]
    areas = [Area(_ccw(a.exterior @ m.T + offset), tuple(h @ m.T + offset for h in a.holes), a.source)
             for a in layout.areas]
    vias = [Via(m @ v.center + offset, v.diameter_mm, v.drill_mm, v.net, v.layers) for v in layout.vias]
    outline = [_ccw(r @ m.T + offset) for r in layout.outline]
    return replace(layout, traces=traces, pads=pads, areas=areas, vias=vias, outline=outline)


def board_center(layouts: list[Layout]) -> npt.NDArray[np.float64]:
    """The centre (2,) layout mm of a board given as one or more files: the middle of its
    outline's bounding box (the largest Edge.Cuts / profile ring of any file), else of
    everything printed (traces, pads, areas) in all files."""
    rings = [r for layout in layouts for r in layout.outline]
    if rings:
        ring = max(rings, key=lambda r: float(np.ptp(r[:, 0]) * np.ptp(r[:, 1])))
        center: npt.NDArray[np.float64] = 0.5 * (ring.min(axis=0) + ring.max(axis=0))
        return center
    boxes = [layout.bounds() for layout in layouts if layout.traces or layout.pads or layout.areas]
    if not boxes:
        return np.zeros(2)
    both = np.vstack(boxes)
    middle: npt.NDArray[np.float64] = 0.5 * (both.min(axis=0) + both.max(axis=0))
    return middle
