"""Nozzle-tip strokes of a circuit: compensated traces (with side passes when wide) and pad /
area fills lifted onto the real surface.

The real surface under a pad is the measured surface the whole program follows
(:class:`app.circuits.surface.MeasuredSurface`: the nominal top plus the loop's fitted field,
or, without one, the deviation interpolated between probe stations by
:func:`deviation_field`: linear over their triangulation, the nearest station's value
outside it).  Side passes of a wide trace follow
its compensated centre line, shifted by the measured surface's height change across.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt
from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

from app.circuits.fills import fill_strokes, offset_polyline, pass_offsets

__all__ = ["deviation_field", "trace_passes", "trace_passes_many", "fill_tip_strokes", "densify"]

HeightFn = Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]]      # xy (m, 2) -> z (m,)


def deviation_field(stations_xy: npt.NDArray[np.float64], deviation_mm: npt.NDArray[np.float64]) -> HeightFn:
    """Measured - nominal height at probe stations (n, 2) -> a function of xy (m, 2)."""
    xy = np.asarray(stations_xy, float)
    dz = np.asarray(deviation_mm, float)
    nearest = NearestNDInterpolator(xy, dz)
    linear = LinearNDInterpolator(xy, dz) if len(xy) >= 3 and np.linalg.matrix_rank(xy - xy.mean(0)) == 2 else None

    def field(q: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        q = np.asarray(q, float)
        out = linear(q) if linear is not None else np.full(len(q), np.nan)
        miss = ~np.isfinite(out)
        if miss.any():
            out[miss] = nearest(q[miss])
        return out

    return field


def densify(xy: npt.NDArray[np.float64], step_mm: float) -> npt.NDArray[np.float64]:
    """The polyline (k, 2) with extra vertices so no segment is longer than ``step_mm``."""
    xy = np.asarray(xy, float)
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    n = np.maximum(1, np.ceil(seg / step_mm)).astype(int)
    parts = [xy[i] + np.linspace(0, 1, n[i], endpoint=False)[:, None] * (xy[i + 1] - xy[i]) for i in range(len(seg))]
    return np.vstack(parts + [xy[-1:]])


def trace_passes(tip: npt.NDArray[np.float64], width_mm: float, line_width_mm: float,
                 surface_z: HeightFn) -> list[npt.NDArray[np.float64]]:
    """Passes (each (k, 3)) of a compensated trace tip path (k, 3): the centre line itself when
    the trace is no wider than the line, else ceil(width / line) parallel passes, each shifted
    by the height change of ``surface_z`` (xy (m, 2) -> z (m,)) across."""
    return trace_passes_many([tip], [width_mm], line_width_mm, surface_z)[0]


def trace_passes_many(tips: list[npt.NDArray[np.float64]], widths_mm: list[float], line_width_mm: float,
                      surface_z: HeightFn) -> list[list[npt.NDArray[np.float64]]]:
    """:func:`trace_passes` of many traces (tips (k_i, 3), widths mm) with ONE evaluation of
    ``surface_z`` over every centre line and side pass that needs it (a board's thousands of
    traces: one large evaluation, not a few small ones each)."""
    plans: list[list[npt.NDArray[np.float64]] | None] = []
    wanted: list[npt.NDArray[np.float64]] = []
    for tip, width in zip(tips, widths_mm):
        tip = np.asarray(tip, float)
        offsets = pass_offsets(width, line_width_mm)
        if len(offsets) == 1:
            plans.append(None)
            continue
        sides = [offset_polyline(tip[:, :2], float(d)) for d in offsets]
        plans.append(sides)
        wanted += [tip[:, :2], *sides]
    z = surface_z(np.vstack(wanted)) if wanted else np.empty(0)
    out: list[list[npt.NDArray[np.float64]]] = []
    k = 0
    for tip, plan in zip(tips, plans):
        tip = np.asarray(tip, float)
        if plan is None:
            out.append([tip])
            continue
        base = z[k:k + len(tip)]
        k += len(tip)
        passes = []
        for xy in plan:
            passes.append(np.column_stack([xy, tip[:, 2] + z[k:k + len(xy)] - base]))
            k += len(xy)
        out.append(passes)
    return out


def fill_tip_strokes(exterior: npt.NDArray[np.float64], holes: list[npt.NDArray[np.float64]], line_width_mm: float,
                     drape: Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]], surface_z: HeightFn,
                     standoff_mm: float,
                     step_mm: float = 0.25, angle_deg: float = 0.0) -> list[npt.NDArray[np.float64]]:
    """Tip strokes (k, 3) filling a pad or area: top-view fill strokes, densified to ``step_mm``
    and to the nominal surface's facets (``drape``: xy (k, 2) -> points (m, 3)), each point at
    the measured surface (``surface_z``: xy (m, 2) -> z (m,), nominal + measured deviation)
    plus the standoff; the raster lines run at ``angle_deg`` from x."""
    xys = [drape(densify(stroke, step_mm))[:, :2] for stroke in fill_strokes(exterior, holes, line_width_mm, angle_deg)]
    if not xys:
        return []
    z = surface_z(np.vstack(xys)) + standoff_mm                         # one evaluation for the whole fill
    ends = np.cumsum([len(xy) for xy in xys])[:-1]
    return [np.column_stack([xy, zs]) for xy, zs in zip(xys, np.split(z, ends))]
