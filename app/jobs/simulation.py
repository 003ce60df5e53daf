"""Evaluation against the mock's truth (simulation only): what was really deposited.

The mock firmware logs every move made with the dispenser on; the as-made part at its
placement is the truth.  The standoff along the printed path follows from both
(:func:`app.reference.evaluation.evaluate_deposition`).  The XY error of the printed
path is its distance, in top view, from the designed trace moved by the mock's TRUE
placement (rotation about the machine origin, then translation; a true-part mesh is
taken as made in the part frame, its placement being the mock's).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import shapely

from app.geometry.drape import top_surface_z
from app.geometry.placement import Placement, apply_placement
from app.reference.evaluation import StandoffReport, evaluate_deposition
from hardware.mock import MockWorld
from hardware.mock.surface import placement_matrix


def true_height_of(world: MockWorld) -> Callable[[np.ndarray], np.ndarray]:
    """xy (m, 2) -> height (m,) of the placed as-made part's top (NaN off the part)."""
    if world.true_part is None:
        raise ValueError("the mock world has no true part")
    placed = world.true_part.copy()
    placed.apply_transform(placement_matrix(world.placement))

    def height(xy: np.ndarray) -> np.ndarray:
        top = top_surface_z(placed, np.asarray(xy, dtype=float))
        return np.where(top.hit, top.z, np.nan)

    return height


def deposited_since(world: MockWorld, start: int) -> np.ndarray:
    """Deposited moves logged after index ``start`` as (n, 2, 3) start/end points, mm."""
    with world.lock:
        moves = world.deposition_log[start:]
    return np.array([[m.start, m.end] for m in moves], dtype=float).reshape(-1, 2, 3)


def evaluate_print(world: MockWorld, start: int, standoff_mm: float) -> StandoffReport:
    """Standoff report of what the mock deposited since log index ``start``."""
    return evaluate_deposition(deposited_since(world, start), true_height_of(world), standoff_mm)


@dataclass(frozen=True)
class XYReport:
    """Top-view distance (mm) of the deposited path from the truly placed design:
    max and rms over points sampled along the deposited moves."""

    max_mm: float
    rms_mm: float


def true_placement(world: MockWorld) -> Placement:
    """The mock's placement of its true part (about the machine origin)."""
    p = world.placement
    return Placement.from_deg(p.dx, p.dy, p.dz, p.rz_deg, (0.0, 0.0))


def xy_error(world: MockWorld, start: int, designed_points: Any, sample_mm: float = 0.05) -> XYReport:
    """XY error of what the mock deposited since log index ``start`` against the designed
    trace (k, 3) part frame, mm, placed by the mock's true placement."""
    moves = deposited_since(world, start)
    if len(moves) == 0:
        raise ValueError("nothing was deposited")
    designed = shapely.LineString(apply_placement(designed_points, true_placement(world))[:, :2])
    samples = []
    for a, b in moves[:, :, :2]:
        k = max(1, math.ceil(float(np.linalg.norm(b - a)) / sample_mm))
        samples.append(a + np.linspace(0.0, 1.0, k + 1)[:, None] * (b - a))
    distance = shapely.distance(designed, shapely.points(np.vstack(samples)))
    return XYReport(float(distance.max()), float(np.sqrt(np.mean(distance ** 2))))
