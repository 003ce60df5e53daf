"""Probe physics of the mock printer: what a probing move touches and what it reads.

A probing move (``G38.2``/``G38.3`` to X Y Z, Marlin ``G30 X Y`` = straight down) starts at
the carriage position ``start`` and heads for ``target`` (commanded coordinates, mm).  The
machine really is ``e(t) = drift_mm_per_min * t / 60`` higher in Z (``t`` = the machine
clock), so the geometry is met by the actual body:

* tool T0, the touch probe: a ball of ``stylus_radius_mm`` centred on the carriage, against
  the part mesh (exact swept-ball contact with its faces, edges and vertices), the bed
  plane, the reference pad (a box) and the datum sphere (analytic);
* tool T>=1, a nozzle: a flat-ended vertical cylinder of its outer diameter with its tip
  at carriage + offset; it triggers only on the conductive artifacts (pad, sphere: the
  flat end or the side).  Driven into the part (its tip path meets the mesh before an
  artifact) it does not trigger and ``stats.collisions`` counts it.

The probe triggers ``delta`` further along the move than the first contact:
``delta(n) = pretravel + lobing * sin(theta) * cos(3 phi) + N(0, pretravel_sd)`` with ``n``
the unit contact normal (ball centre minus contact point, over r), theta its angle from
+Z, phi = atan2(n_y, n_x); a nozzle has no pre-travel, only ``N(0, touchoff_sd)``.  No
trigger when that passes the move's end.  The reading is the commanded carriage position
at the trigger plus ``probe_noise_mm`` scatter along the move (against its direction, so
a downward touch reads z + noise as before).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from .artifacts import PAD_DEPTH_MM
from .surface import PlacedSurface
from .sweep import (
    Contact,
    in_triangles,
    sweep_ball_plane,
    sweep_ball_sphere,
    sweep_ball_triangles,
    sweep_nozzle_box,
    sweep_nozzle_sphere,
)
from .world import MockWorld

if TYPE_CHECKING:
    import trimesh

_VERTICAL = np.array([0.0, 0.0, -1.0])
DUST_RADIUS_MM = 0.5  # a touch this close (xy) to a speck of MockWorld.probe_dust lands on it


def _xyz(values: Sequence[float] | np.ndarray) -> tuple[float, float, float]:
    """A point (3,) mm as three floats."""
    x, y, z = (float(v) for v in values)
    return x, y, z


class Touch(NamedTuple):
    """Outcome of a probing move: ``status`` "hit", "miss" or "inside" (touching before it
    moved); ``reading`` (3,) commanded mm where it stopped (the trigger, or the target on
    a miss, or the start when inside); ``travel_mm`` moved; ``what`` was touched."""

    status: str
    reading: tuple[float, float, float]
    travel_mm: float
    what: str | None


class MeshIndex:
    """The placed part's triangles with their bounding boxes, sorted by x-min, so a
    swept body's candidate triangles come from a strip search plus a box filter."""

    def __init__(self, mesh: trimesh.Trimesh) -> None:
        tris = np.asarray(mesh.vertices, dtype=float)[np.asarray(mesh.faces)]
        lo, hi = tris.min(axis=1), tris.max(axis=1)
        order = np.argsort(lo[:, 0], kind="stable")
        self.tris, self.lo, self.hi = tris[order], lo[order], hi[order]
        self.width = float((hi[:, 0] - lo[:, 0]).max()) if len(tris) else 0.0
        self.top = float(hi[:, 2].max()) + 1.0 if len(tris) else 0.0

    def near(self, start: np.ndarray, end: np.ndarray, radius: float) -> np.ndarray:
        """Triangles (k, 3, 3) whose boxes meet the box of the segment grown by ``radius``."""
        box_lo = np.minimum(start, end) - radius
        box_hi = np.maximum(start, end) + radius
        first = int(np.searchsorted(self.lo[:, 0], box_lo[0] - self.width, side="left"))
        last = int(np.searchsorted(self.lo[:, 0], box_hi[0], side="right"))
        lo, hi = self.lo[first:last], self.hi[first:last]
        keep = np.all(lo <= box_hi, axis=1) & np.all(hi >= box_lo, axis=1)
        return self.tris[first:last][keep]

    def crossings_above(self, point: np.ndarray) -> int:
        """How many faces a vertical ray up from ``point`` crosses (odd: inside the part)."""
        top = np.array([point[0], point[1], max(self.top, float(point[2]) + 1.0)])
        tris = self.near(point, top, 0.0)
        if len(tris) == 0:
            return 0
        a, b, c = tris[:, 0, :2], tris[:, 1, :2], tris[:, 2, :2]
        p = np.asarray(point[:2], float)

        def cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
            return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]

        w1, w2, w3 = cross(b - a, p - a), cross(c - b, p - b), cross(a - c, p - c)
        inside = ((w1 >= 0) & (w2 >= 0) & (w3 >= 0)) | ((w1 <= 0) & (w2 <= 0) & (w3 <= 0))
        area = cross(b - a, c - a)
        inside &= np.abs(area) > 1e-15
        if not inside.any():
            return 0
        t = tris[inside]
        area, w1, w2, w3 = area[inside], w1[inside], w2[inside], w3[inside]
        z = (w2 * t[:, 0, 2] + w3 * t[:, 1, 2] + w1 * t[:, 2, 2]) / area
        heights = np.unique(np.round(z[z > point[2] + 1e-9], 9))  # a ray through an edge counts once
        return int(len(heights))


