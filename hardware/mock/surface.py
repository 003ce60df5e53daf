"""Where the mock's probe meets the as-made part: vertical rays against a placed mesh.

The true part (a ``trimesh.Trimesh``) is moved once by the world's ``TruePlacement``
(rotation about Z through the origin, then translation); the bed is the plane
``z = bed_z`` under it.  All lengths in mm."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from .world import TruePlacement

if TYPE_CHECKING:
    import trimesh


class ProbeHit(NamedTuple):
    """Result of a vertical probe: ``z`` of the first surface below the start (None when
    nothing is within reach) and whether the probe started inside the part."""

    z: float | None
    started_inside: bool


def placement_matrix(placement: TruePlacement) -> np.ndarray:
    """4x4 homogeneous transform of ``placement`` (rotation about Z, then translation)."""
    angle = math.radians(placement.rz_deg)
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0, placement.dx], [s, c, 0.0, placement.dy],
                     [0.0, 0.0, 1.0, placement.dz], [0.0, 0.0, 0.0, 1.0]])


class PlacedSurface:
    """The as-made part at its placement, answering vertical probe queries."""

    def __init__(self, mesh: trimesh.Trimesh | None, placement: TruePlacement, bed_z: float) -> None:
        self.bed_z = float(bed_z)
        self.mesh: trimesh.Trimesh | None = None
        if mesh is not None:
            placed = mesh.copy()
            placed.apply_transform(placement_matrix(placement))
            self.mesh = placed
            self._top = float(placed.bounds[1][2]) + 1.0

    def true_z(self, x: float, y: float) -> float:
        """Height of the topmost surface (part or bed) at (x, y)."""
        hits = self._hits(x, y)
        return max(hits) if hits else self.bed_z

    def _hits(self, x: float, y: float) -> list[float]:
        if self.mesh is None:
            return []
        origin = np.array([[x, y, self._top]])
        locations, _, _ = self.mesh.ray.intersects_location(
            origin, np.array([[0.0, 0.0, -1.0]]), multiple_hits=True)
        return sorted((float(p[2]) for p in locations), reverse=True)

    def probe(self, x: float, y: float, z_start: float, z_min: float) -> ProbeHit:
        """First surface met moving down from ``z_start`` to ``z_min`` at (x, y)."""
        hits = self._hits(x, y)
        above = [z for z in hits if z > z_start + 1e-9]
        inside = len(above) % 2 == 1 or z_start < self.bed_z - 1e-9
        below = [z for z in hits if z <= z_start + 1e-9] + [self.bed_z]
        candidates = [z for z in below if z <= z_start + 1e-9]
        z = max(candidates) if candidates else None
        if z is not None and z < z_min:
            z = None
        return ProbeHit(z, inside)
