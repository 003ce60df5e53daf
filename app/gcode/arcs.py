"""XY arcs of G2/G3 lines: their circles and exact extents, many at once (pure, vectorised).

An arc goes from ``start`` to ``end`` around a centre given by ``I J`` (offsets from the
start) or ``R`` (the radius; negative: the long way round), clockwise for G2.  Its radius
goes linearly from the start's to the end's (they may differ by the reader's tolerance), Z
and E linearly with the angle (a helix).  :func:`arc_circles` gives each arc's centre, radii
and swept angle exactly as :class:`app.gcode.reader.ModalReader` chords them;
:func:`arc_extents` gives the lowest and highest XYZ an arc reaches without any chord: the
end points and the points where the arc crosses the axis directions (multiples of 90
degrees) around its centre, at most four.  Its cost is a few array operations per batch of
arcs whatever their chord tolerance or radius.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from app.geometry.tolerance import DEGENERATE_LENGTH_MM, LENGTH_EPS_MM

__all__ = ["ArcCircles", "arc_circles", "arc_extents", "arc_chord_counts", "FULL_CIRCLE_SWEEP_RAD",
           "MIN_ARC_TOLERANCE_MM", "MIN_ARC_STEP_RAD"]

#: an arc whose end angle is within this (rad) of its start angle, against its direction,
#: sweeps a full circle
FULL_CIRCLE_SWEEP_RAD = 1e-12
#: floor (mm) of the chord tolerance an arc is flattened with
MIN_ARC_TOLERANCE_MM = 1e-6
#: floor (rad) of an arc's angular step: one arc is at most 2 pi / this many chords
MIN_ARC_STEP_RAD = 1e-6
_QUARTER = math.pi / 2
#: cos and sin of k * 90 degrees, k mod 4 (exact: no 6e-17 for cos 90)
_COS = np.array([1.0, 0.0, -1.0, 0.0])
_SIN = np.array([0.0, 1.0, 0.0, -1.0])

Floats = npt.NDArray[np.float64]


class ArcCircles(NamedTuple):
    """k arcs: centre (k, 2) mm; r0, r1 (k,) radius at the start and the end (mm); a0 (k,)
    start angle (rad, atan2 around the centre); sweep (k,) signed angle swept (rad, negative
    clockwise); ``problem``: None, or (index of the first arc that is not one, its reason)."""

    centre: Floats
    r0: Floats
    r1: Floats
    a0: Floats
    sweep: Floats
    problem: tuple[int, str] | None


def arc_circles(start: Floats, end: Floats, clockwise: npt.NDArray[np.bool_], ij: Floats, r: Floats,
                use_r: npt.NDArray[np.bool_], use_ij: npt.NDArray[np.bool_], r_word: Floats) -> ArcCircles:
    """The circles of k arcs from ``start`` to ``end`` (k, >= 2) mm: ``ij`` (k, 2) centre
    offsets (mm) where ``use_ij``, ``r`` (k,) radii (mm) where ``use_r`` (R wins), ``r_word``
    (k,) the R words as written (for the message).  An arc whose R cannot join its ends,
    with neither centre nor radius, or whose end is off its circle is the ``problem``."""
    k = len(start)
    sxy, exy = start[:, :2], end[:, :2]
    bad = np.zeros(k, bool)
    reason = np.zeros(k, np.int8)         # 1: R cannot join, 2: no centre, 3: end off its circle
    chord = exy - sxy
    half = np.hypot(chord[:, 0], chord[:, 1]) / 2.0
    r_bad = use_r & ((half < DEGENERATE_LENGTH_MM) | (np.abs(r) < half - LENGTH_EPS_MM))
    reason[r_bad] = 1
    no_centre = ~use_r & ~use_ij
    reason[no_centre] = 2
    bad |= r_bad | no_centre
    with np.errstate(invalid="ignore", divide="ignore"):
        offset = np.sqrt(np.maximum(r * r - half * half, 0.0))
        middle = (sxy + exy) / 2.0
        normal = np.stack([-chord[:, 1], chord[:, 0]], axis=1) / (2.0 * half)[:, None]
        # the centre lies left of the chord for a short CCW (or long CW) arc
        sign = np.where(clockwise == (r < 0), 1.0, -1.0)
        from_r = middle + (sign * offset)[:, None] * normal
    centre = np.where(use_r[:, None], from_r, sxy + ij)
    r0 = np.hypot(sxy[:, 0] - centre[:, 0], sxy[:, 1] - centre[:, 1])
    r1 = np.hypot(exy[:, 0] - centre[:, 0], exy[:, 1] - centre[:, 1])
    off = ~bad & ((r0 < LENGTH_EPS_MM) | (np.abs(r0 - r1) > np.maximum(0.005, 1e-3 * r0)))
    reason[off] = 3
    bad |= off
    a0 = np.arctan2(sxy[:, 1] - centre[:, 1], sxy[:, 0] - centre[:, 0])
    a1 = np.arctan2(exy[:, 1] - centre[:, 1], exy[:, 0] - centre[:, 0])
    sweep = a1 - a0
    sweep = np.where(clockwise, np.where(sweep >= -FULL_CIRCLE_SWEEP_RAD, sweep - 2 * math.pi, sweep),
                     np.where(sweep <= FULL_CIRCLE_SWEEP_RAD, sweep + 2 * math.pi, sweep))
    problem = None
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        if reason[i] == 1:
            text = f"arc radius {float(r_word[i]):g} cannot join its end points"
        elif reason[i] == 2:
            text = "an arc needs I/J or R"
        else:
            text = f"arc end is not on its circle (radius {float(r0[i]):.4f} vs {float(r1[i]):.4f} mm)"
        problem = (i, text)
    return ArcCircles(centre, r0, r1, a0, sweep, problem)


def arc_chord_counts(r0: Floats, sweep: Floats, tolerance_mm: float) -> Floats:
    """(k,) float: the chords each of k arcs of start radius ``r0`` (k,) mm and signed
    ``sweep`` (k,) rad is split into at a sagitta of ``tolerance_mm`` (floored at
    :data:`MIN_ARC_TOLERANCE_MM`): n = ceil(|sweep| / step), step = 2 acos(1 - tol / r0)
    (a quarter turn when tol >= r0), at least :data:`MIN_ARC_STEP_RAD`; at least 1.  Counted
    without making any chord, whatever the radius: the modal reader splits each arc into
    exactly this many (:class:`app.gcode.reader.ModalReader`)."""
    tol = max(float(tolerance_mm), MIN_ARC_TOLERANCE_MM)
    r0 = np.asarray(r0, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        step = np.where(tol < r0, 2.0 * np.arccos(np.maximum(1.0 - tol / r0, -1.0)), math.pi / 2)
    count: Floats = np.maximum(1.0, np.ceil(np.abs(sweep) / np.maximum(step, MIN_ARC_STEP_RAD)))
    return count


def arc_extents(start: Floats, end: Floats, circles: ArcCircles) -> tuple[Floats, Floats]:
    """(low, high) (k, 3) mm: the lowest and highest XYZ each arc reaches (``start``/``end``
    (k, >= 3) mm, ``circles`` from :func:`arc_circles`; Z is linear in the angle, so its
    extremes are the ends).  Exact for a circle; for a radius that changes along the arc,
    the radius at each axis crossing (the spiral's extreme is within (r1 - r0)^2 / r of it)."""
    low = np.minimum(start[:, :3], end[:, :3])
    high = np.maximum(start[:, :3], end[:, :3])
    a0, sweep = circles.a0, circles.sweep
    lo_angle, hi_angle = np.minimum(a0, a0 + sweep), np.maximum(a0, a0 + sweep)
    first = np.ceil(lo_angle / _QUARTER)
    safe_sweep = np.where(sweep == 0.0, 1.0, sweep)
    for step in range(5):             # a sweep of at most 360 degrees crosses at most 5 axis directions
        m = first + step
        inside = m * _QUARTER <= hi_angle
        if not inside.any():
            break
        t = np.clip((m * _QUARTER - a0) / safe_sweep, 0.0, 1.0)
        radius = circles.r0 + (circles.r1 - circles.r0) * t
        quarter = np.mod(m, 4).astype(np.int64)
        x = circles.centre[:, 0] + radius * _COS[quarter]
        y = circles.centre[:, 1] + radius * _SIN[quarter]
        low[:, 0] = np.where(inside, np.minimum(low[:, 0], x), low[:, 0])
        low[:, 1] = np.where(inside, np.minimum(low[:, 1], y), low[:, 1])
        high[:, 0] = np.where(inside, np.maximum(high[:, 0], x), high[:, 0])
        high[:, 1] = np.where(inside, np.maximum(high[:, 1], y), high[:, 1])
    return low, high
