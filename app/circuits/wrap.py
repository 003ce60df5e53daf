"""Length-preserving wrapping: the exponential map of a part's upper surface at an anchor.

A layout vector w (2,) mm from the anchor goes to the end of the surface geodesic that
leaves the anchor in the direction of w (in the anchor's tangent frame: e1 = the surface
direction seen as +x from above, e2 = n x e1) and runs |w| mm.  Distances from the anchor
along the surface therefore equal the layout's; on a developable part (a cylinder, a cone)
the map is an isometry, so every trace keeps its length; on a doubly curved part traces
stretch and the stretch is reported.

Geodesics are traced exactly on the faceted mesh ("straightest geodesics"): a straight
line within each facet; across an edge the direction is unfolded about the edge (its
component along the edge kept, the rest turned into the next facet).  Only upward facets
(n_z > ``min_normal_z``) belong to the upper surface; a geodesic that reaches a rim or a
downward facet leaves the part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import trimesh

from app.circuits.errors import LayoutError
from app.geometry.tolerance import DEGENERATE_LENGTH_MM

#: a ray whose exit rate through a triangle edge (outward normal . direction) is at or
#: below this does not leave the triangle through that edge (parallel or inward)
_LEAVE_RATE_FLOOR = 1e-15

__all__ = ["SurfaceWalker", "ExpMapResult"]


@dataclass(frozen=True)
class ExpMapResult:
    """points (n, 3) mm on the surface (NaN where the geodesic left the part); on_part (n,) bool."""

    points: npt.NDArray[np.float64]
    on_part: npt.NDArray[np.bool_]


class SurfaceWalker:
    """Geodesic shooting on a mesh's upper surface (precomputed facet frames and neighbours)."""

    def __init__(self, mesh: trimesh.Trimesh, min_normal_z: float = 0.05) -> None:
        faces = np.asarray(mesh.faces)
        verts = np.asarray(mesh.vertices, float)
        normals = np.asarray(mesh.face_normals, float).copy()
        normals[normals[:, 2] < 0] *= -1.0
        self.mesh = mesh
        self._up = np.abs(np.asarray(mesh.face_normals)[:, 2]) > min_normal_z
        v0, v1, v2 = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
        e1 = v1 - v0
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        e2 = np.cross(normals, e1)
        self._origin = v0.tolist()
        self._e1, self._e2 = e1.tolist(), e2.tolist()
        self._normals = normals.tolist()
        d1, d2 = v1 - v0, v2 - v0
        p2 = np.stack([np.zeros((len(faces), 2)), np.column_stack([(d1 * e1).sum(1), (d1 * e2).sum(1)]),
                       np.column_stack([(d2 * e1).sum(1), (d2 * e2).sum(1)])], axis=1)
        self._p2 = p2.tolist()
        self._verts = verts
        self._faces = faces
        self._neighbors = self._neighbor_table(mesh, faces)

    @staticmethod
    def _neighbor_table(mesh: trimesh.Trimesh, faces: npt.NDArray[np.int64]) -> list[list[int]]:
        """(F, 3) face across local edge j (vertices j, j+1), -1 at a rim."""
        table = -np.ones((len(faces), 3), dtype=np.int64)
        pairs = np.asarray(mesh.face_adjacency)
        edges = np.sort(np.asarray(mesh.face_adjacency_edges), axis=1)
        for side in (0, 1):
            f = pairs[:, side]
            other = pairs[:, 1 - side]
            for j in range(3):
                a, b = faces[f, j], faces[f, (j + 1) % 3]
                match = (np.minimum(a, b) == edges[:, 0]) & (np.maximum(a, b) == edges[:, 1])
                table[f[match], j] = other[match]
        return table.tolist()

    def locate(self, xy: npt.NDArray[np.float64]) -> tuple[int, npt.NDArray[np.float64]]:
        """The upper-surface facet above xy (2,) and the surface point; LayoutError if none."""
        top = float(self.mesh.bounds[1, 2]) + 1.0
        face = int(self.mesh.ray.intersects_first([[xy[0], xy[1], top]], [[0.0, 0.0, -1.0]])[0])
        if face < 0 or not self._up[face]:
            raise LayoutError(f"the anchor x={xy[0]:.6g}, y={xy[1]:.6g} is not over the part's upper surface",
                              field="origin_mm", value=[float(xy[0]), float(xy[1])])
        n = np.asarray(self._normals[face])
        v0 = np.asarray(self._origin[face])
        z = v0[2] - (n[0] * (xy[0] - v0[0]) + n[1] * (xy[1] - v0[1])) / n[2]
        return face, np.array([xy[0], xy[1], z])

    def frame(self, face: int) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Tangent frame at a facet: e1 = +x projected into the facet, e2 = n x e1 (both unit)."""
        n = np.asarray(self._normals[face])
        e1 = np.array([1.0, 0.0, 0.0]) - n[0] * n
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(n, e1)

    def shoot(self, face: int, start: npt.NDArray[np.float64], direction: npt.NDArray[np.float64],
              length: float) -> npt.NDArray[np.float64] | None:
        """End point (3,) of the geodesic from ``start`` on ``face`` along the unit tangent
        ``direction`` (3,) for ``length`` mm; None if it leaves the upper surface."""
        o, e1, e2 = self._origin[face], self._e1[face], self._e2[face]
        rel = (start[0] - o[0], start[1] - o[1], start[2] - o[2])
        px = rel[0] * e1[0] + rel[1] * e1[1] + rel[2] * e1[2]
        py = rel[0] * e2[0] + rel[1] * e2[1] + rel[2] * e2[2]
        dx = direction[0] * e1[0] + direction[1] * e1[1] + direction[2] * e1[2]
        dy = direction[0] * e2[0] + direction[1] * e2[1] + direction[2] * e2[2]
        norm = math.hypot(dx, dy)
        dx, dy = dx / norm, dy / norm
        remaining = float(length)
        for _ in range(1_000_000):
            tri = self._p2[face]
            (x0, y0), (x1, y1), (x2, y2) = tri
            orient = 1.0 if (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0) > 0 else -1.0
            best_t, best_j = math.inf, -1
            for j in range(3):
                ax, ay = tri[j]
                bx, by = tri[(j + 1) % 3]
                nx, ny = orient * (by - ay), -orient * (bx - ax)      # outward edge normal
                rate = nx * dx + ny * dy
                if rate <= _LEAVE_RATE_FLOOR:
                    continue                                         # the ray does not leave here
                t = (nx * (ax - px) + ny * (ay - py)) / rate
                if t < best_t:
                    best_t, best_j = t, j
            best_t = max(best_t, 0.0)
            if best_j < 0 or best_t >= remaining:
                step = remaining
                x, y = px + dx * step, py + dy * step
                return np.array([o[0] + x * e1[0] + y * e2[0], o[1] + x * e1[1] + y * e2[1],
                                 o[2] + x * e1[2] + y * e2[2]])
            remaining -= best_t
            px, py = px + dx * best_t, py + dy * best_t
            nxt = self._neighbors[face][best_j]
            if nxt < 0 or not self._up[nxt]:
                return None
            # 3-D point and direction, then unfold the direction about the shared edge
            p3 = (o[0] + px * e1[0] + py * e2[0], o[1] + px * e1[1] + py * e2[1], o[2] + px * e1[2] + py * e2[2])
            d3 = (dx * e1[0] + dy * e2[0], dx * e1[1] + dy * e2[1], dx * e1[2] + dy * e2[2])
            va = self._verts[self._faces[face][best_j]]
            vb = self._verts[self._faces[face][(best_j + 1) % 3]]
            ed = (vb[0] - va[0], vb[1] - va[1], vb[2] - va[2])
            el = math.sqrt(ed[0] ** 2 + ed[1] ** 2 + ed[2] ** 2)
            ed = (ed[0] / el, ed[1] / el, ed[2] / el)
            nf, ng = self._normals[face], self._normals[nxt]
            uf = (nf[1] * ed[2] - nf[2] * ed[1], nf[2] * ed[0] - nf[0] * ed[2], nf[0] * ed[1] - nf[1] * ed[0])
            ug = (ng[1] * ed[2] - ng[2] * ed[1], ng[2] * ed[0] - ng[0] * ed[2], ng[0] * ed[1] - ng[1] * ed[0])
            along = d3[0] * ed[0] + d3[1] * ed[1] + d3[2] * ed[2]
            across = d3[0] * uf[0] + d3[1] * uf[1] + d3[2] * uf[2]
            d3 = (along * ed[0] + across * ug[0], along * ed[1] + across * ug[1], along * ed[2] + across * ug[2])
            face = nxt
            o, e1, e2 = self._origin[face], self._e1[face], self._e2[face]
            rel = (p3[0] - o[0], p3[1] - o[1], p3[2] - o[2])
            px = rel[0] * e1[0] + rel[1] * e1[1] + rel[2] * e1[2]
            py = rel[0] * e2[0] + rel[1] * e2[1] + rel[2] * e2[2]
            dx = d3[0] * e1[0] + d3[1] * e1[1] + d3[2] * e1[2]
            dy = d3[0] * e2[0] + d3[1] * e2[1] + d3[2] * e2[2]
            norm = math.hypot(dx, dy)
            dx, dy = dx / norm, dy / norm
        return None

    def exp_map(self, anchor_xy: npt.NDArray[np.float64], vectors: npt.NDArray[np.float64]) -> ExpMapResult:
        """Surface points for layout vectors (n, 2) mm from the anchor (top view xy (2,))."""
        face, start = self.locate(np.asarray(anchor_xy, float))
        e1, e2 = self.frame(face)
        vec = np.asarray(vectors, float)
        out = np.full((len(vec), 3), np.nan)
        for i, (u, v) in enumerate(vec):
            r = math.hypot(u, v)
            if r < DEGENERATE_LENGTH_MM:
                out[i] = start
                continue
            end = self.shoot(face, start, (u * e1 + v * e2) / r, r)
            if end is not None:
                out[i] = end
        return ExpMapResult(out, np.isfinite(out[:, 0]))
