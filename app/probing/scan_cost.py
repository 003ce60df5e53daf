"""Machine time of touching and of scanning: the cost model the scan planner minimises.

One machine model for both (mm, s):

* a straight move of length L at speed v with acceleration a takes the trapezoid time
  ``L / v + v / a`` when it reaches v (L >= v^2 / a), else the triangle ``2 sqrt(L / a)``;
* a **touch** (:func:`touch_time`): up ``clearance_mm`` from the previous station, across to
  the next at the travel speed, down ``clearance_mm``, then the probing move at the probe
  speed over ``approach_mm`` (it starts that far above the expected surface; the trigger
  comes at the surface) plus ``trigger_s`` (the controller latches and answers), then back
  up ``approach_mm`` at the travel speed;
* a **scan pass** (:func:`pass_time`): its length at the scan speed with one ramp up and
  down (a pass is one smooth path; its corners are not slowed for), plus the link from the
  previous pass's end: a hop (up, across, down) between trace passes, a straight move at
  scan height between the lines of one raster (it stays above the part), plus
  ``storage_s`` to start and stop the sensor's storage.

Pure.  The defaults are a small gantry's: travel and scan 100 mm/s, 1000 mm/s^2, probing
100 mm/min from 1 mm above the expected surface.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from app.domain.checks import require_non_negative, require_positive
from app.domain.errors import InvalidInput


class CostError(InvalidInput):
    """Cost-model parameters that cannot be used."""


@dataclass(frozen=True)
class MotionCost:
    """Speeds mm/s, acceleration mm/s^2, lengths mm, times s (module docstring)."""

    travel_mm_s: float = 100.0
    accel_mm_s2: float = 1000.0
    probe_mm_s: float = 100.0 / 60.0
    approach_mm: float = 1.0
    clearance_mm: float = 2.0
    trigger_s: float = 0.02
    scan_mm_s: float = 100.0
    storage_s: float = 0.01

    def __post_init__(self) -> None:
        require_positive(self, ("travel_mm_s", "accel_mm_s2", "probe_mm_s", "approach_mm", "scan_mm_s"), CostError)
        require_non_negative(self, ("clearance_mm", "trigger_s", "storage_s"), CostError)


def move_time(length_mm: float | np.ndarray, speed_mm_s: float, accel_mm_s2: float) -> np.ndarray:
    """Seconds of straight moves of ``length_mm`` from rest to rest (trapezoid or triangle)."""
    length = np.abs(np.asarray(length_mm, dtype=float))
    full = length >= speed_mm_s ** 2 / accel_mm_s2
    out: np.ndarray = np.where(full, length / speed_mm_s + speed_mm_s / accel_mm_s2,
                               2.0 * np.sqrt(length / accel_mm_s2))
    return out


def hop_time(cost: MotionCost, distance_mm: float | np.ndarray) -> np.ndarray:
    """Up clearance, across ``distance_mm`` (xy), down clearance (s)."""
    up = move_time(cost.clearance_mm, cost.travel_mm_s, cost.accel_mm_s2)
    out: np.ndarray = 2 * up + move_time(distance_mm, cost.travel_mm_s, cost.accel_mm_s2)
    return out


def touch_time(cost: MotionCost, stations_xy: np.ndarray) -> float:
    """Seconds to touch stations (n, 2) in the given order (module docstring)."""
    xy = np.asarray(stations_xy, dtype=float).reshape(-1, 2)
    if not len(xy):
        return 0.0
    hops = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    probing = cost.approach_mm / cost.probe_mm_s + cost.trigger_s \
        + float(move_time(cost.approach_mm, cost.travel_mm_s, cost.accel_mm_s2))
    return float(np.sum(hop_time(cost, hops)) + len(xy) * probing)


def pass_time(cost: MotionCost, length_mm: float) -> float:
    """Seconds of one scan pass of ``length_mm`` at the scan speed, ramps included."""
    return float(move_time(length_mm, cost.scan_mm_s, cost.accel_mm_s2)) + cost.storage_s


def link_time(cost: MotionCost, distance_mm: float, hop: bool) -> float:
    """Seconds from one pass's end to the next's start: a hop or a straight move."""
    if hop:
        return float(hop_time(cost, distance_mm))
    return float(move_time(distance_mm, cost.travel_mm_s, cost.accel_mm_s2))


def nearest_order(starts: np.ndarray, ends: np.ndarray, origin: np.ndarray | None = None
                  ) -> tuple[list[int], list[bool]]:
    """A greedy nearest-neighbour tour over passes (k,) with start/end xy (k, 2): the order
    and whether each pass runs reversed (entered at its end)."""
    k = len(starts)
    left = np.ones(k, dtype=bool)
    here = np.asarray(origin if origin is not None else starts[0], dtype=float)
    order: list[int] = []
    flipped: list[bool] = []
    for _ in range(k):
        d_start = np.where(left, np.linalg.norm(starts - here, axis=1), math.inf)
        d_end = np.where(left, np.linalg.norm(ends - here, axis=1), math.inf)
        i_s, i_e = int(np.argmin(d_start)), int(np.argmin(d_end))
        if d_start[i_s] <= d_end[i_e]:
            order.append(i_s)
            flipped.append(False)
            here = ends[i_s]
            left[i_s] = False
        else:
            order.append(i_e)
            flipped.append(True)
            here = starts[i_e]
            left[i_e] = False
    return order, flipped


def touch_order(stations_xy: np.ndarray, origin: np.ndarray | None = None) -> np.ndarray:
    """A greedy nearest-neighbour order (n,) of touch stations (n, 2) from ``origin`` (2,)
    (None: the first station): fewer mm of hops than an order by uncertainty."""
    xy = np.asarray(stations_xy, dtype=float).reshape(-1, 2)
    if not len(xy):
        return np.zeros(0, dtype=int)
    order, _ = nearest_order(xy, xy, origin)
    return np.asarray(order, dtype=int)
