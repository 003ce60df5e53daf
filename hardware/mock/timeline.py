"""Where the mock machine's carriage was, on the machine clock: a position stream with times.

The mock firmware advances its machine clock (``MockStats.machine_time_s``: modelled seconds
of motion and dwell, whatever ``time_scale`` is) move by move.  When a device shares the
machine's world (the mock height sensor, :mod:`hardware.height_sensor`), the world holds a
``MotionTimeline`` and the firmware appends one segment per clock advance: from time t0 to
t1 the carriage went from p0 to p1 at constant speed (a dwell: p0 == p1).  Lookups are
vectorised: :meth:`positions` answers (n,) times with (n, 3) positions in mm.

Bounded: at most ``capacity`` segments are kept (the oldest go first); a device that needs
the positions of a window marks its start with :meth:`anchor` and reads before the window
scrolls out.
"""

from __future__ import annotations

import threading
from collections import deque

import numpy as np

DEFAULT_CAPACITY = 1_000_000


class MotionTimeline:
    """Segments (t0, t1, p0, p1) of the carriage on the machine clock (s, mm)."""

    def __init__(self, capacity: int = DEFAULT_CAPACITY) -> None:
        self._segments: deque[tuple[float, float, tuple[float, float, float], tuple[float, float, float]]] = \
            deque(maxlen=capacity)
        self._anchor: tuple[float, tuple[float, float, float]] | None = None
        self._lock = threading.Lock()

    def add(self, t0: float, t1: float, p0: tuple[float, ...], p1: tuple[float, ...]) -> None:
        """The carriage went from p0 (3,) at t0 to p1 (3,) at t1 (machine clock s)."""
        a = (float(p0[0]), float(p0[1]), float(p0[2]))
        b = (float(p1[0]), float(p1[1]), float(p1[2]))
        with self._lock:
            self._segments.append((float(t0), float(t1), a, b))

    def advance(self, until: float, seconds: float, path: tuple[tuple[float, ...], tuple[float, ...]]) -> None:
        """The clock advanced by ``seconds`` up to ``until`` while the carriage went path[0] -> path[1]."""
        self.add(until - max(float(seconds), 0.0), until, path[0], path[1])

    def anchor(self, t: float, position: tuple[float, ...]) -> None:
        """The carriage stands at ``position`` at time ``t``; older segments are dropped."""
        with self._lock:
            self._segments.clear()
            self._anchor = (float(t), (float(position[0]), float(position[1]), float(position[2])))

    def segments_since(self, t: float) -> np.ndarray:
        """Segments ending after machine time ``t`` as rows (t0, t1, x0, y0, z0, x1, y1, z1), (n, 8)."""
        with self._lock:
            rows = [(s[0], s[1], *s[2], *s[3]) for s in self._segments if s[1] > t]
        return np.array(rows, dtype=float).reshape(-1, 8)

    def __len__(self) -> int:
        return len(self._segments)

    def positions(self, times: np.ndarray) -> np.ndarray:
        """Carriage positions (n, 3) mm at machine-clock ``times`` (n,) s: inside a segment
        interpolated, between segments the last end, before the first the anchor."""
        t = np.asarray(times, dtype=float)
        with self._lock:
            segs = list(self._segments)
            anchor = self._anchor
        out = np.empty((len(t), 3))
        if not segs:
            out[:] = anchor[1] if anchor is not None else (0.0, 0.0, 0.0)
            return out
        t0 = np.array([s[0] for s in segs])
        t1 = np.array([s[1] for s in segs])
        p0 = np.array([s[2] for s in segs])
        p1 = np.array([s[3] for s in segs])
        i = np.searchsorted(t0, t, side="right") - 1
        before = i < 0
        j = np.clip(i, 0, len(segs) - 1)
        span = t1[j] - t0[j]
        f = np.where(span > 0, np.clip((t - t0[j]) / np.where(span > 0, span, 1.0), 0.0, 1.0), 1.0)
        out[:] = p0[j] + (p1[j] - p0[j]) * f[:, None]
        if before.any():
            out[before] = anchor[1] if anchor is not None else p0[0]
        return out
