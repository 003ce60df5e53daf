"""The height-compensation paper's reference case as a fixture and demo dataset (pure: no files).

The part: 60 mm (x, long edge) x 40 mm (y, short edge), bottom at z = 0, five planar faces
and a free-form top, a bicubic clamped B-spline (NURBS with unit weights) over an 8 x 7
control net with a few mm of relief (a wavy top: 1.5-3 mm of
rise and fall along each trace) above an 8 mm base.  The control points' x/y sit at the
Greville abscissae, so x = 60 u and y = 40 v exactly and the top is a height field
z = h(x, y) (:func:`nominal_height`, analytic).

The nine traces (top view, frame "xy", API geometry dicts), as we read the paper's layout:
each runs across the part parallel to the short edge from y = 4 to y = 36 (4 mm from the
long edges, 32 mm end to end); they sit 4 mm apart starting 6 mm from the short edge
x = 0: traces 1-3 lines at x = 6, 10, 14; 4-6 arcs of radius 40 mm whose chords lie at
x = 18, 22, 26 (bulging +x by 3.34 mm); 7-9 cubic NURBS curves whose ends lie at
x = 30, 34, 38.  Standoffs: traces 1, 4, 7 -> 0.08 mm; 2, 5, 8 -> 0.10; 3, 6, 9 -> 0.11.

As-made variants (:func:`as_made`): a smooth machining error field (seeded sum of plane
waves, wavelengths >= ``min_wavelength_mm``, scaled to ``amplitude_mm`` peak) on the top,
and a placement error (dx, dy, dz, rz about the part centre, :func:`centred_placement`,
an :class:`app.geometry.placement.Placement`): the TRUE part in machine
coordinates, as an analytic height function and as a watertight mesh.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import trimesh
from scipy.interpolate import BSpline, NdBSpline

from app.geometry.placement import Placement
from app.geometry.tolerance import ROUNDOFF_SLACK
from app.geometry.traces import TracePolyline

if TYPE_CHECKING:
    from app.geometry.nurbs_surface import NurbsSurface

LENGTH_X_MM = 60.0
WIDTH_Y_MM = 40.0
CENTER = np.array([LENGTH_X_MM / 2, WIDTH_Y_MM / 2])
BASE_Z_MM = 8.0
DEGREE = 3
RELIEF_MM = np.array([  # (8 along x, 7 along y) control heights above the base
    [0.0, 1.0, 2.5, 0.5, 2.8, 1.0, 0.0],
    [0.5, 4.2, 0.2, 5.0, 0.6, 4.4, 0.4],
    [1.0, 0.4, 5.5, 0.3, 5.8, 0.6, 0.9],
    [0.8, 5.6, 0.6, 6.0, 0.4, 5.4, 1.2],
    [1.2, 0.8, 5.8, 0.5, 5.6, 0.4, 0.8],
    [0.6, 5.0, 0.4, 5.2, 0.8, 4.8, 0.5],
    [0.3, 1.4, 3.8, 0.8, 3.6, 1.6, 0.2],
    [0.0, 0.4, 0.9, 0.5, 0.8, 0.3, 0.0],
])
STANDOFFS_MM = (0.08, 0.10, 0.11)
TRACE_Y_MM = (4.0, 36.0)
ARC_RADIUS_MM = 40.0
NURBS_OFFSETS_MM = (0.0, 1.5, -0.2, 2.0, 0.5, 0.0)  # x offsets of the 6 control points


def _clamped_knots(n_ctrl: int, degree: int = DEGREE) -> np.ndarray:
    inner = np.linspace(0.0, 1.0, n_ctrl - degree + 1)[1:-1]
    return np.concatenate([np.zeros(degree + 1), inner, np.ones(degree + 1)])


def _greville(knots: np.ndarray, n_ctrl: int, degree: int = DEGREE) -> np.ndarray:
    return np.array([knots[i + 1:i + degree + 1].mean() for i in range(n_ctrl)])


_KU = _clamped_knots(RELIEF_MM.shape[0])
_KV = _clamped_knots(RELIEF_MM.shape[1])
_HEIGHT = NdBSpline((_KU, _KV), BASE_Z_MM + RELIEF_MM, (DEGREE, DEGREE))


def s1_surface() -> NurbsSurface:
    """The top face as the geometry core's NurbsSurface (control points (6, 5, 3) mm)."""
    from app.geometry.nurbs_surface import NurbsSurface

    gx = _greville(_KU, RELIEF_MM.shape[0]) * LENGTH_X_MM
    gy = _greville(_KV, RELIEF_MM.shape[1]) * WIDTH_Y_MM
    X, Y = np.meshgrid(gx, gy, indexing="ij")
    ctrl = np.stack([X, Y, BASE_Z_MM + RELIEF_MM], axis=-1)
    return NurbsSurface(DEGREE, DEGREE, _KU, _KV, ctrl, None)


