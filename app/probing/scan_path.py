"""Where the carriage is at a time during a scan pass, and what a sensor sample means.

A scan pass is a polyline of waypoints (m, 3) mm driven at one feed from rest at the first
one.  Machine model (the mock's, and a controller's without look-ahead at scan speed):
constant speed along each segment, no acceleration phase inside the pass (the ramps are in
the cost model, :mod:`app.probing.scan_cost`).  A sensor storage started with the carriage
at rest at the first waypoint stamps sample k at ``k / rate`` s; its value was exposed at
``stamp - time_offset`` (the sensor's calibrated latency and start delay).

Pure: numpy.  Units: mm, s.
"""

from __future__ import annotations

import numpy as np

from app.domain.errors import InvalidInput


class ScanPathError(InvalidInput):
    """A scan pass that cannot be timed (fewer than two waypoints, a bad feed)."""


def pass_lengths(waypoints: np.ndarray) -> np.ndarray:
    """Cumulative arc length (m,) mm of the waypoints (m, 3)."""
    w = np.asarray(waypoints, dtype=float)
    if w.ndim != 2 or w.shape[1] != 3 or len(w) < 2:
        raise ScanPathError("a scan pass needs at least two waypoints [x, y, z]", field="waypoints",
                            value=list(w.shape))
    out: np.ndarray = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(w, axis=0), axis=1))])
    return out


def positions_at(waypoints: np.ndarray, speed_mm_s: float, times_s: np.ndarray) -> np.ndarray:
    """Carriage positions (n, 3) mm at ``times_s`` (n,) s after leaving the first waypoint
    at ``speed_mm_s``; before 0 at the first waypoint, after the end at the last."""
    if not speed_mm_s > 0:
        raise ScanPathError("the scan speed must be > 0", field="speed_mm_s", value=speed_mm_s)
    w = np.asarray(waypoints, dtype=float)
    s = pass_lengths(w)
    at = np.clip(np.asarray(times_s, dtype=float) * speed_mm_s, 0.0, s[-1])
    out = np.empty((len(at), 3))
    for axis in range(3):
        out[:, axis] = np.interp(at, s, w[:, axis])
    return out


def pass_duration(waypoints: np.ndarray, speed_mm_s: float) -> float:
    """Seconds (constant speed) the pass takes."""
    return float(pass_lengths(waypoints)[-1] / speed_mm_s)


def sample_positions(waypoints: np.ndarray, speed_mm_s: float, count: int, rate_hz: float,
                     time_offset_s: float = 0.0) -> np.ndarray:
    """The carriage (count, 3) mm where each of ``count`` stored samples was exposed."""
    stamps = np.arange(int(count)) / float(rate_hz)
    return positions_at(waypoints, speed_mm_s, stamps - time_offset_s)
