"""Z drift during long probe runs: when each touch happens, re-touch schedule, correction (pure).

Drift model (SPEC16): actual Z = commanded Z + e(t), e slowly varying in machine time t, so a
reading taken at t is LOW by e(t).  Re-touching the reference pad at known times gives
pad readings ``pad_z(t_k) = pad_z(0) - e(t_k)``; between re-touches e is interpolated linearly
and held constant beyond the first and last re-touch, so the offset to ADD to a reading
taken at t is ``reference_z - interp(t, t_k, pad_z(t_k))``.

Times are *machine seconds*: modelled motion time, the same kinematics as the mock's clock
(straight moves at their feed, no acceleration: duration = length / feed).  ``touch_times``
replays ``Machine.probe``: for each station, Z to its safe height at the travel feed, XY at
the travel feed, probe down at the probe feed to the contact, retract to the safe height at
the travel feed.  The contact height is the station's expected z (its nominal surface), bounded
by the move (between target_z and safe_z): the estimate assumes the part is where the plan says
(a 0.1 mm miss shifts a touch by 0.1 mm / probe feed, 0.06 s at 100 mm/min).

``plan_times`` replays a calibration run instead (planned ``Touch`` moves in any direction,
executed as the calibration jobs do: up to the travel height -- or a short hop for a
``local`` touch --, across, down to the start, probe toward the target until the trigger,
back to the start) from the readings it produced,
so its times are exact for the mock's clock; they feed ``fit_qualification(times_s=...)``.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.calibration.errors import CalibrationError
from app.calibration.model import Touch, hops

__all__ = ["touch_times", "plan_times", "DriftTrack", "drift_offsets", "retouch_schedule"]


def _array(value: npt.ArrayLike, name: str, shape_tail: tuple[int, ...] = ()) -> npt.NDArray[np.float64]:
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        want = "(n" + "".join(f", {k}" for k in shape_tail) + ")"
        raise CalibrationError(f"{name} must have shape {want}", field=name, value=list(arr.shape))
    if not np.isfinite(arr).all():
        raise CalibrationError(f"{name} must be finite", field=name)
    return arr


def touch_times(points: npt.ArrayLike, safe_z: npt.ArrayLike, target_z: npt.ArrayLike, travel_feed: float,
                probe_feed: float,
                start_mm: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Machine seconds (n,) from ``start_mm`` (3,) to each touch's trigger.

    points (n, 3): stations with their expected contact z (mm).  safe_z (n,), target_z (n,):
    each touch's start and lowest height (mm).  travel_feed, probe_feed: mm/min.
    """
    p = _array(points, "points", (3,))
    n = len(p)
    safe, low = _array(safe_z, "safe_z"), _array(target_z, "target_z")
    if safe.shape != (n,) or low.shape != (n,):
        raise CalibrationError(f"safe_z and target_z must have shape ({n},)", field="safe_z",
                               value=[list(safe.shape), list(low.shape)])
    if np.any(low >= safe):
        i = int(np.flatnonzero(low >= safe)[0])
        raise CalibrationError(f"target_z[{i}] must lie below safe_z[{i}]", field=f"target_z[{i}]", value=low[i])
    for name, feed in (("travel_feed", travel_feed), ("probe_feed", probe_feed)):
        if not np.isfinite(feed) or feed <= 0:
            raise CalibrationError(f"{name} must be > 0 (mm/min)", field=name, value=feed)
    travel, probe = float(travel_feed) / 60.0, float(probe_feed) / 60.0          # mm/s
    here = _array(start_mm, "start_mm")
    if here.shape != (3,):
        raise CalibrationError("start_mm must be three numbers (mm)", field="start_mm", value=list(here.shape))
    contact = np.clip(p[:, 2], low, safe)
    out = np.empty(n)
    t = 0.0
    x, y, z = here
    for i in range(n):
        t += abs(safe[i] - z) / travel + float(np.hypot(p[i, 0] - x, p[i, 1] - y)) / travel
        t += (safe[i] - contact[i]) / probe
        out[i] = t
        t += (safe[i] - contact[i]) / travel
        x, y, z = p[i, 0], p[i, 1], safe[i]
    return out


