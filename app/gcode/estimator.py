"""Print-time estimator: a Marlin-style planner (trapezoids + junction deviation).

Usable on any G-code text (:func:`estimate_gcode`) or on move arrays
(:func:`estimate_moves`).  Model ("marlin-jd, full lookahead"):

* each move is a block of length L (XYZ distance; |dE| for extruder-only moves) with
  nominal speed F (mm/s) capped so that no axis exceeds its max feed (M203);
* acceleration: printing moves (E > 0 with XYZ motion) ``accel_mm_s2`` (M204 P/S),
  travel ``travel_accel_mm_s2`` (M204 T), extruder-only ``retract_accel_mm_s2`` (M204 R),
  each capped by the per-axis max accelerations (M201) projected on the move;
* junction speed between blocks (Marlin ``JUNCTION_DEVIATION``):
  cos(theta) = -u_prev . u_cur, sin(theta/2) = sqrt((1 - cos theta) / 2),
  v_j^2 = a * jd * sin(theta/2) / (1 - sin(theta/2)), capped by both nominal speeds;
  a full reversal gives 0, a straight continuation the smaller nominal speed; junctions
  touching extruder-only moves, dwells and the program ends are full stops;
* lookahead over the whole program: backward then forward passes of
  v_(i)^2 <= v_(i+1)^2 + 2 a L (solved in closed form with cumulative minima);
* time of a block with entry vi, exit vf, nominal vn: trapezoid
  (vn - vi)/a + (vn - vf)/a + (L - d_acc - d_dec)/vn, or a triangle with peak
  sqrt((2 a L + vi^2 + vf^2) / 2) when L is too short to reach vn.
The program is read by the one G-code reader (:mod:`app.gcode.reader`): G92, G28, units,
relative modes and arcs (timed along their chords) as it defines them.
Not modelled: Marlin's 16-block planner buffer, minimum segment time, S-curves, firmware
retraction (G10/G11), heating waits.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Annotated

import numpy as np
import numpy.typing as npt
from annotated_types import Ge, Gt, Le

from app.domain.errors import InvalidInput
from app.gcode.reader import Program, ReadOptions, read_program
from app.geometry.tolerance import DEGENERATE_LENGTH_MM

#: a junction with sin(theta / 2) >= 1 - this (theta: the angle between the moves' reversed
#: and forward directions) is straight: it puts no junction-deviation limit on the speed
_STRAIGHT_JUNCTION_SLACK = 1e-9


class EstimatorError(InvalidInput):
    """Bad machine limits or unparsable G-code numbers."""


Axes4 = tuple[float, float, float, float]  # one value per axis X, Y, Z, E


@dataclass(frozen=True)
class MachineLimits:
    """Planner limits (mm, s).  ``max_feed_mm_s`` / ``max_accel_mm_s2`` per axis X, Y, Z, E.
    The bounds in the annotations are the ranges a toolpath job may ask for (its parameter
    model reads them, :meth:`app.slicing.toolpath.ToolpathParams.validate` refuses the rest)."""

    accel_mm_s2: Annotated[float, Gt(0), Le(1_000_000)] = 1000.0
    travel_accel_mm_s2: Annotated[float, Gt(0), Le(1_000_000)] = 1500.0
    retract_accel_mm_s2: Annotated[float, Gt(0), Le(1_000_000)] = 1500.0
    junction_deviation_mm: Annotated[float, Ge(0), Le(10)] = 0.013
    max_feed_mm_s: Axes4 = (300.0, 300.0, 10.0, 60.0)
    max_accel_mm_s2: Axes4 = (5000.0, 5000.0, 200.0, 5000.0)

    def validate(self) -> None:
        """Raise :class:`EstimatorError` for non-positive limits."""
        vals = (self.accel_mm_s2, self.travel_accel_mm_s2, self.retract_accel_mm_s2,
                *self.max_feed_mm_s, *self.max_accel_mm_s2)
        if not all(np.isfinite(v) and v > 0 for v in vals) or not (
                self.junction_deviation_mm >= 0):
            raise EstimatorError("machine limits must be positive", field="limits",
                                 value=str(self))

    def describe(self) -> str:
        """One line naming the estimator and these limits (for benchmark tables)."""
        return (f"marlin-jd planner: a={self.accel_mm_s2:g} (travel "
                f"{self.travel_accel_mm_s2:g}) mm/s2, jd={self.junction_deviation_mm:g} mm, "
                f"vmax XY={self.max_feed_mm_s[0]:g} mm/s")


@dataclass(frozen=True)
class TimeEstimate:
    """Estimated times (s).  ``block_times``: (N,) per move; ``layer_times``: per ``;LAYER``
    marker (moves before the first marker count as layer -1 and are excluded)."""

    total_s: float
    print_s: float
    travel_s: float
    dwell_s: float
    moves: int
    block_times: npt.NDArray[np.float64]
    layer_times: tuple[float, ...]


def _trapezoid_times(L: npt.NDArray[np.float64], vi: npt.NDArray[np.float64], vf: npt.NDArray[np.float64],
                     vn: npt.NDArray[np.float64], a: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """(N,) times (s) of blocks of length ``L`` (mm) entered at ``vi``, left at ``vf``, with
    nominal speed ``vn`` (mm/s) and acceleration ``a`` (mm/s^2): trapezoid, or triangle when
    ``vn`` is out of reach."""
    d_acc = (vn ** 2 - vi ** 2) / (2 * a)
    d_dec = (vn ** 2 - vf ** 2) / (2 * a)
    cruise = L - d_acc - d_dec
    with np.errstate(divide="ignore", invalid="ignore"):
        t_trap = (vn - vi) / a + (vn - vf) / a + np.where(vn > 0, cruise / vn, 0.0)
        vp = np.sqrt(np.maximum((2 * a * L + vi ** 2 + vf ** 2) / 2, 0.0))
        vp = np.maximum(vp, np.maximum(vi, vf))
        t_tri = (vp - vi) / a + (vp - vf) / a
    times: npt.NDArray[np.float64] = np.where(cruise >= 0, t_trap, t_tri)
    return times


def estimate_moves(positions: npt.ArrayLike, feed_mm_s: npt.ArrayLike, limits: MachineLimits,
                   stops: npt.ArrayLike | None = None,
                   jumps: npt.ArrayLike | None = None) -> npt.NDArray[np.float64]:
    """Per-move times (s) of the moves between ``positions`` (N+1, 4) [x, y, z, e] mm.

    ``feed_mm_s`` (N,) requested feed; ``stops`` (N+1,) bool forces a full stop at a
    junction (index k = before move k); ``jumps`` (N,) bool marks moves that take no
    time (homing, coordinate resets).  Zero-length moves take 0 s.
    """
    limits.validate()
    pos = np.asarray(positions, dtype=np.float64)
    d = np.diff(pos, axis=0)
    n = len(d)
    if n == 0:
        return np.zeros(0)
    xyz = np.linalg.norm(d[:, :3], axis=1)
    e_only = (xyz <= DEGENERATE_LENGTH_MM) & (np.abs(d[:, 3]) > DEGENERATE_LENGTH_MM)
    L = np.where(e_only, np.abs(d[:, 3]), xyz)
    valid = L > DEGENERATE_LENGTH_MM
    if jumps is not None:
        valid &= ~np.asarray(jumps, dtype=bool)
    Ls = np.where(valid, L, 1.0)
    frac = np.abs(d) / Ls[:, None]
    with np.errstate(divide="ignore"):
        v_cap = np.min(np.where(frac > 0, np.asarray(limits.max_feed_mm_s) / frac, np.inf),
                       axis=1)
        a_cap = np.min(np.where(frac > 0, np.asarray(limits.max_accel_mm_s2) / frac, np.inf),
                       axis=1)
    printing = (d[:, 3] > DEGENERATE_LENGTH_MM) & ~e_only
    a = np.where(e_only, limits.retract_accel_mm_s2,
                 np.where(printing, limits.accel_mm_s2, limits.travel_accel_mm_s2))
    a = np.minimum(a, a_cap)
    vn = np.minimum(np.asarray(feed_mm_s, dtype=np.float64), v_cap)
    if np.any(vn[valid] <= 0):
        raise EstimatorError("a move has a non-positive feed", field="feed_mm_s", value=0)
    u = np.where(valid[:, None] & ~e_only[:, None], d[:, :3] / Ls[:, None], 0.0)
    # junction k sits before move k (k = 1..n-1)
    cos_t = -np.einsum("ij,ij->i", u[:-1], u[1:])
    sin_h = np.sqrt(np.clip(0.5 * (1 - cos_t), 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        vj2 = np.where(sin_h < 1 - _STRAIGHT_JUNCTION_SLACK,
                       a[1:] * limits.junction_deviation_mm * sin_h / (1 - sin_h), np.inf)
    vj2 = np.where(cos_t > 0.999999, 0.0, vj2)
    vmax = np.concatenate([[0.0], np.minimum(np.minimum(vn[:-1], vn[1:]) ** 2, vj2), [0.0]])
    # zero-length / extruder-only moves are full stops on both sides
    bad = ~valid | e_only
    vmax[:-1][bad] = 0.0
    vmax[1:][bad] = 0.0
    if stops is not None:
        vmax = np.where(np.asarray(stops, dtype=bool), 0.0, vmax)
    dd = np.where(valid, 2 * a * L, 0.0)                 # v_k^2 <= v_(k+1)^2 + dd_k
    P = np.concatenate([[0.0], np.cumsum(dd)])           # P[k] = sum_{j<k} dd_j
    w = np.minimum.accumulate((vmax + P)[::-1])[::-1] - P          # backward pass
    w = np.minimum.accumulate(w - P) + P                           # forward pass
    v = np.sqrt(np.maximum(w, 0.0))
    vi, vf = np.minimum(v[:-1], vn), np.minimum(v[1:], vn)
    t = _trapezoid_times(L, vi, vf, vn, a)
    times: npt.NDArray[np.float64] = np.where(valid, t, 0.0)
    return times


def _per_axis(current: Axes4, words: dict[str, float]) -> Axes4:
    """``current`` with the axes an M201/M203 command names (X Y Z E words) replaced."""
    x, y, z, e = (words.get(axis, value) for axis, value in zip("XYZE", current))
    return (x, y, z, e)


def _apply_limit_commands(limits: MachineLimits,
                          commands: tuple[tuple[str, dict[str, float]], ...]) -> MachineLimits:
    """``limits`` after the program's M201/M203/M204/M205 commands, in order."""
    for code, w in commands:
        if code == "M204":
            p = w.get("P", w.get("S"))
            limits = replace(limits, accel_mm_s2=p if p else limits.accel_mm_s2,
                             travel_accel_mm_s2=w.get("T", w.get("S", limits.travel_accel_mm_s2)),
                             retract_accel_mm_s2=w.get("R", limits.retract_accel_mm_s2))
        elif code == "M205" and "J" in w:
            limits = replace(limits, junction_deviation_mm=w["J"])
        elif code == "M203":
            limits = replace(limits, max_feed_mm_s=_per_axis(limits.max_feed_mm_s, w))
        elif code == "M201":
            limits = replace(limits, max_accel_mm_s2=_per_axis(limits.max_accel_mm_s2, w))
    return limits


