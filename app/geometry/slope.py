"""Surface slope under a trace, and what a vertical nozzle can print (pure).

The slope at a trace point is the angle between the surface normal and +Z (0 deg: flat,
90 deg: a wall).  A vertical nozzle keeps its standoff along Z, so on a slope theta a
lateral (xy) error delta of the machine or of the part's placement becomes a height error
delta * tan(theta), and the bead lands on a surface tilted by theta: beyond
:attr:`SlopePolicy.max_deg` the trace is refused (use ``five_axis`` paths, which keep the
nozzle along the surface normal), above :attr:`SlopePolicy.warn_deg` it is accepted with a
warning.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from app.geometry.errors import GeometryError
from app.geometry.tolerance import DIVISION_FLOOR

DEFAULT_WARN_DEG = 30.0
DEFAULT_MAX_DEG = 60.0
DEFAULT_XY_UNCERTAINTY_MM = 0.01


class SteepTraceError(GeometryError):
    """The trace runs over a slope a vertical nozzle cannot print (422)."""


@dataclass(frozen=True)
class SlopePolicy:
    """``warn_deg``: accepted with a warning above; ``max_deg``: refused above (deg);
    ``xy_uncertainty_mm``: the lateral error the height-error estimate assumes."""

    warn_deg: float = DEFAULT_WARN_DEG
    max_deg: float = DEFAULT_MAX_DEG
    xy_uncertainty_mm: float = DEFAULT_XY_UNCERTAINTY_MM


@dataclass(frozen=True)
class SlopeReport:
    """``slopes_deg`` (k,); the largest, where it is (index, point (3,) mm), the height
    error a lateral error of ``xy_uncertainty_mm`` causes there (mm), and warnings."""

    slopes_deg: np.ndarray
    max_slope_deg: float
    index: int
    point: np.ndarray
    height_error_mm: float
    warnings: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        return {"max_slope_deg": round(self.max_slope_deg, 4), "at": np.round(self.point, 4).tolist(),
                "height_error_mm_per_xy_error": round(float(np.tan(np.radians(min(self.max_slope_deg, 89.999)))), 6),
                "height_error_mm": round(self.height_error_mm, 6), "warnings": list(self.warnings)}


def surface_slopes_deg(normals: np.ndarray) -> np.ndarray:
    """(k,) slope in degrees of the surface whose unit normals are ``normals`` (k, 3)."""
    n = np.asarray(normals, dtype=float)
    nz = np.abs(n[:, 2]) / np.maximum(np.linalg.norm(n, axis=1), DIVISION_FLOOR)
    out: np.ndarray = np.degrees(np.arccos(np.clip(nz, 0.0, 1.0)))
    return out


def height_error_mm(slope_deg: np.ndarray | float, xy_uncertainty_mm: float) -> np.ndarray | float:
    """Height error (mm) of a vertical-nozzle standoff caused by a lateral error on a slope."""
    return xy_uncertainty_mm * np.tan(np.radians(np.minimum(slope_deg, 89.999)))


def check_slope(points: np.ndarray, normals: np.ndarray, policy: SlopePolicy = SlopePolicy(),
                field: str = "geometry") -> SlopeReport:
    """The slope report of a trace (points (k, 3), normals (k, 3)); raises
    :class:`SteepTraceError` naming ``field`` when the largest slope passes ``max_deg``."""
    slopes = surface_slopes_deg(normals)
    k = int(np.argmax(slopes))
    worst = float(slopes[k])
    point = np.asarray(points, dtype=float)[k]
    error = float(height_error_mm(worst, policy.xy_uncertainty_mm))
    where = f"({point[0]:.3f}, {point[1]:.3f}, {point[2]:.3f})"
    if worst > policy.max_deg:
        raise SteepTraceError(
            f"the trace crosses a {worst:.1f} deg slope at {where}, beyond {policy.max_deg:g} deg for a vertical "
            f"nozzle (a {policy.xy_uncertainty_mm} mm lateral error is {error:.4f} mm of standoff there); print it "
            f"with a five_axis job (nozzle along the surface normal) or raise slope_max_deg",
            field=field, value=round(worst, 3))
    warnings: tuple[str, ...] = ()
    if worst > policy.warn_deg:
        warnings = (f"steep: the trace crosses a {worst:.1f} deg slope at {where} (warning above "
                    f"{policy.warn_deg:g} deg); a vertical nozzle's standoff there moves {error:.4f} mm per "
                    f"{policy.xy_uncertainty_mm} mm of lateral error - consider five_axis paths",)
    return SlopeReport(slopes, worst, k, point, error, warnings)