def _uv(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    xy = np.atleast_2d(np.asarray(xy, dtype=float))
    uv = xy[:, :2] / np.array([LENGTH_X_MM, WIDTH_Y_MM])
    inside = np.all((uv >= -ROUNDOFF_SLACK) & (uv <= 1 + ROUNDOFF_SLACK), axis=1)
    return np.clip(uv, 0.0, 1.0), inside


def nominal_height(xy: Any) -> np.ndarray:
    """Nominal top height (m,) mm at part coordinates xy (m, 2); NaN off the part."""
    uv, inside = _uv(xy)
    return np.where(inside, _HEIGHT(uv), np.nan)


def nominal_gradient(xy: Any) -> np.ndarray:
    """(dh/dx, dh/dy) (m, 2) of the nominal top at xy (m, 2)."""
    uv, _ = _uv(xy)
    return np.stack([_HEIGHT(uv, nu=(1, 0)) / LENGTH_X_MM,
                     _HEIGHT(uv, nu=(0, 1)) / WIDTH_Y_MM], axis=1)


def height_field_mesh(height: Callable[[np.ndarray], np.ndarray], grid_mm: float = 0.15) -> trimesh.Trimesh:
    """Watertight block over [0, 60] x [0, 40]: top z = height(xy) on a grid of about
    ``grid_mm`` (two triangles per cell), planar sides, planar bottom z = 0 (fan)."""
    nx = int(math.ceil(LENGTH_X_MM / grid_mm))
    ny = int(math.ceil(WIDTH_Y_MM / grid_mm))
    x = np.linspace(0.0, LENGTH_X_MM, nx + 1)
    y = np.linspace(0.0, WIDTH_Y_MM, ny + 1)
    X, Y = np.meshgrid(x, y, indexing="ij")
    top = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=1)
    top[:, 2] = height(top[:, :2])
    vid = np.arange(X.size).reshape(nx + 1, ny + 1)
    a, b = vid[:-1, :-1].ravel(), vid[1:, :-1].ravel()
    c, d = vid[1:, 1:].ravel(), vid[:-1, 1:].ravel()
    faces = [np.stack([a, b, c], 1), np.stack([a, c, d], 1)]  # counter-clockwise from +z
    ring = np.concatenate([vid[:, 0], vid[-1, 1:], vid[-2::-1, -1], vid[0, -2:0:-1]])
    n_top = len(top)
    bottom = top[ring].copy()
    bottom[:, 2] = 0.0
    centre = np.array([[LENGTH_X_MM / 2, WIDTH_Y_MM / 2, 0.0]])
    verts = np.concatenate([top, bottom, centre])
    k = len(ring)
    i0 = np.arange(k)
    i1 = (i0 + 1) % k
    tb0, tb1 = ring[i0], ring[i1]
    bb0, bb1 = n_top + i0, n_top + i1
    faces += [np.stack([tb0, bb0, bb1], 1), np.stack([tb0, bb1, tb1], 1)]  # walls, outward
    faces.append(np.stack([np.full(k, n_top + k), bb1, bb0], 1))  # bottom, facing -z
    return trimesh.Trimesh(verts, np.concatenate(faces), process=False)


