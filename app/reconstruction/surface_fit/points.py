"""Measured (CMM) points for a surface fit: the CSV text they arrive in and the checks that
they can carry a fit before it runs.

* :func:`parse_points_csv` — CSV text -> points (k, 3) mm;
* :func:`check_points` — enough distinct (x, y) positions, spread over an area, one height
  per position when they are resampled onto a grid.

Both raise :class:`~app.reconstruction.surface_fit.errors.SurfaceFitError` naming the
input (``points_csv`` for the text, ``points`` for the checked array), as the fit does.
"""

from __future__ import annotations

import math
import re

import numpy as np
import numpy.typing as npt

from app.reconstruction.surface_fit.errors import SurfaceFitError
from app.reconstruction.surface_fit.fit import SurfaceFitParams

__all__ = ["BAD_POINT_FACTOR", "check_points", "parse_points_csv", "points_needed"]

BAD_POINT_FACTOR = 2  # find_bad_points fits a patch of its own: twice its (degree + 1)^2 unknowns
_CSV_SEPARATOR = re.compile(r"[,;\s]+")


def parse_points_csv(text: str, max_points: int | None = None) -> npt.NDArray[np.float64]:
    """CSV text -> points (k, 3) mm, k >= 1.

    One ``x, y, z`` per line (separators ``,`` ``;`` or blanks); blank lines and ``#``
    comments are skipped, and so is one header line before the first point.  Raises
    SurfaceFitError (field ``points_csv``) naming the first bad line (not three finite
    numbers), for text without points, or for more than ``max_points`` points.
    """
    rows: list[list[float]] = []
    header_skipped = False
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        cells = [cell for cell in _CSV_SEPARATOR.split(stripped) if cell]
        try:
            values = [float(cell) for cell in cells]
        except ValueError:
            if not rows and not header_skipped:
                header_skipped = True
                continue
            raise SurfaceFitError(f"line {number}: {stripped[:60]!r} is not three numbers x, y, z",
                                  field="points_csv", value=number) from None
        if len(values) != 3 or not all(math.isfinite(v) for v in values):
            raise SurfaceFitError(f"line {number}: {stripped[:60]!r} is not three finite numbers x, y, z",
                                  field="points_csv", value=number)
        rows.append(values)
        if max_points is not None and len(rows) > max_points:
            raise SurfaceFitError(f"more than {max_points} points", field="points_csv", value=max_points)
    if not rows:
        raise SurfaceFitError("no points (expected one 'x, y, z' per line)", field="points_csv", value=0)
    return np.array(rows, dtype=float)


def points_needed(fit: SurfaceFitParams) -> int:
    """Fewest distinct (x, y) positions a fit with these parameters can use: the
    (degree + 1)^2 unknowns of one patch, twice that when bad points are looked for."""
    return (fit.degree + 1) ** 2 * (BAD_POINT_FACTOR if fit.remove_bad_points else 1)


def check_points(points: npt.NDArray[np.float64], fit: SurfaceFitParams) -> None:
    """Points (k, 3) mm must be at least :func:`points_needed` distinct (x, y) positions
    spanning an area (not all on one line), and with ``fit.resample_shape`` no (x, y)
    position may repeat.  Raises SurfaceFitError (field ``points``) otherwise."""
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] == 0 or not np.isfinite(pts).all():
        raise SurfaceFitError(f"points must be a finite (k, 3) array, got shape {pts.shape}",
                              field="points", value=list(pts.shape))
    xy = np.unique(pts[:, :2], axis=0)
    needed = points_needed(fit)
    if xy.shape[0] < needed:
        raise SurfaceFitError(
            f"{xy.shape[0]} distinct (x, y) positions; a degree-{fit.degree} surface needs at least {needed}"
            + (" (with remove_bad_points)" if fit.remove_bad_points else ""), field="points", value=xy.shape[0])
    if np.linalg.matrix_rank(xy - xy.mean(axis=0)) < 2:
        raise SurfaceFitError("the points lie on one line in (x, y): they span no area", field="points",
                              value=xy[:2])
    if fit.resample_shape is not None and xy.shape[0] < pts.shape[0]:
        raise SurfaceFitError(f"{pts.shape[0] - xy.shape[0]} points repeat an (x, y) position: "
                              "resample_to_grid needs one height per position", field="points",
                              value=pts.shape[0] - xy.shape[0])
