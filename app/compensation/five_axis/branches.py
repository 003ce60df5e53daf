"""Continuous choice of the (A, C) solution branch along a path.

Every normal has two solutions (A, C) and (-A, C + pi) (see :mod:`.kinematics`).  Along a
path we pick, per point, the branch that minimises the total rotary motion
``sum |dA| + c_weight * |dC|`` subject to the A limits (a two-state Viterbi pass), then
unwrap C so that every move takes the short way (``|dC| <= pi``; no 360-degree flips).

Singularity: where the normal is vertical within ``singular_rho`` (= sin of the tilt),
C is undefined; the previous C is held and A is the best tilt for that C (the residual
angle between the tool axis and the normal is then at most ``asin(singular_rho)``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.compensation.five_axis.errors import AxisLimitError
from app.compensation.five_axis.kinematics import MachineConfig, angles_for_normal

__all__ = ["BranchChoice", "choose_axes", "wrap_angle"]

_LIMIT_SLACK_RAD = 1e-12


@dataclass(frozen=True)
class BranchChoice:
    """Chosen rotary angles for k path points.

    a_rad, c_rad: (k,) angles (C unwrapped: continuous, consecutive moves <= pi).
    branch: (k,) int, +1 where A >= 0 was chosen, -1 where A <= 0.
    held: (k,) bool, True where C was held at a (near-)vertical normal.
    """

    a_rad: np.ndarray
    c_rad: np.ndarray
    branch: np.ndarray
    held: np.ndarray


def wrap_angle(x: np.ndarray | float) -> np.ndarray:
    """Wrap angles (rad) into [-pi, pi)."""
    return (np.asarray(x, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


def _a_feasible(a: float, limits: tuple[float, float]) -> bool:
    return limits[0] - _LIMIT_SLACK_RAD <= a <= limits[1] + _LIMIT_SLACK_RAD


def choose_axes(normals: np.ndarray, config: MachineConfig, *, c_start_rad: float = 0.0,
                singular_rho: float = 1e-6, c_weight: float = 1.0,
                field: str = "params.a_limits_deg") -> BranchChoice:
    """Rotary angles bringing each unit normal (k,3) to +Z, branches chosen continuously.

    c_start_rad: C before the path (held while the first normals are vertical).
    Raises AxisLimitError (naming the point index, the normal and both candidate A values
    in degrees) when no branch keeps A within ``config.a_limits_rad`` or the unwrapped C
    leaves ``config.c_limits_rad``.
    """
    n = np.atleast_2d(np.asarray(normals, dtype=float))
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    cand = angles_for_normal(n)
    k = n.shape[0]
    lim = config.a_limits_rad
    signs = (1, -1)
    # per state: cost, A, C (wrapped, or carried), and back pointers
    cost = np.zeros(2)
    a_state = np.zeros((k, 2))
    c_state = np.zeros((k, 2))
    back = np.zeros((k, 2), dtype=int)
    prev_a = np.zeros(2)
    prev_c = np.full(2, wrap_angle(c_start_rad))
    for i in range(k):
        new_cost = np.full(2, np.inf)
        singular = cand.rho[i] <= singular_rho
        for s_idx, s in enumerate(signs):
            if singular:
                c = prev_c[s_idx]
                a = float(np.arctan2(n[i, 0] * np.sin(c) + n[i, 1] * np.cos(c), n[i, 2]))
                preds = (s_idx,)
            else:
                a = s * cand.a_pos[i]
                c = float(wrap_angle(cand.c_pos[i] + (0.0 if s == 1 else np.pi)))
                preds = (0, 1)
            a_state[i, s_idx], c_state[i, s_idx] = a, c
            if not _a_feasible(a, lim):
                continue
            for p in preds:
                step = (abs(a - prev_a[p]) + c_weight * abs(float(wrap_angle(c - prev_c[p]))))
                if cost[p] + step < new_cost[s_idx]:
                    new_cost[s_idx] = cost[p] + step
                    back[i, s_idx] = p
        if not np.isfinite(new_cost).any():
            raise AxisLimitError(
                f"point {i}: the normal needs A = {np.degrees(cand.a_pos[i]):.3f} or "
                f"{-np.degrees(cand.a_pos[i]):.3f} deg, outside the A limits "
                f"[{np.degrees(lim[0]):.3f}, {np.degrees(lim[1]):.3f}] deg",
                field=field,
                value={"index": i, "normal": n[i], "a_deg": np.degrees(cand.a_pos[i]),
                       "a_limits_deg": np.degrees(np.asarray(lim))})
        cost = new_cost
        prev_a, prev_c = a_state[i].copy(), c_state[i].copy()
        # carried C of a singular state follows its own (single) predecessor
    states = np.zeros(k, dtype=int)
    states[-1] = int(np.argmin(cost))
    for i in range(k - 1, 0, -1):
        states[i - 1] = back[i, states[i]]
    idx = np.arange(k)
    a_out = a_state[idx, states]
    c_wrapped = c_state[idx, states]
    held = cand.rho <= singular_rho
    c_out = np.empty(k)
    previous = float(c_start_rad)
    for i in range(k):
        previous = previous + float(wrap_angle(c_wrapped[i] - previous))
        c_out[i] = previous
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
    branch = np.where(np.asarray(signs)[states] > 0, 1, -1)
    return BranchChoice(a_rad=a_out, c_rad=c_out, branch=branch, held=held)