def s1_mesh(grid_mm: float = 0.15) -> trimesh.Trimesh:
    """The nominal S1 part as a watertight mesh (see :func:`height_field_mesh`)."""
    return height_field_mesh(nominal_height, grid_mm)


@dataclass(frozen=True)
class ReferenceTrace:
    """One of the nine traces: number 1..9, kind line|arc|nurbs, API geometry dict."""

    number: int
    kind: str
    geometry: dict[str, Any]
    standoff_mm: float
    frame: str = "xy"

    @property
    def name(self) -> str:
        return f"S1-trace-{self.number}"

    def to_api(self) -> dict[str, Any]:
        """Body of ``POST /api/v1/parts/{id}/traces``."""
        return {"name": self.name, "geometry": self.geometry, "frame": self.frame,
                "standoff_mm": self.standoff_mm}


def s1_traces() -> tuple[ReferenceTrace, ...]:
    """The nine traces in the paper's layout (see the module doc)."""
    y0, y1 = TRACE_Y_MM
    half = (y1 - y0) / 2
    sweep = math.degrees(math.asin(half / ARC_RADIUS_MM))
    sag_to_centre = math.sqrt(ARC_RADIUS_MM ** 2 - half ** 2)
    out: list[ReferenceTrace] = []
    for i in range(9):
        x0 = 6.0 + 4.0 * i
        standoff = STANDOFFS_MM[i % 3]
        if i < 3:
            geom: dict[str, Any] = {"type": "line", "start": [x0, y0], "end": [x0, y1]}
            kind = "line"
        elif i < 6:
            geom = {"type": "arc", "center": [x0 - sag_to_centre, (y0 + y1) / 2],
                    "radius": ARC_RADIUS_MM, "start_deg": -sweep, "end_deg": sweep}
            kind = "arc"
        else:
            ys = np.linspace(y0, y1, len(NURBS_OFFSETS_MM))
            geom = {"type": "nurbs", "degree": DEGREE,
                    "control_points": [[x0 + dx, float(y)] for dx, y in zip(NURBS_OFFSETS_MM, ys)],
                    "knots": _clamped_knots(len(NURBS_OFFSETS_MM)).tolist()}
            kind = "nurbs"
        out.append(ReferenceTrace(i + 1, kind, geom, standoff))
    return tuple(out)


def trace_xy(geometry: dict[str, Any], step_mm: float = 0.05) -> np.ndarray:
    """Top-view points (k, 2) mm of a reference trace, evenly spaced ~step_mm along it."""
    t = np.linspace(0.0, 1.0, 4001)
    kind = geometry["type"]
    if kind == "line":
        a, b = np.array(geometry["start"]), np.array(geometry["end"])
        pts = a + t[:, None] * (b - a)
    elif kind == "arc":
        ang = np.radians(geometry["start_deg"] + t * (geometry["end_deg"] - geometry["start_deg"]))
        pts = np.array(geometry["center"]) + geometry["radius"] * np.stack(
            [np.cos(ang), np.sin(ang)], axis=1)
    elif kind == "nurbs":
        spl = BSpline(np.array(geometry["knots"]), np.array(geometry["control_points"]),
                      geometry["degree"])
        pts = spl(t)
    else:
        raise ValueError(f"not a reference trace type: {kind}")
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    n = int(math.ceil(s[-1] / step_mm)) + 1
    ss = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(ss, s, pts[:, 0]), np.interp(ss, s, pts[:, 1])], axis=1)