def plan_times(touches: Iterable[Touch], readings: npt.ArrayLike, *, travel_z: float, travel_feed: float,
               probe_feed: float,
               start_mm: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Machine seconds (n,) from ``start_mm`` (3,) to each planned touch's trigger.

    touches: ``Touch`` (n); readings (n, 3) mm, the carriage at each trigger.  Per touch, from
    the previous touch's start (``start_mm`` for the first): Z to ``travel_z``, XY to the start,
    Z down to the start (travel feed), probe from the start to the reading (probe feed), back
    to the start (travel feed).  A ``local`` touch right after one of its kind hops instead:
    Z to max(here, start), XY, Z to the start (``Touch.local``, as
    ``app.jobs.calibration_touch`` runs it).  Feeds in mm/min.
    """
    touches = list(touches)
    p = _array(readings, "readings", (3,))
    if len(p) != len(touches):
        raise CalibrationError(f"readings must have shape ({len(touches)}, 3)", field="readings",
                               value=list(p.shape))
    for name, feed in (("travel_feed", travel_feed), ("probe_feed", probe_feed)):
        if not np.isfinite(feed) or feed <= 0:
            raise CalibrationError(f"{name} must be > 0 (mm/min)", field=name, value=feed)
    travel, probe = float(travel_feed) / 60.0, float(probe_feed) / 60.0
    here = _array(start_mm, "start_mm")
    if here.shape != (3,):
        raise CalibrationError("start_mm must be three numbers (mm)", field="start_mm", value=list(here.shape))
    out = np.empty(len(touches))
    t = 0.0
    x, y, z = here
    for i, touch in enumerate(touches):
        sx, sy, sz = touch.start_mm
        hop = max(z, sz) if hops(touches[i - 1] if i else None, touch) else travel_z
        t += (abs(hop - z) + float(np.hypot(sx - x, sy - y)) + abs(hop - sz)) / travel
        run = float(np.linalg.norm(p[i] - touch.start_mm))
        t += run / probe
        out[i] = t
        t += run / travel                     # back to the start
        x, y, z = sx, sy, sz
    return out


@dataclass(frozen=True)
class DriftTrack:
    """Reference-pad re-touches: machine times (m,) s and the pad's vertical readings (m,) mm."""

    times_s: tuple[float, ...]
    pad_z_mm: tuple[float, ...]

    def __post_init__(self) -> None:
        t, z = np.asarray(self.times_s, float), np.asarray(self.pad_z_mm, float)
        if t.ndim != 1 or t.shape != z.shape or len(t) == 0:
            raise CalibrationError("a drift track needs as many pad readings as times (at least one)",
                                   field="drift.times_s", value=[t.size, z.size])
        if not (np.isfinite(t).all() and np.isfinite(z).all()):
            raise CalibrationError("drift track times and readings must be finite", field="drift")
        if np.any(np.diff(t) < 0):
            raise CalibrationError("drift track times must not decrease", field="drift.times_s", value=t)
        object.__setattr__(self, "times_s", tuple(float(v) for v in t))
        object.__setattr__(self, "pad_z_mm", tuple(float(v) for v in z))

    def to_dict(self) -> dict[str, list[float]]:
        return {"times_s": list(self.times_s), "pad_z_mm": list(self.pad_z_mm)}


def drift_offsets(track: DriftTrack, times_s: npt.ArrayLike, reference_z_mm: float) -> npt.NDArray[np.float64]:
    """Offsets (n,) mm to ADD to readings taken at ``times_s`` (n,) machine seconds.

    reference_z_mm: the pad reading that means "no drift" (the first re-touch of the run, or
    the qualification's pad reading to correct drift since the calibration too).
    """
    t = _array(times_s, "times_s")
    if not np.isfinite(reference_z_mm):
        raise CalibrationError("reference_z_mm must be finite", field="reference_z_mm", value=reference_z_mm)
    return float(reference_z_mm) - np.interp(t, track.times_s, track.pad_z_mm)


def retouch_schedule(times_s: npt.ArrayLike, interval_s: float) -> list[int]:
    """Indices before which the pad is (re-)touched: 0, then every touch whose time is more than
    ``interval_s`` after the previous pad touch, and n (= after the last touch)."""
    t = _array(times_s, "times_s")
    if not np.isfinite(interval_s) or interval_s <= 0:
        raise CalibrationError("interval_s must be > 0 (s)", field="interval_s", value=interval_s)
    if len(t) == 0:
        return []
    out, last = [0], float(t[0])
    for i in range(1, len(t)):
        if t[i] - last > interval_s:
            out.append(i)
            last = float(t[i])
    out.append(len(t))
    return out
