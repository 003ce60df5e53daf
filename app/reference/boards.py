"""Whole-board fixtures for the field planner (pure: no files).

Two nominal parts, each a height field z = h(x, y) over a rectangle (part coordinates, mm):
the S1 part (60 x 40, :mod:`app.reference.s1`) and a 150 x 100 mm doubly curved part (a
dome with a gentle saddle-like ripple: both principal curvatures vary over the top).

A board of N traces (:func:`board_traces`): N = 9 on S1 is the seed's nine traces; else
the part's top (4 mm margin) is cut into about N equal cells and each cell holds one trace,
in turn a straight line, a circular arc or a free cubic curve (seeded jitter), as API
geometry dicts (``frame: "xy"``).  :func:`board_path` drapes one onto the analytic top.

As made (:func:`as_made_board`): the seed's error model on any part — a sum of plane waves
(wavelengths in [lambda, 3 lambda], scaled to a peak amplitude over the part) plus a seeded
rigid placement (|dx|, |dy| <= 0.1 mm, |dz| <= 0.05 mm, |rz| <= 0.2 deg about the centre).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import trimesh

from app.geometry.placement import Placement
from app.geometry.tolerance import ROUNDOFF_SLACK
from app.geometry.traces import TracePolyline
from app.reference import s1

MARGIN_MM = 4.0


@dataclass(frozen=True, eq=False)
class BoardPart:
    """A nominal part: name, size (2,) mm, height(xy (m, 2)) -> (m,), gradient(xy) -> (m, 2)."""

    name: str
    size: np.ndarray
    height: Callable[[np.ndarray], np.ndarray]
    gradient: Callable[[np.ndarray], np.ndarray]

    @property
    def center(self) -> np.ndarray:
        return self.size / 2.0

    def mesh(self, grid_mm: float = 0.5) -> trimesh.Trimesh:
        """The nominal part as a watertight mesh (top on a grid of about ``grid_mm``)."""
        scale = self.size / np.array([s1.LENGTH_X_MM, s1.WIDTH_Y_MM])
        base = s1.height_field_mesh(lambda xy: self.height(xy * scale), grid_mm / float(scale.min()))
        v = base.vertices.copy()
        v[:, :2] *= scale
        return trimesh.Trimesh(v, base.faces, process=False)


def s1_part() -> BoardPart:
    return BoardPart("S1", np.array([s1.LENGTH_X_MM, s1.WIDTH_Y_MM]), s1.nominal_height, s1.nominal_gradient)


DOME_SIZE = np.array([150.0, 100.0])
DOME_BASE_MM, DOME_RISE_MM, DOME_RIPPLE_MM = 10.0, 6.0, 1.0


def _dome_height(xy: Any) -> np.ndarray:
    p = np.atleast_2d(np.asarray(xy, dtype=float))
    u, v = p[:, 0] / DOME_SIZE[0] * 2 - 1, p[:, 1] / DOME_SIZE[1] * 2 - 1
    inside = (np.abs(u) <= 1 + ROUNDOFF_SLACK) & (np.abs(v) <= 1 + ROUNDOFF_SLACK)
    h = (DOME_BASE_MM + DOME_RISE_MM * (1 - u * u) * (1 - 0.5 * v * v)
         + DOME_RIPPLE_MM * np.sin(2 * math.pi * p[:, 0] / 60.0) * np.cos(2 * math.pi * p[:, 1] / 50.0))
    return np.where(inside, h, np.nan)


def _dome_gradient(xy: Any) -> np.ndarray:
    p = np.atleast_2d(np.asarray(xy, dtype=float))
    u, v = p[:, 0] / DOME_SIZE[0] * 2 - 1, p[:, 1] / DOME_SIZE[1] * 2 - 1
    du, dv = 2 / DOME_SIZE[0], 2 / DOME_SIZE[1]
    a, b = 2 * math.pi / 60.0, 2 * math.pi / 50.0
    hx = (DOME_RISE_MM * (-2 * u * du) * (1 - 0.5 * v * v)
          + DOME_RIPPLE_MM * a * np.cos(a * p[:, 0]) * np.cos(b * p[:, 1]))
    hy = DOME_RISE_MM * (1 - u * u) * (-v * dv) - DOME_RIPPLE_MM * b * np.sin(a * p[:, 0]) * np.sin(b * p[:, 1])
    return np.stack([hx, hy], axis=1)


def dome_part() -> BoardPart:
    """The 150 x 100 mm doubly curved part."""
    return BoardPart("dome", DOME_SIZE.copy(), _dome_height, _dome_gradient)


def board_traces(part: BoardPart, count: int, seed: int = 0) -> list[dict[str, Any]]:
    """``count`` trace geometries (API dicts) on ``part`` (see the module doc)."""
    if part.name == "S1" and count == 9:
        return [t.geometry for t in s1.s1_traces()]
    rng = np.random.default_rng(seed)
    w, h = part.size - 2 * MARGIN_MM
    nx = int(math.ceil(math.sqrt(count * w / h)))
    ny = int(math.ceil(count / nx))
    cw, ch = w / nx, h / ny
    out: list[dict[str, Any]] = []
    for i in range(count):
        x0 = MARGIN_MM + (i % nx) * cw
        y0 = MARGIN_MM + (i // nx) * ch
        j = rng.uniform(-0.05, 0.05, 4)
        kind = i % 3
        if kind == 0:
            out.append({"type": "line", "start": [x0 + (0.1 + j[0]) * cw, y0 + (0.1 + j[1]) * ch],
                        "end": [x0 + (0.9 + j[2]) * cw, y0 + (0.9 + j[3]) * ch]})
        elif kind == 1:
            start = float(rng.uniform(0, 360))
            out.append({"type": "arc", "center": [x0 + 0.5 * cw, y0 + 0.5 * ch],
                        "radius": 0.4 * min(cw, ch), "start_deg": start, "end_deg": start + 220.0})
        else:
            t = np.linspace(0.1, 0.9, 5)
            a = np.array([x0, y0]) + np.stack([t * cw, t * ch], axis=1)
            normal = np.array([-ch, cw]) / math.hypot(cw, ch)
            a[1:-1] += normal * rng.uniform(-0.15, 0.15, (3, 1)) * min(cw, ch)
            knots = [0.0] * 4 + [0.5] + [1.0] * 4
            out.append({"type": "nurbs", "degree": 3, "control_points": a.tolist(), "knots": knots})
    return out


def board_path(part: BoardPart, geometry: dict[str, Any], step_mm: float = 0.05) -> TracePolyline:
    """The trace draped on the part's analytic top: dense TracePolyline with normals."""
    xy = s1.trace_xy(geometry, step_mm)
    g = part.gradient(xy)
    normals = np.stack([-g[:, 0], -g[:, 1], np.ones(len(xy))], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    points = np.column_stack([xy, part.height(xy)])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    return TracePolyline(points=points, s=s, normals=normals)


@dataclass(frozen=True, eq=False)
class AsMadeBoard:
    """A seeded as-made part: waves (M, 4) rows (kx, ky, phase, amplitude) in part
    coordinates; placement: the rigid placement part -> machine (about the part centre)."""

    part: BoardPart
    seed: int
    waves: np.ndarray
    placement: Placement

    def machining_error(self, xy_part: Any) -> np.ndarray:
        p = np.atleast_2d(np.asarray(xy_part, dtype=float))
        out: np.ndarray = np.cos(p @ self.waves[:, :2].T + self.waves[:, 2]) @ self.waves[:, 3]
        return out

    def to_part(self, xy_machine: Any) -> np.ndarray:
        """Machine xy (m, 2) -> part xy (m, 2) (inverse placement)."""
        return self.placement.remove(np.atleast_2d(np.asarray(xy_machine, dtype=float))[:, :2])

    def true_height(self, xy_machine: Any) -> np.ndarray:
        """TRUE top height (m,) mm at machine xy (m, 2)."""
        p = self.to_part(xy_machine)
        out: np.ndarray = self.part.height(p) + self.machining_error(p) + self.placement.dz
        return out


def as_made_board(part: BoardPart, seed: int, amplitude_mm: float = 0.15, min_wavelength_mm: float = 15.0,
                  n_waves: int = 6) -> AsMadeBoard:
    """A seeded as-made ``part`` (see the module doc)."""
    rng = np.random.default_rng(seed)
    lam = rng.uniform(min_wavelength_mm, 3 * min_wavelength_mm, n_waves)
    ang = rng.uniform(0, 2 * math.pi, n_waves)
    k = (2 * math.pi / lam)[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    waves = np.column_stack([k, rng.uniform(0, 2 * math.pi, n_waves), rng.uniform(0.5, 1.0, n_waves)])
    dx, dy = rng.uniform(-0.1, 0.1, 2)
    placement = Placement.from_deg(float(dx), float(dy), float(rng.uniform(-0.05, 0.05)), float(rng.uniform(-0.2, 0.2)),
                                   (float(part.center[0]), float(part.center[1])))
    made = AsMadeBoard(part, seed, waves, placement)
    gx, gy = np.meshgrid(np.linspace(0, part.size[0], 121), np.linspace(0, part.size[1], 81))
    peak = np.abs(made.machining_error(np.column_stack([gx.ravel(), gy.ravel()]))).max()
    waves[:, 3] *= amplitude_mm / peak
    return AsMadeBoard(part, seed, waves, made.placement)
