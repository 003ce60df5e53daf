"""Nozzle-tip strokes of a circuit: compensated traces (with side passes when wide) and pad /
area fills lifted onto the real surface.

The real surface under a pad is the nominal surface (the part mesh, draped exactly) plus the
deviation the probes measured, interpolated between probe stations (linear over their
triangulation, the nearest station's value outside it).  Side passes of a wide trace follow
its compensated centre line, shifted by the nominal surface's height change across.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

from app.circuits.fills import fill_strokes, offset_polyline, pass_offsets

__all__ = ["deviation_field", "trace_passes", "fill_tip_strokes", "densify"]

HeightFn = Callable[[np.ndarray], np.ndarray]      # xy (m, 2) -> z (m,)


def deviation_field(stations_xy: np.ndarray, deviation_mm: np.ndarray) -> HeightFn:
    """Measured - nominal height at probe stations (n, 2) -> a function of xy (m, 2)."""
    xy = np.asarray(stations_xy, float)
    dz = np.asarray(deviation_mm, float)
    nearest = NearestNDInterpolator(xy, dz)
    linear = LinearNDInterpolator(xy, dz) if len(xy) >= 3 and np.linalg.matrix_rank(xy - xy.mean(0)) == 2 else None

    def field(q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, float)
        out = linear(q) if linear is not None else np.full(len(q), np.nan)
        miss = ~np.isfinite(out)
        if miss.any():
            out[miss] = nearest(q[miss])
        return out

    return field


def densify(xy: np.ndarray, step_mm: float) -> np.ndarray:
    """The polyline (k, 2) with extra vertices so no segment is longer than ``step_mm``."""
    xy = np.asarray(xy, float)
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    n = np.maximum(1, np.ceil(seg / step_mm)).astype(int)
    parts = [xy[i] + np.linspace(0, 1, n[i], endpoint=False)[:, None] * (xy[i + 1] - xy[i]) for i in range(len(seg))]
    return np.vstack(parts + [xy[-1:]])


def trace_passes(tip: np.ndarray, width_mm: float, line_width_mm: float, nominal_top: HeightFn) -> list[np.ndarray]:
    """Passes (each (k, 3)) of a compensated trace tip path (k, 3): the centre line itself when
    the trace is no wider than the line, else ceil(width / line) parallel passes."""
    tip = np.asarray(tip, float)
    offsets = pass_offsets(width_mm, line_width_mm)
    if len(offsets) == 1:
        return [tip]
    base = nominal_top(tip[:, :2])
    out = []
    for d in offsets:
        xy = offset_polyline(tip[:, :2], float(d))
        out.append(np.column_stack([xy, tip[:, 2] + nominal_top(xy) - base]))
    return out


def fill_tip_strokes(exterior: np.ndarray, holes: list[np.ndarray], line_width_mm: float,
                     drape: Callable[[np.ndarray], np.ndarray], deviation: HeightFn, standoff_mm: float,
                     step_mm: float = 0.25) -> list[np.ndarray]:
    """Tip strokes (k, 3) filling a pad or area: top-view fill strokes, densified to ``step_mm``,
    draped on the nominal surface (``drape``: xy (k, 2) -> points (m, 3)), lifted by the measured
    deviation and the standoff."""
    out = []
    for stroke in fill_strokes(exterior, holes, line_width_mm):
        pts = drape(densify(stroke, step_mm))
        out.append(np.column_stack([pts[:, :2], pts[:, 2] + deviation(pts[:, :2]) + standoff_mm]))
    return out