def estimate_gcode(text: str, limits: MachineLimits = MachineLimits(),
                   max_arc_chords: int | None = None) -> TimeEstimate:
    """Estimate the run time of G-code ``text`` as :func:`app.gcode.reader.read_program`
    reads it (arcs timed along their chords at the reader's tolerance, at most
    ``max_arc_chords`` of them: by default the budget of the text's size).  The last
    M201/M203/M204/M205 seen applies to the whole file (limits are normally set once in
    the start section)."""
    return estimate_program(read_program(text, ReadOptions(feed_mm_s=25.0, max_arc_chords=max_arc_chords)), limits)


def command_times(commands: list[str], limits: MachineLimits = MachineLimits()) -> npt.NDArray[np.float64]:
    """(len(commands),) estimated seconds each command keeps the machine busy (its moves'
    planned times; dwells and heating waits count 0): what the machines page's time left is
    weighted by.  ``commands``: one G-code command per entry, as the machine streams them."""
    program = read_program("\n".join(commands), ReadOptions(feed_mm_s=25.0))
    times = estimate_program(program, limits).block_times
    per_command = np.zeros(len(commands))
    if len(times):
        np.add.at(per_command, np.clip(program.line - 1, 0, max(len(commands) - 1, 0)), times)
    return per_command


def estimate_program(program: Program, limits: MachineLimits = MachineLimits()) -> TimeEstimate:
    """:func:`estimate_gcode` of a program already read (with the default :class:`ReadOptions`)."""
    limits = _apply_limit_commands(limits, program.limits)
    dwell = program.dwell_s
    if program.count == 0:
        return TimeEstimate(dwell, 0.0, 0.0, dwell, 0, np.zeros(0), ())
    rows = np.vstack([program.start[:1], program.end])
    stops = np.concatenate([program.stop_before, [True]])
    t = estimate_moves(rows, program.feed_mm_s, limits, stops, program.home)
    layers = program.layer
    d = np.diff(rows, axis=0)
    printing = d[:, 3] > DEGENERATE_LENGTH_MM
    lay = np.asarray(layers)
    layer_times: tuple[float, ...] = ()
    if len(lay) and lay.max() >= 0:
        sums = np.bincount(lay[lay >= 0], weights=t[lay >= 0])
        layer_times = tuple(float(s) for s in sums)
    return TimeEstimate(total_s=float(t.sum() + dwell), print_s=float(t[printing].sum()),
                        travel_s=float(t[~printing].sum()), dwell_s=float(dwell),
                        moves=len(t), block_times=t, layer_times=layer_times)
