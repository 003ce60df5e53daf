"""What the service calls to create a trace: geometry dict -> nominal trace on the part.

frame "xy": the design curve is drawn in the part's top view; it becomes a top-view
polyline within ``tolerance.chord_mm`` (verified CL points) and is draped exactly onto the
mesh's upper surface.  frame "3d": the curve lies on the surface; its CL points are snapped
to the mesh and any point farther than ``tolerance.snap_mm`` is an error naming it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal, NamedTuple

import numpy as np
import trimesh

from app.geometry.cl_points import cl_points
from app.geometry.drape import drape_polyline, snap_to_surface
from app.geometry.errors import GeometryError
from app.geometry.nurbs import NurbsCurve
from app.geometry.shapes import trace_curve
from app.geometry.tolerance import DEFAULT_TOLERANCE, Tolerance

__all__ = ["NominalTrace", "build_nominal_trace"]

Frame = Literal["xy", "3d"]


class NominalTrace(NamedTuple):
    """curve: the design curve (2-D for "xy", 3-D for "3d"); points (k, 3) mm on the surface;
    normals (k, 3) unit, upward; length_mm; z_range (zmin, zmax) mm; slope_stretch = 3-D
    length / top-view length; s_mm (k,) cumulative 3-D length along points."""

    curve: NurbsCurve
    points: np.ndarray
    normals: np.ndarray
    length_mm: float
    z_range: tuple[float, float]
    slope_stretch: float
    s_mm: np.ndarray


def build_nominal_trace(
    mesh: trimesh.Trimesh, geometry: Mapping[str, Any], frame: Frame = "xy",
    tolerance: Tolerance = DEFAULT_TOLERANCE,
) -> NominalTrace:
    """Geometry dict (API form) + part mesh -> the nominal trace on the part's surface.

    Raises GeometryError subclasses (-> 422): bad geometry, zero length, off the surface.
    """
    curve = trace_curve(geometry, tolerance=tolerance)
    if frame == "xy":
        if curve.dimension != 2:
            raise GeometryError(
                "frame 'xy' takes top-view (x, y) coordinates; use frame '3d' for points on the surface",
                field="geometry", value=curve.dimension,
            )
        top_view = cl_points(curve, tolerance.chord_mm)
        draped = drape_polyline(mesh, top_view.points, tolerance)
        points, normals, s_mm = draped.points, draped.normals, draped.s_mm
        stretch = draped.slope_stretch
    elif frame == "3d":
        if curve.dimension != 3:
            raise GeometryError("frame '3d' takes (x, y, z) coordinates", field="geometry", value=curve.dimension)
        samples = cl_points(curve, tolerance.chord_mm)
        snapped = snap_to_surface(mesh, samples.points, tolerance.snap_mm)
        points, normals = snapped.points, snapped.normals
        s_mm = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
        xy_len = float(np.linalg.norm(np.diff(points[:, :2], axis=0), axis=1).sum())
        stretch = float(s_mm[-1] / xy_len) if xy_len > 0 else float("inf")
    else:
        raise GeometryError("frame must be 'xy' or '3d'", field="frame", value=frame)
    return NominalTrace(
        curve, points, normals, float(s_mm[-1]),
        (float(points[:, 2].min()), float(points[:, 2].max())), stretch, s_mm,
    )
