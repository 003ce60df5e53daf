"""Continuous choice of the (A, C) solution branch along a path, with a pole window.

Every normal has two solutions (A, C) and (-A, C + pi) (see :mod:`.kinematics`).  Along a
path we pick, per point, the branch that minimises the total rotary motion
``sum |dA| + c_weight * |dC|`` subject to the A limits (a two-state Viterbi pass), then
unwrap C so that every move takes the short way (``|dC| <= pi``; no 360-degree flips).

Singularity (A = 0).  Near the pole the normal's azimuth, and with it the exact C, turns
fast: a straight path passing a sphere's apex at distance d needs C to turn by about
180 degrees at up to 1/d rad per mm of path, which a machine cannot follow and which makes
the tool tip leave the path between program lines.  Points whose normal is tilted from
+Z by at most ``pole_tilt_rad`` form a *pole window*.  There C is not taken from the
normal: it is blended linearly in path length (``arc_mm``) from the C where the path
enters the window to the C where it leaves it, and the branch after the window is chosen
(by the same Viterbi pass) so that this turn is the smallest; a path through the apex
thus keeps C and flips the sign of A.  Windows at the start or end of the path hold the
C of the nearest point outside them (so C is set by the approach move and does not turn
while printing); a path that is all window holds ``c_start_rad``.  In the window A is
the tilt that best aligns the tool axis with the normal for that C
(``A = atan2(nx sin C + ny cos C, nz)``), so the residual angle between tool axis and
normal is at most the normal's tilt, i.e. at most ``pole_tilt_rad``.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import numpy as np
import numpy.typing as npt

from app.five_axis.errors import AxisLimitError
from app.five_axis.kinematics import MachineConfig, angles_for_normal

__all__ = ["BranchChoice", "choose_axes", "wrap_angle", "best_tilt"]

#: round-off slack (rad) of "this angle lies within the axis limits"
_LIMIT_SLACK_RAD = 1e-12
#: default half-angle (rad) of the pole window around +Z where C is held, not solved
_POLE_TILT_RAD = 1e-6


@dataclass(frozen=True)
class BranchChoice:
    """Chosen rotary angles for k path points.

    a_rad, c_rad: (k,) angles (C unwrapped: continuous, consecutive moves <= pi).
    branch: (k,) int, +1 where A >= 0 was chosen, -1 where A < 0.
    held: (k,) bool, True inside a pole window (C blended or held, not from the normal).
    """

    a_rad: npt.NDArray[np.float64]
    c_rad: npt.NDArray[np.float64]
    branch: npt.NDArray[np.int64]
    held: npt.NDArray[np.bool_]


def wrap_angle(x: npt.NDArray[np.float64] | float) -> npt.NDArray[np.float64]:
    """Wrap angles (rad) into [-pi, pi)."""
    return (np.asarray(x, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


def best_tilt(normals: npt.NDArray[np.float64], c_rad: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """A (k,) rad that best aligns the tool axis with unit normals (k,3) for given C (k,)."""
    n = np.atleast_2d(normals)
    return np.arctan2(n[:, 0] * np.sin(c_rad) + n[:, 1] * np.cos(c_rad), n[:, 2])


def _a_feasible(a: float, limits: tuple[float, float]) -> bool:
    return limits[0] - _LIMIT_SLACK_RAD <= a <= limits[1] + _LIMIT_SLACK_RAD


def _limit_error(i: int, a_pos: float, lim: tuple[float, float], n: npt.NDArray[np.float64],
                 field: str) -> AxisLimitError:
    return AxisLimitError(
        f"point {i}: the normal needs A = {np.degrees(a_pos):.3f} or {-np.degrees(a_pos):.3f} "
        f"deg, outside the A limits [{np.degrees(lim[0]):.3f}, {np.degrees(lim[1]):.3f}] deg",
        field=field, value={"index": i, "normal": n, "a_deg": np.degrees(a_pos),
                            "a_limits_deg": np.degrees(np.asarray(lim))})


def _viterbi(free: npt.NDArray[np.int64], n: npt.NDArray[np.float64], a_pos: npt.NDArray[np.float64],
             c_pos: npt.NDArray[np.float64],
             lim: tuple[float, float], c_start: float, c_weight: float,
             field: str) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Branch choice over the points ``free`` (outside pole windows): (A, wrapped C)."""
    m = free.size
    a_state, c_state = np.zeros((m, 2)), np.zeros((m, 2))
    back = np.zeros((m, 2), dtype=int)
    cost, prev_a, prev_c = np.zeros(2), np.zeros(2), np.full(2, wrap_angle(c_start))
    for j, i in enumerate(free):
        new_cost = np.full(2, np.inf)
        for s_idx, s in enumerate((1, -1)):
            a = s * a_pos[i]
            c = float(wrap_angle(c_pos[i] + (0.0 if s == 1 else np.pi)))
            a_state[j, s_idx], c_state[j, s_idx] = a, c
            if not _a_feasible(a, lim):
                continue
            for p in (0, 1):
                step = abs(a - prev_a[p]) + c_weight * abs(float(wrap_angle(c - prev_c[p])))
                if cost[p] + step < new_cost[s_idx]:
                    new_cost[s_idx], back[j, s_idx] = cost[p] + step, p
        if not np.isfinite(new_cost).any():
            raise _limit_error(int(i), float(a_pos[i]), lim, n[i], field)
        cost, prev_a, prev_c = new_cost, a_state[j].copy(), c_state[j].copy()
    states = np.zeros(m, dtype=int)
    states[-1] = int(np.argmin(cost))
    for j in range(m - 1, 0, -1):
        states[j - 1] = back[j, states[j]]
    idx = np.arange(m)
    return a_state[idx, states], c_state[idx, states]


