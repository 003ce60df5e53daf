"""What the mock point laser triangulation sensor reads: its optics against the true scene.

The spot sits at carriage + ``offset_mm`` (x, y) and the sensor's zero (the middle of its
measuring range, its reference distance) at carriage z + offset z; a reading is the height
of the lit surface above that zero: ``(h - z0 + bias) * (1 + scale_error) + noise``,
quantised to ``resolution_mm``, where

* ``h`` is the scene's top (the as-made part at its placement, the bed, material jetted on
  the bed, the reference pad's top, the datum sphere's cap: :class:`Scene`) averaged over the spot (``spot_mm``: the
  centre and six points on a circle of a third of the diameter);
* ``bias = slope_bias_mm * tan(theta)^2`` (theta: the surface's tilt from horizontal at the
  spot centre): a triangulation spot on a slope is stretched and its centroid moves;
* no value (the LK-G alarm) where theta exceeds ``acceptance_deg`` (too little light comes
  back), inside a marked dark or specular spot (``dark_spots`` (x, y, r) mm: a bare copper
  pad, a black mark), or at random with ``dropout_rate``; beyond ``range_mm`` the reading is
  over range.

Time: the value stamped at sampling instant t (machine clock) was exposed at
``t - time_offset_ms`` (the sensor's latency plus the start delay of its storage).
Units: mm, s (``time_offset_ms`` in ms).  Pure numpy/trimesh on the mock world's objects.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import InvalidConfig
from ..mock.surface import placement_matrix
from ..mock.world import MockWorld
from .optics_model import SPOT_PATTERN, optical_values, spot_points

__all__ = ["SPOT_PATTERN", "Scene", "SensorOptics", "readings"]


@dataclass
class SensorOptics:
    """The mock sensor head and controller (see module docstring).  Defaults: an LK-G32-like
    head (reference distance 30 mm, +-5 mm), 2 kHz storage, mounted beside the probe."""

    offset_mm: tuple[float, float, float] = (30.0, 5.0, -10.0)
    range_mm: float = 5.0
    resolution_mm: float = 0.0001
    noise_mm: float = 0.0005
    spot_mm: float = 0.03
    rate_hz: float = 2000.0
    acceptance_deg: float = 25.0
    time_offset_ms: float = 0.0
    scale_error: float = 0.0
    slope_bias_mm: float = 0.0
    dropout_rate: float = 0.0
    dark_spots: tuple[tuple[float, float, float], ...] = ()
    capacity: int = 65_536
    seed: int = 0
    rng: np.random.Generator = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.offset_mm = tuple(float(v) for v in self.offset_mm)  # type: ignore[assignment]
        if len(self.offset_mm) != 3 or not all(math.isfinite(v) for v in self.offset_mm):
            raise InvalidConfig("offset_mm must be three finite numbers", field="offset_mm",
                                value=str(self.offset_mm)[:60])
        for name in ("range_mm", "rate_hz", "acceptance_deg"):
            if not float(getattr(self, name)) > 0:
                raise InvalidConfig(f"{name} must be > 0", field=name, value=getattr(self, name))
        for name in ("resolution_mm", "noise_mm", "spot_mm", "dropout_rate"):
            if not float(getattr(self, name)) >= 0:
                raise InvalidConfig(f"{name} must be >= 0", field=name, value=getattr(self, name))
        if not 1 <= int(self.capacity) <= 1_000_000:
            raise InvalidConfig("capacity must be within 1..1000000", field="capacity", value=self.capacity)
        self.dark_spots = tuple((float(x), float(y), float(r)) for x, y, r in self.dark_spots)
        self.rng = np.random.default_rng(self.seed)


class Scene:
    """The mock world's top as the sensor sees it: heights and normals at many xy at once."""

    def __init__(self, world: MockWorld) -> None:
        self.world = world
        self.mesh = None
        if world.true_part is not None:
            placed = world.true_part.copy()
            placed.apply_transform(placement_matrix(world.placement))
            self.mesh = placed
            self.top = float(placed.bounds[1][2]) + 1.0

    def top_z(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Height (n,) mm and unit normal (n, 3) of the topmost surface at xy (n, 2)."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        n = len(xy)
        world = self.world
        z = np.full(n, float(world.bed_z))
        normal = np.tile([0.0, 0.0, 1.0], (n, 1))
        if self.mesh is not None and n:
            origins = np.column_stack([xy, np.full(n, self.top)])
            tris, rays, where = self.mesh.ray.intersects_id(origins, np.tile([0.0, 0.0, -1.0], (n, 1)),
                                                            multiple_hits=False, return_locations=True)
            higher = where[:, 2] > z[rays]
            z[rays[higher]] = where[higher, 2]
            normal[rays[higher]] = self.mesh.face_normals[tris[higher]]
        for surface in world.surfaces:  # jetted material on the bed (the mock printhead's field)
            dz, on = surface.top(xy)
            higher = on & (world.bed_z + dz > z)
            z[higher] = world.bed_z + dz[higher]
            normal[higher] = (0.0, 0.0, 1.0)
        pad = world.pad
        if pad is not None:
            cx, cy, top = pad.centre_mm
            half = pad.size_mm / 2.0
            on = (np.abs(xy[:, 0] - cx) <= half) & (np.abs(xy[:, 1] - cy) <= half) & (top > z)
            z[on] = top
            normal[on] = (0.0, 0.0, 1.0)
        sphere = world.sphere
        if sphere is not None:
            c = np.asarray(sphere.centre_mm, dtype=float)
            r = sphere.diameter_mm / 2.0
            d2 = np.sum((xy - c[:2]) ** 2, axis=1)
            cap = c[2] + np.sqrt(np.maximum(r * r - d2, 0.0))
            on = (d2 < r * r) & (cap > z)
            z[on] = cap[on]
            normal[on] = (np.column_stack([xy[on], cap[on]]) - c) / r
        return z, normal


def readings(optics: SensorOptics, scene: Scene, carriage: np.ndarray) -> np.ndarray:
    """Readings (n,) mm (NaN: no value) with the carriage at ``carriage`` (n, 3) mm at the
    exposure instants (see module docstring; beyond +-range the value is kept: the
    output format turns it into over-range)."""
    p = np.asarray(carriage, dtype=float).reshape(-1, 3)
    n = len(p)
    offset = np.asarray(optics.offset_mm)
    spot = p[:, :2] + offset[:2]
    points = spot_points(spot, optics.spot_mm)
    z_all, normals = scene.top_z(points.reshape(-1, 2))
    k = points.shape[1]
    lost = np.zeros(n, dtype=bool)
    for x, y, r in optics.dark_spots:
        lost |= np.hypot(spot[:, 0] - x, spot[:, 1] - y) <= r
    return optical_values(z_all.reshape(n, k), normals.reshape(n, k, 3)[:, 0, 2], p[:, 2] + offset[2], optics.rng,
                          noise_mm=optics.noise_mm, resolution_mm=optics.resolution_mm,
                          scale_error=optics.scale_error, slope_bias_mm=optics.slope_bias_mm,
                          acceptance_deg=optics.acceptance_deg, dropout_rate=optics.dropout_rate, lost=lost)
