"""The verification residuals of a closed loop as a map on the part.

A field loop touches a few verification points after its stations (never used in the fit) and
records, per point, the measured deviation, the field's prediction and the band the residual
had to stay within (the loop result's ``verdict``, :mod:`app.reconstruction.field_trust`).
:func:`residual_map` places each point on its trace's nominal (the foot of its xy on the
polyline), lifted by the measured deviation, with its residual (measured - predicted, mm) and
a flag where it is outside its band or where the correction does not help (the compensated
program would be worse than the nominal one there).  The view colours the points by residual
on their own diverging scale (µm, legend "verification residual") and highlights the flagged
points and the traces the verdict names worse than nominal.

numpy only.  Units: mm.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from app.viewer.scene_data import ResidualMap
from app.viewer.trace_math import project_onto_polyline

__all__ = ["residual_map"]


def _foot_z(xy: np.ndarray, nominals: Sequence[np.ndarray]) -> float:
    """The nominal height (mm) under top-view point xy (2,) on the nearest of the polylines."""
    best, z = np.inf, 0.0
    point = np.array([[xy[0], xy[1], 0.0]])
    for nominal in nominals:
        foot = project_onto_polyline(point, nominal).nominal[0]
        d = float(np.hypot(*(foot[:2] - xy)))
        if d < best:
            best, z = d, float(foot[2])
    return z


def residual_map(verdict: Mapping[str, Any] | None, trace_ids: Sequence[str],
                 nominals: Mapping[str, np.ndarray], name: str = "verification residuals") -> ResidualMap | None:
    """The verdict's verification points (each ``xy``, ``trace`` (the plan's trace index),
    ``measured_mm``, ``residual_mm``, ``limit_mm``, ``within``, ``worse``) on the part: the
    trace index names ``trace_ids[index]``, whose nominal polyline (k, 3) mm in ``nominals``
    gives the height (the nearest of all nominals when the index names none).  None without
    verification points or nominals."""
    points = list((verdict or {}).get("verification") or [])
    if not points or not nominals:
        return None
    every = list(nominals.values())
    xyz, owners = [], []
    for p in points:
        index = p.get("trace")
        owner = trace_ids[index] if isinstance(index, int) and 0 <= index < len(trace_ids) else None
        xy = np.asarray(p["xy"], float)
        own = [nominals[owner]] if owner is not None and owner in nominals else every
        xyz.append([xy[0], xy[1], _foot_z(xy, own) + float(p["measured_mm"])])
        owners.append(owner)
    residual = np.array([float(p["residual_mm"]) for p in points])
    limit = np.array([float(p["limit_mm"]) for p in points])
    flagged = np.array([not p.get("within", True) or bool(p.get("worse", False)) for p in points])
    return ResidualMap(name, np.array(xyz), residual, limit, flagged, tuple(owners))