def nominal_path(trace: ReferenceTrace, step_mm: float = 0.05) -> TracePolyline:
    """The trace draped on the analytic nominal top: dense TracePolyline with normals."""
    xy = trace_xy(trace.geometry, step_mm)
    z = nominal_height(xy)
    g = nominal_gradient(xy)
    normals = np.stack([-g[:, 0], -g[:, 1], np.ones(len(xy))], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    points = np.column_stack([xy, z])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    return TracePolyline(points=points, s=s, normals=normals)


def centred_placement(dx: float = 0.0, dy: float = 0.0, dz: float = 0.0, rz_deg: float = 0.0) -> Placement:
    """Where the real part sits relative to its nominal place: mm and degrees about the
    part centre (rz counter-clockwise seen from +z)."""
    return Placement.from_deg(dx, dy, dz, rz_deg, (float(CENTER[0]), float(CENTER[1])))


@dataclass(frozen=True, eq=False)
class AsMadePart:
    """A synthetic as-made S1 part.

    waves: (M, 4) rows (kx, ky, phase, amplitude) of the machining error, part coordinates.
    """

    seed: int
    amplitude_mm: float
    min_wavelength_mm: float
    placement: Placement
    waves: np.ndarray

    def machining_error(self, xy_part: Any) -> np.ndarray:
        """Machining error (m,) mm of the top at part coordinates (m, 2)."""
        p = np.atleast_2d(np.asarray(xy_part, dtype=float))[:, :2]
        k, phase, amp = self.waves[:, :2], self.waves[:, 2], self.waves[:, 3]
        out: np.ndarray = np.cos(p @ k.T + phase) @ amp
        return out

    def to_part(self, xy_machine: Any) -> np.ndarray:
        """Machine xy (m, 2) -> part xy (m, 2) (inverse placement)."""
        return self.placement.remove(np.atleast_2d(np.asarray(xy_machine, dtype=float))[:, :2])

    def to_machine(self, xy_part: Any) -> np.ndarray:
        """Part xy (m, 2) -> machine xy (m, 2) (placement)."""
        return self.placement.apply(np.atleast_2d(np.asarray(xy_part, dtype=float))[:, :2])

    def true_height(self, xy_machine: Any) -> np.ndarray:
        """TRUE top height (m,) mm at machine xy (m, 2); NaN off the part."""
        p = self.to_part(xy_machine)
        out: np.ndarray = nominal_height(p) + self.machining_error(p) + self.placement.dz
        return out

    def mesh(self, grid_mm: float = 0.15) -> trimesh.Trimesh:
        """The TRUE part as a watertight mesh in machine coordinates."""
        m = height_field_mesh(lambda xy: nominal_height(xy) + self.machining_error(xy), grid_mm)
        v = m.vertices.copy()
        v[:, :2] = self.to_machine(v[:, :2])
        v[:, 2] += self.placement.dz
        return trimesh.Trimesh(v, m.faces, process=False)


def as_made(seed: int = 0, amplitude_mm: float = 0.15, min_wavelength_mm: float = 15.0,
            placement: Placement | None = None, n_waves: int = 6) -> AsMadePart:
    """A seeded as-made variant.  The machining error is a sum of ``n_waves`` plane waves
    with wavelengths in [min, 3 min] mm and random directions/phases, scaled so that its
    peak over the part is ``amplitude_mm``.  ``placement`` None -> a seeded random one
    (|dx|, |dy| <= 0.1 mm, |dz| <= 0.05 mm, |rz| <= 0.2 deg)."""
    rng = np.random.default_rng(seed)
    lam = rng.uniform(min_wavelength_mm, 3 * min_wavelength_mm, n_waves)
    ang = rng.uniform(0, 2 * math.pi, n_waves)
    k = (2 * math.pi / lam)[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    waves = np.column_stack([k, rng.uniform(0, 2 * math.pi, n_waves),
                             rng.uniform(0.5, 1.0, n_waves)])
    if placement is None:
        dx, dy = rng.uniform(-0.1, 0.1, 2)
        placement = centred_placement(float(dx), float(dy), float(rng.uniform(-0.05, 0.05)),
                                      float(rng.uniform(-0.2, 0.2)))
    part = AsMadePart(seed, amplitude_mm, min_wavelength_mm, placement, waves)
    gx, gy = np.meshgrid(np.linspace(0, LENGTH_X_MM, 121), np.linspace(0, WIDTH_Y_MM, 81))
    peak = np.abs(part.machining_error(np.column_stack([gx.ravel(), gy.ravel()]))).max()
    waves[:, 3] *= amplitude_mm / peak
    return AsMadePart(seed, amplitude_mm, min_wavelength_mm, placement, waves)
