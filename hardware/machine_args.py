"""The arguments every machine backend checks before it moves, checked once: move words,
probe heights and feeds, a probe's start and target, tool numbers, a program's commands and
its start line.  Each raises ``InvalidConfig`` naming the field and the value; the probe
failures both backends report are built here too (``probe_missed``)."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from .errors import InvalidConfig, ProbeFailed
from .machine_types import MachineProfile
from .protocol import validate_program

__all__ = ["ProbeDown", "ProbeToward", "axis_words", "check_tool", "probe_down", "probe_missed", "probe_toward",
           "program_commands", "straight_move", "written_at"]

Point = tuple[float, float, float]


def axis_words(x: float | None, y: float | None, z: float | None) -> str:
    """`` X.. Y.. Z..`` (mm, 4 decimals) of the axes given; ``InvalidConfig`` when none is."""
    words = "".join(f" {a}{v:.4f}" for a, v in zip("XYZ", (x, y, z)) if v is not None)
    if not words:
        raise InvalidConfig("move needs at least one of x, y, z", field="move")
    return words


def straight_move(profile: MachineProfile, x: float | None, y: float | None, z: float | None,
                  feed_mm_min: float | None) -> str:
    """``G1 X.. Y.. Z.. F..`` to the axes given (mm) at ``feed_mm_min`` (default: the travel
    feed, mm/min); ``InvalidConfig`` (field ``move``) when no axis is given."""
    words = axis_words(x, y, z)
    return f"G1{words} F{feed_mm_min or profile.travel_feed_mm_min:.1f}"


@dataclass(frozen=True)
class ProbeDown:
    """A probe straight down at (x, y): from ``z_start`` to ``z_min`` (mm) at ``feed``, the
    travel there at ``travel`` (mm/min)."""

    x: float
    y: float
    z_start: float
    z_min: float
    feed: float
    travel: float

    @property
    def retract(self) -> str:
        """Back up to ``z_start`` at the travel feed (absolute)."""
        return f"G1 Z{self.z_start:.4f} F{self.travel:.1f}"

    def approach_moves(self, here: Point) -> list[str]:
        """From a tool commanded at ``here`` (x, y, z mm) to (x, y, ``z_start``): Z first
        (:attr:`retract`), then XY, without the moves that would not move it (see
        :meth:`ProbeToward.approach_moves`)."""
        hx, hy, hz = here
        moves = [] if _written_at(self.z_start, hz) else [self.retract]
        if not (_written_at(self.x, hx) and _written_at(self.y, hy)):
            moves.append(f"G1 X{self.x:.4f} Y{self.y:.4f} F{self.travel:.1f}")
        return moves


def probe_down(profile: MachineProfile, x: float, y: float, z_start: float | None, z_min: float | None,
               feed_mm_min: float | None) -> ProbeDown:
    """``probe``'s arguments with the profile's defaults (clearance, probe depth and feed);
    ``InvalidConfig`` (field ``z_min``) unless ``z_min`` lies below ``z_start``."""
    start = profile.clearance_z if z_start is None else z_start
    low = profile.probe_z_min if z_min is None else z_min
    if low >= start:
        raise InvalidConfig("z_min must be below z_start", field="z_min", value=low)
    return ProbeDown(x, y, start, low, feed_mm_min or profile.probe_feed_mm_min, profile.travel_feed_mm_min)


@dataclass(frozen=True)
class ProbeToward:
    """A probe from ``start`` toward ``target`` (mm) at ``feed``, the travel at ``travel``
    (mm/min); ``where`` is the target as reported (4 decimals)."""

    start: Point
    target: Point
    feed: float
    travel: float

    @property
    def where(self) -> list[float]:
        return [round(v, 4) for v in self.target]

    @property
    def back(self) -> str:
        """Straight back to ``start`` at the travel feed (absolute)."""
        sx, sy, sz = self.start
        return f"G1 X{sx:.4f} Y{sy:.4f} Z{sz:.4f} F{self.travel:.1f}"

    def approach(self, z_now: float) -> list[str]:
        """To ``start`` from a tool at height ``z_now``: Z up first (to the higher of the two),
        then XY, then Z down, each its own move."""
        sx, sy, sz = self.start
        t = self.travel
        return [f"G1 Z{max(z_now, sz):.4f} F{t:.1f}", f"G1 X{sx:.4f} Y{sy:.4f} F{t:.1f}", f"G1 Z{sz:.4f} F{t:.1f}"]

    def approach_moves(self, here: Point) -> list[str]:
        """:meth:`approach` from a tool commanded at ``here`` (x, y, z mm) without the moves
        that would not move it: a move whose target, as written (4 decimals), is where the
        tool already is.  For a controller that answers each command a polling period
        after it took it (linuxcncrsh: 0.1 s), where a move of nothing costs as much."""
        (sx, sy, sz), (hx, hy, hz), t = self.start, here, self.travel
        up = max(hz, sz)
        moves = []
        if not _written_at(up, hz):
            moves.append(f"G1 Z{up:.4f} F{t:.1f}")
            hz = float(f"{up:.4f}")
        if not (_written_at(sx, hx) and _written_at(sy, hy)):
            moves.append(f"G1 X{sx:.4f} Y{sy:.4f} F{t:.1f}")
        if not _written_at(sz, hz):
            moves.append(f"G1 Z{sz:.4f} F{t:.1f}")
        return moves

    @property
    def command(self) -> str:
        tx, ty, tz = self.target
        return f"G38.2 X{tx:.4f} Y{ty:.4f} Z{tz:.4f} F{self.feed:.1f}"


def probe_toward(profile: MachineProfile, start: Point, target: Point, feed_mm_min: float | None) -> ProbeToward:
    """``probe_toward``'s arguments: three finite numbers each (fields ``start``, ``target``),
    a target apart from the start, a feed > 0 (the profile's probe feed by default)."""
    a, b = _point(start, "start"), _point(target, "target")
    if math.dist(a, b) < 1e-6:
        raise InvalidConfig("probe target equals its start", field="target", value=list(b))
    feed = feed_mm_min or profile.probe_feed_mm_min
    if not feed > 0:
        raise InvalidConfig("feed_mm_min must be > 0", field="feed_mm_min", value=feed)
    return ProbeToward(a, b, feed, profile.travel_feed_mm_min)


def probe_missed(probe: ProbeDown | ProbeToward, why: str = "") -> ProbeFailed:
    """The ``ProbeFailed`` of a probe that touched nothing (``why``: the controller's words)."""
    if isinstance(probe, ProbeDown):
        x, y = probe.x, probe.y
        return ProbeFailed(f"probe at ({x:.3f}, {y:.3f}) found no surface above z={probe.z_min:.3f}{why}",
                           x=x, y=y, field="probe", value=[x, y])
    return ProbeFailed(f"probe from {list(probe.start)} toward {probe.where} touched nothing{why}",
                       x=probe.target[0], y=probe.target[1], field="probe", value=probe.where)


def check_tool(tool: int, most: int) -> int:
    """``tool`` when it is an integer 0..``most``; ``InvalidConfig`` (field ``tool``) else."""
    if isinstance(tool, bool) or not isinstance(tool, int) or not 0 <= tool <= most:
        raise InvalidConfig(f"tool must be an integer 0..{most}", field="tool", value=tool)
    return tool


def program_commands(lines: Iterable[str], start_line: int) -> list[str]:
    """A program's commands (comments and blank lines dropped; ``InvalidConfig`` field
    ``program`` for a line that is not G-code); ``InvalidConfig`` (field ``start_line``)
    unless ``start_line`` lies within 0..len(commands)."""
    commands = validate_program(lines)
    total = len(commands)
    if not 0 <= start_line <= total:
        raise InvalidConfig(f"start_line must be within 0..{total}", field="start_line", value=start_line)
    return commands


def written_at(here: Point, x: float | None, y: float | None, z: float | None) -> bool:
    """True when a move to the axes given (mm), as written (4 decimals), would not move a
    tool commanded at ``here`` (x, y, z mm)."""
    return all(_written_at(v, h) for v, h in zip((x, y, z), here) if v is not None)


def _written_at(target: float, position: float) -> bool:
    """True when ``target`` written with 4 decimals (as every move is) is ``position`` (mm)."""
    return abs(float(f"{target:.4f}") - position) < 5e-7


def _point(value: Point, field: str) -> Point:
    try:
        point = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise InvalidConfig(f"{field} must be (x, y, z) in mm", field=field, value=str(value)[:60]) from None
    if len(point) != 3 or not all(math.isfinite(v) for v in point):
        raise InvalidConfig(f"{field} must be three finite numbers (mm)", field=field,
                            value=str(value)[:60])
    return (point[0], point[1], point[2])
