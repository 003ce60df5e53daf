"""Evaluation against the mock's truth (simulation only): what was really deposited.

The mock firmware logs every move made with the dispenser on; the as-made part at its
placement is the truth.  The standoff along the printed path follows from both
(:func:`app.compensation.evaluation.evaluate_deposition`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from app.compensation.evaluation import StandoffReport, evaluate_deposition
from app.geometry.drape import top_surface_z
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