def pad_triangles(centre: tuple[float, float, float], size: float, bed_z: float) -> np.ndarray:
    """The pad as a closed box of 12 triangles (12, 3, 3): top face at the centre's z, down
    to the bed (or ``PAD_DEPTH_MM`` deep when the top is not above the bed)."""
    lo, hi = box_bounds(centre, size, bed_z)
    corners = np.array([[x, y, z] for z in (lo[2], hi[2]) for y in (lo[1], hi[1])
                        for x in (lo[0], hi[0])])
    quads = [(0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5)]
    tris = []
    for a, b, c, d in quads:
        tris += [corners[[a, b, c]], corners[[a, c, d]]]
    return np.array(tris)


def box_bounds(centre: tuple[float, float, float], size: float, bed_z: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corners (3,) of the pad block."""
    cx, cy, top = centre
    bottom = bed_z if top > bed_z else top - PAD_DEPTH_MM
    half = size / 2.0
    return np.array([cx - half, cy - half, bottom]), np.array([cx + half, cy + half, top])


class ProbePhysics:
    """Contact and trigger model of one firmware instance (see module docstring)."""

    def __init__(self, world: MockWorld, surface: PlacedSurface, rng: np.random.Generator) -> None:
        self.world = world
        self.surface = surface
        self.rng = rng
        self._index: MeshIndex | None = None

    @property
    def index(self) -> MeshIndex:
        """The mesh index, built on first use (only physics-enabled touches on a part need it)."""
        if self._index is None:
            assert self.surface.mesh is not None, "a flat bed has no mesh to index"
            self._index = MeshIndex(self.surface.mesh)
        return self._index

    # ------------------------------------------------------------------ contacts
    def _part_contact(self, start: np.ndarray, direction: np.ndarray, length: float,
                      radius: float) -> Contact | None:
        if self.surface.mesh is None:
            return None
        vertical = bool(np.allclose(direction, _VERTICAL))
        if radius == 0.0 and vertical and self.world.pretravel_lobing_mm == 0.0:
            # the ideal probe: the same vertical ray cast as ever (exactly today's numbers)
            hits = [z for z in self.surface._hits(float(start[0]), float(start[1]))
                    if z <= start[2] + 1e-9]
            if not hits or start[2] - max(hits) > length + 1e-9:
                return None
            z = max(hits)
            return Contact(float(start[2] - z), np.array([start[0], start[1], z]),
                           np.array([0.0, 0.0, 1.0]))
        index = self.index
        end = start + direction * length
        return sweep_ball_triangles(start, direction, length, radius,
                                    index.near(start, end, radius))

    def _ball_contacts(self, start: np.ndarray, direction: np.ndarray, length: float
                       ) -> list[tuple[Contact, str]]:
        world, r = self.world, self.world.stylus_radius_mm
        found: list[tuple[Contact, str]] = []
        part = self._part_contact(start, direction, length, r)
        if part is not None:
            found.append((part, "part"))
        bed = sweep_ball_plane(start, direction, length, r, world.bed_z)
        if bed is not None:
            found.append((bed, "bed"))
        if world.pad is not None:
            tris = pad_triangles(world.pad.centre_mm, world.pad.size_mm, world.bed_z)
            pad = sweep_ball_triangles(start, direction, length, r, tris)
            if pad is not None:
                found.append((pad, "pad"))
        if world.sphere is not None:
            sphere = sweep_ball_sphere(start, direction, length, r, np.array(world.sphere.centre_mm),
                                       world.sphere.diameter_mm / 2.0)
            if sphere is not None:
                found.append((sphere, "sphere"))
        return found

    def started_inside(self, start: np.ndarray, exact_old: bool) -> bool:
        """The probe's axis starts inside the part (odd crossings above) or under the bed;
        ``exact_old``: with the ideal probe's ray cast, as the mock always did."""
        if start[2] < self.world.bed_z - 1e-9:
            return True
        if self.surface.mesh is None:
            return False
        if exact_old:
            above = [z for z in self.surface._hits(float(start[0]), float(start[1]))
                     if z > start[2] + 1e-9]
            return len(above) % 2 == 1
        return self.index.crossings_above(start) % 2 == 1

    # ------------------------------------------------------------------ a probing move
    def touch(self, start: tuple[float, float, float], target: tuple[float, float, float],
              tool: int) -> Touch:
        """Run one probing move from ``start`` to ``target`` (commanded mm) with ``tool``."""
        world = self.world
        start_c = np.asarray(start, float)
        offset = np.array([0.0, 0.0, world.drift_mm()])
        chord = np.asarray(target, float) - start_c
        length = float(np.linalg.norm(chord))
        if length <= 0.0:
            return Touch("miss", _xyz(start), 0.0, None)
        direction = chord / length
        world.stats.touches += 1
        what: str | None
        if tool == 0:
            actual = start_c + offset
            ideal = world.stylus_radius_mm == 0.0 and world.pretravel_lobing_mm == 0.0 \
                and bool(np.allclose(direction, _VERTICAL))
            if self.started_inside(actual, exact_old=ideal):
                return Touch("inside", _xyz(start), 0.0, None)
            found = self._ball_contacts(actual, direction, length)
            if not found:
                return Touch("miss", _xyz(target), length, None)
            contact, what = min(found, key=lambda f: f[0].s)
            if contact.s < -1e-9:
                return Touch("inside", _xyz(start), 0.0, what)
            delta = self.pretravel(contact.normal)
            # the ball centre at contact, back in commanded coordinates (bit-exact for r = 0)
            at_contact = contact.point + world.stylus_radius_mm * contact.normal - offset
        else:
            tool_spec = world.tools[tool - 1]
            tip = start_c + offset + np.asarray(tool_spec.offset_mm)
            contact_s, what = self._nozzle_contact(tip, direction, length,
                                                   tool_spec.outer_diameter_mm)
            self._count_collision(tip, direction, length if contact_s is None else max(contact_s, 0.0))
            if contact_s is None:
                return Touch("miss", _xyz(target), length, None)
            if contact_s < 0.0:
                return Touch("inside", _xyz(start), 0.0, what)
            contact = Contact(contact_s, tip + contact_s * direction, -direction)
            at_contact = start_c + contact_s * direction
            sd = world.touchoff_sd_mm
            delta = float(self.rng.normal(0.0, sd)) if sd > 0 else 0.0
        travel = max(contact.s + delta, 0.0)
        if travel > length + 1e-12:
            return Touch("miss", _xyz(target), length, what)
        reading = at_contact + delta * direction if travel > 0.0 else start_c
        for i, (x, y, dz) in enumerate(world.probe_dust):
            if i not in world.dust_gone and math.hypot(reading[0] - x, reading[1] - y) <= DUST_RADIUS_MM:
                world.dust_gone.add(i)
                reading = reading - dz * direction
        noise = world.probe_noise_mm
        if noise > 0:
            reading = reading - float(self.noise_draw(noise)) * direction
        return Touch("hit", _xyz(reading), travel, what)

    def noise_draw(self, sd: float) -> float:
        return float(self.rng.normal(0.0, sd))

    def pretravel(self, normal: np.ndarray) -> float:
        """delta(n) mm: mean + 3-lobed direction term + scatter (see module docstring)."""
        world = self.world
        delta = world.pretravel_mm
        if world.pretravel_lobing_mm:
            nz = float(np.clip(normal[2], -1.0, 1.0))
            theta = math.acos(nz)
            phi = math.atan2(float(normal[1]), float(normal[0]))
            delta += world.pretravel_lobing_mm * math.sin(theta) * math.cos(3.0 * phi)
        if world.pretravel_sd_mm:
            delta += float(self.rng.normal(0.0, world.pretravel_sd_mm))
        return delta

    def _nozzle_contact(self, tip: np.ndarray, direction: np.ndarray, length: float,
                        diameter: float) -> tuple[float | None, str | None]:
        world = self.world
        found: list[tuple[float, str]] = []
        if world.pad is not None:
            lo, hi = box_bounds(world.pad.centre_mm, world.pad.size_mm, world.bed_z)
            s = sweep_nozzle_box(tip, direction, length, diameter, lo, hi)
            if s is not None:
                found.append((s, "pad"))
        if world.sphere is not None:
            s = sweep_nozzle_sphere(tip, direction, length, diameter, np.array(world.sphere.centre_mm),
                                    world.sphere.diameter_mm / 2.0)
            if s is not None:
                found.append((s, "sphere"))
        if not found:
            return None, None
        return min(found)

    def nozzle_move(self, start_tip: tuple, end_tip: tuple) -> None:
        """A plain move (G0/G1) of a nozzle: its tip path crossing the part's surface (or
        reaching the bed) counts one collision (the body beside the tip is not checked)."""
        a = np.asarray(start_tip, float)
        chord = np.asarray(end_tip, float) - a
        length = float(np.linalg.norm(chord))
        if length > 0.0:
            self._count_collision(a, chord / length, length)

    def _count_collision(self, tip: np.ndarray, direction: np.ndarray, length: float) -> None:
        """A nozzle's tip path entering the part (crossing a face against its outward
        normal) or going below the bed counts one collision; leaving does not count."""
        if length <= 0.0:
            return
        entered = False
        if self.surface.mesh is not None:
            tris = self.index.near(tip, tip + direction * length, 0.0)
            if len(tris):
                a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
                n = np.cross(b - a, c - a)  # outward for a consistently wound (trimesh) part
                v = n @ direction
                going_in = v < -1e-15
                if going_in.any():
                    n, a, b, c, v = n[going_in], a[going_in], b[going_in], c[going_in], v[going_in]
                    s = np.einsum("ij,ij->i", a - tip, n) / v
                    q = tip + s[:, None] * direction
                    entered = bool(np.any((s >= 0.0) & (s <= length) & in_triangles(q, a, b, c)))
        end_z = tip[2] + direction[2] * length
        if entered or (tip[2] >= self.world.bed_z > end_z):
            self.world.stats.collisions += 1