def _fill_pole_windows(c_wrapped: npt.NDArray[np.float64], pole: npt.NDArray[np.bool_], arc: npt.NDArray[np.float64],
                       c_start: float) -> None:
    """C inside pole windows (in place): blended between the window's neighbours, held
    at a path end, ``c_start`` if there is no point outside the windows."""
    free = np.flatnonzero(~pole)
    if free.size == 0:
        c_wrapped[:] = wrap_angle(c_start)
        return
    c_wrapped[:free[0]] = c_wrapped[free[0]]
    c_wrapped[free[-1] + 1:] = c_wrapped[free[-1]]
    for j0, j1 in pairwise(free):
        if j1 - j0 < 2:
            continue
        span = arc[j1] - arc[j0]
        w = ((arc[j0 + 1:j1] - arc[j0]) / span if span > 0
             else np.linspace(0.0, 1.0, j1 - j0 + 1)[1:-1])
        c_wrapped[j0 + 1:j1] = c_wrapped[j0] + w * float(wrap_angle(c_wrapped[j1] - c_wrapped[j0]))


def choose_axes(normals: npt.NDArray[np.float64], config: MachineConfig, *, c_start_rad: float = 0.0,
                pole_tilt_rad: float = _POLE_TILT_RAD, arc_mm: npt.NDArray[np.float64] | None = None,
                c_weight: float = 1.0, field: str = "params.a_limits_deg") -> BranchChoice:
    """Rotary angles bringing each unit normal (k,3) to +Z, branches chosen continuously.

    pole_tilt_rad: half-angle of the pole window around +Z (see module doc).
    arc_mm: (k,) path position of each point (mm, increasing) for blending C across a pole
    window; None: equally spaced.  c_start_rad: C before the path (biases the first branch;
    held when the whole path lies in the pole window).
    Raises AxisLimitError (naming the point index, the normal and both candidate A values
    in degrees) when no branch keeps A within ``config.a_limits_rad`` or the unwrapped C
    leaves ``config.c_limits_rad``.
    """
    n = np.atleast_2d(np.asarray(normals, dtype=float))
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    k = n.shape[0]
    arc = np.arange(k, dtype=float) if arc_mm is None else np.asarray(arc_mm, dtype=float)
    cand = angles_for_normal(n)
    lim = config.a_limits_rad
    pole = cand.a_pos <= pole_tilt_rad
    free = np.flatnonzero(~pole)
    a_out, c_wrapped = np.zeros(k), np.zeros(k)
    if free.size:
        a_out[free], c_wrapped[free] = _viterbi(free, n, cand.a_pos, cand.c_pos, lim,
                                                c_start_rad, c_weight, field)
    _fill_pole_windows(c_wrapped, pole, arc, c_start_rad)
    c_out = np.empty(k)
    previous = float(c_start_rad)
    for i in range(k):
        previous = previous + float(wrap_angle(c_wrapped[i] - previous))
        c_out[i] = previous
    in_window = np.flatnonzero(pole)
    if in_window.size:
        a_best = best_tilt(n[in_window], c_out[in_window])
        if lim[0] <= 0.0 <= lim[1]:
            a_best = np.clip(a_best, lim[0], lim[1])  # |A| <= tilt: closer to the normal than A = 0
        bad = np.flatnonzero((a_best < lim[0] - _LIMIT_SLACK_RAD)
                             | (a_best > lim[1] + _LIMIT_SLACK_RAD))
        if bad.size:
            i = int(in_window[bad[0]])
            raise _limit_error(i, float(cand.a_pos[i]), lim, n[i], field)
        a_out[in_window] = a_best
    if config.c_limits_rad is not None:
        lo, hi = config.c_limits_rad
        bad = np.flatnonzero((c_out < lo - _LIMIT_SLACK_RAD) | (c_out > hi + _LIMIT_SLACK_RAD))
        if bad.size:
            j = int(bad[0])
            raise AxisLimitError(
                f"point {j}: C = {np.degrees(c_out[j]):.3f} deg is outside the C limits "
                f"[{np.degrees(lo):.3f}, {np.degrees(hi):.3f}] deg",
                field="params.c_limits_deg",
                value={"index": j, "c_deg": np.degrees(c_out[j])})
    return BranchChoice(a_rad=a_out, c_rad=c_out, branch=np.where(a_out >= 0, 1, -1), held=pole)
