"""Pure helpers for resuming an interrupted program: which commands surely moved, and the
modal state to restore before continuing.  No I/O; used by ``hardware.machine``.

* An ``ok`` means *planned*, not moved (grbl and Marlin alike): up to the planner's
  block count of acknowledged moves may never have run when a controller resets.
  ``executed_bound(blocks, acked, pending)`` walks back over ``pending`` planner blocks
  from the ``acked`` commands and returns the first command index not known to be
  executed.  ``planner_blocks(commands)`` counts, per command, the blocks it certainly
  created (a straight move longer than ``MIN_BLOCK_MM``; arcs count as one, an
  undercount, which only makes the bound more conservative).
* ``modal_preamble(commands, start, ...)`` restores what the commands before ``start`` set:
  units (G20/G21), work coordinate system (G54..G59), motion mode (G0/G1), feed rate, the
  tool's start point (at a clearance height, dispenser off), distance mode (G90/G91) and
  last the dispenser (its on/off commands from the machine profile).
  ``G92`` offsets are not replayed (they depend on where the tool was).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

MIN_BLOCK_MM = 0.05  # a shorter move may be dropped by the planner (fewer than one step)
_WORD = re.compile(r"([A-Z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")


@dataclass
class ModalState:
    """What a G-code interpreter remembers between lines (program units, mm for state)."""

    inches: bool = False
    absolute: bool = True
    wcs: str | None = None  # None: the program never chose one
    motion: str | None = None
    feed: float | None = None
    position: list[float | None] = field(default_factory=lambda: [None, None, None])
    dispensing: bool | None = None
    g92: bool = False

    def update(self, command: str, dispense_on: str = "", dispense_off: str = "") -> bool:
        """Apply one command; True when it creates a planner block for sure."""
        text = command.upper()
        if dispense_on and (text == dispense_on.upper()
                            or text.split(" ")[0] == dispense_on.upper().split(" ")[0]):
            self.dispensing = True
            return False
        if dispense_off and (text == dispense_off.upper()
                             or text.split(" ")[0] == dispense_off.upper().split(" ")[0]):
            self.dispensing = False
            return False
        words = _WORD.findall(text.replace(" ", ""))
        axes: dict[str, float] = {}
        motion_here = None
        for letter, number in words:
            value = float(number)
            if letter == "G":
                code = f"G{number.rstrip('0').rstrip('.') if '.' in number else int(value)}"
                if code in ("G20", "G21"):
                    self.inches = code == "G20"
                elif code in ("G90", "G91"):
                    self.absolute = code == "G90"
                elif code in ("G54", "G55", "G56", "G57", "G58", "G59"):
                    self.wcs = code
                elif code in ("G0", "G1", "G2", "G3"):
                    self.motion = motion_here = code
                elif code == "G92":
                    self.g92 = True
                    return False
                elif code in ("G4", "G28", "G30", "G38.2", "G38.3", "G10", "G53"):
                    self.position = [None, None, None] if code != "G4" else self.position
                    return False
            elif letter == "F":
                self.feed = value
            elif letter in "XYZ":
                axes[letter] = value
        if not axes or (self.motion is None and motion_here is None):
            return False
        squares, known = 0.0, True
        for i, axis in enumerate("XYZ"):
            if axis not in axes:
                continue  # an axis the line does not name does not move
            base = self.position[i]
            end = axes[axis] if self.absolute else (None if base is None else base + axes[axis])
            self.position[i] = end
            if base is None or end is None:
                known = False  # length unknown: not counted (conservative)
            else:
                squares += (end - base) ** 2
        scale = 25.4 if self.inches else 1.0
        return known and math.sqrt(squares) * scale >= MIN_BLOCK_MM


def planner_blocks(commands: list[str], dispense_on: str = "", dispense_off: str = "") -> list[int]:
    """Per command, 1 when it certainly created a planner block, else 0."""
    state = ModalState()
    return [int(state.update(c, dispense_on, dispense_off)) for c in commands]


def executed_bound(blocks: list[int], acked: int, pending: int) -> int:
    """First index not known to be executed when commands ``[0, acked)`` were acknowledged
    and at most ``pending`` of their planner blocks had not run."""
    index = acked
    remaining = pending
    while index > 0 and remaining > 0:
        index -= 1
        remaining -= blocks[index]
    return index


def modal_preamble(commands: list[str], start: int, *, dispense_on: str, dispense_off: str,
                   clearance_z: float) -> list[str]:
    """Commands that put the controller in the state the program had before ``start``."""
    state = ModalState()
    for command in commands[:start]:
        state.update(command, dispense_on, dispense_off)
    out = [dispense_off, "G20" if state.inches else "G21"] + ([state.wcs] if state.wcs else [])
    out.append("G90")
    x, y, z = state.position
    if x is not None and y is not None and z is not None and not state.g92:
        unit = 1.0 / 25.4 if state.inches else 1.0
        out += [f"G0 Z{max(z, clearance_z * unit):.4f}", f"G0 X{x:.4f} Y{y:.4f}",
                f"G0 Z{z:.4f}"]
    if state.motion is not None or state.feed is not None:
        mode = state.motion if state.motion in ("G0", "G1") else "G1"
        out.append(mode + (f" F{state.feed:g}" if state.feed else ""))
    if not state.absolute:
        out.append("G91")
    if state.dispensing:
        out.append(dispense_on)
    return out


POSITION_TOLERANCE_MM = 0.01  # a reported position this close to the programmed path is on it


@dataclass(frozen=True)
class ResumeLocation:
    """Where a resumed program starts and why, and what may run twice.

    start: first command to send; basis: "line numbers" (Marlin kept running and counting:
    exact), "position" (the controller kept its position and it lies on exactly one place
    of the path: at most the move it was cut in runs again), "reported position" (the
    controller reset; the last real position it reported while streaming lies on one place
    of the path: what may run twice is bounded by ``repeat_bound_mm`` / ``repeat_bound_lines``)
    or "planner bound" (nothing better is known: everything the controller could hold
    acknowledged but unmoved, planner blocks and stepper segments, runs again); detail: the
    evidence, for the operator.  ``repeats``: commands from ``start`` on that may already
    have run (they run again), ``repeat_moves`` the moves among them; nothing is skipped:
    every command before ``start`` is known to have completed."""

    start: int
    basis: str
    detail: str
    repeat_bound_mm: float | None = None  # "reported position": what may run twice, mm ...
    repeat_bound_lines: int | None = None  # ... and commands (whole or in part)
    repeats: int = 0
    repeat_moves: int = 0

    def summary(self) -> str:
        """One sentence for the operator before confirming."""
        if self.repeats == 0:
            again = "no command runs twice"
        else:
            again = (f"commands {self.start + 1}..{self.start + self.repeats} may run a second time "
                     f"({self.repeat_moves} move{'s' if self.repeat_moves != 1 else ''})")
        return (f"resumes at command {self.start + 1} (by {self.basis}); {again}; none is skipped: "
                f"every command before it is known to have completed")

    def as_dict(self) -> dict:
        out: dict = {"start": self.start, "basis": self.basis, "detail": self.detail,
                     "repeats": self.repeats, "repeat_moves": self.repeat_moves, "skipped": 0,
                     "summary": self.summary()}
        if self.basis == "reported position":
            out |= {"repeat_bound_mm": self.repeat_bound_mm, "repeat_bound_lines": self.repeat_bound_lines}
        return out


def count_moves(commands: list[str]) -> int:
    """Commands among ``commands`` that move the tool (motion words with an axis)."""
    state = ModalState()
    moves = 0
    for command in commands:
        text = command.upper()
        before = state.motion
        state.update(command)
        motion = state.motion or before
        has_axis = any(letter in "XYZ" for letter, _ in _WORD.findall(text.replace(" ", "")))
        moves += int(has_axis and motion is not None and not any(g in text for g in ("G4", "G92", "G10")))
    return moves


def end_positions(commands: list[str], dispense_on: str = "", dispense_off: str = "",
                  start: tuple[float, float, float] | None = None) -> list[tuple[float, float, float] | None]:
    """Per command, the tool's programmed position after it (x, y, z) in mm (the program's
    frame), or None where it is not known (before every axis was set absolutely, after G28,
    G30, G38.x, G53 or G10, and from a G92 frame shift on).  ``start``: where the tool stood
    before the first command (mm), when known (then the opening is known too)."""
    state = ModalState()
    if start is not None:
        state.position = [float(v) for v in start]
    out: list[tuple[float, float, float] | None] = []
    for command in commands:
        before_inches = state.inches
        state.update(command, dispense_on, dispense_off)
        if state.inches != before_inches and any(v is not None for v in state.position):
            state.position = [None, None, None]  # earlier coordinates were in the other unit
        x, y, z = state.position
        if state.g92 or x is None or y is None or z is None:
            out.append(None)
            continue
        scale = 25.4 if state.inches else 1.0
        out.append((x * scale, y * scale, z * scale))
    return out


def _distance_to_segment(p: tuple[float, ...], a: tuple[float, ...], b: tuple[float, ...]) -> float:
    ab = [bi - ai for ai, bi in zip(a, b)]
    length2 = sum(c * c for c in ab)
    t = 0.0 if length2 == 0 else max(0.0, min(1.0, sum((pi - ai) * c for pi, ai, c in zip(p, a, ab)) / length2))
    return math.dist(p, [ai + t * c for ai, c in zip(a, ab)])


def locate_by_position(ends: list[tuple[float, float, float] | None], position: tuple[float, float, float],
                       lo: int, hi: int, tolerance_mm: float = POSITION_TOLERANCE_MM,
                       acked: int = 0, origin: tuple[float, float, float] | None = None) -> int | None:
    """First command not completed when the tool stands still at ``position`` (mm), knowing
    that commands [0, lo) completed and commands [hi, ...) never reached the controller;
    ``ends`` from :func:`end_positions`.  None when that is not one answer.

    The tool at the end of move k (the position after command k) means k completed when k
    moved it there (a command that moves nothing may not have run: k itself is an answer
    too; ``origin``: where the tool stood before command 0, when known): the answer is k + 1, or later over the commands
    after k that do not move (a dispenser switch, a dwell) and were acknowledged (``acked``: commands [0, acked) were;
    such a command ran when it was answered); the others are sent again rather than skipped.  The tool strictly inside
    move k's straight segment means k was cut: the answer is k (the resume's modal replay goes back to k's start point;
    the move runs again whole).  Arcs (G2/G3) and moves from an unknown start are only
    recognised at their ends; the program's opening before its first fully known position
    (units, modes, a first move naming only some axes) cannot be placed and is passed over.
    Places of the window [lo - 1, hi) that the path visits more than once, an unknown
    position after a known one (G28, G92 ...), or no place at all give None."""
    lo, hi = max(lo, 0), min(hi, len(ends))
    if lo > hi:
        return None
    answers: set[int] = set()
    previous = ends[lo - 1] if lo > 0 else origin
    if previous is not None and math.dist(previous, position) <= tolerance_mm:
        answers.add(lo)  # nothing of the window moved yet
    known = any(e is not None for e in ends[:lo])
    for k in range(lo, hi):
        end = ends[k]
        if end is None:
            if known:
                return None  # the path is not known here: the tool could be anywhere on it
            continue  # the program's opening, before its first known position: not placeable
        known = True
        if math.dist(end, position) <= tolerance_mm:
            answers.add(k + 1)
            if previous is not None and math.dist(previous, end) <= tolerance_mm:
                answers.add(k)  # k moves nothing: the tool there does not prove that it ran
        elif previous is not None and _distance_to_segment(position, previous, end) <= tolerance_mm:
            answers.add(k)
        previous = end
    if not answers:
        return None
    first, last = min(answers), max(answers)
    moved = any(ends[k] != ends[k - 1] for k in range(max(first, 1), last))
    if moved:
        return None  # two places of the path
    return max(first, min(acked, last))  # one place: a run of commands that do not move


def command_feeds(commands: list[str], dispense_on: str = "", dispense_off: str = "") -> list[float | None]:
    """Per command, the programmed feed of its motion in mm/min: G1/G2/G3 the modal ``F``;
    None for a rapid (G0: the controller's own rate) or before any ``F``."""
    state = ModalState()
    out: list[float | None] = []
    for command in commands:
        state.update(command, dispense_on, dispense_off)
        scale = 25.4 if state.inches else 1.0
        out.append(state.feed * scale if state.motion in ("G1", "G2", "G3") and state.feed else None)
    return out


@dataclass(frozen=True)
class ReportedResume:
    """Where a resume located by a reported position starts, and what may run twice: the
    part of command ``start`` before the reported point plus the motion after the report
    (``bound_mm``; None: not bounded by time, the path up to the last command sent), over
    ``bound_lines`` commands (``start`` and those after it that the tool may have reached)."""

    start: int
    bound_mm: float | None
    bound_lines: int
    before_mm: float
    after_mm: float | None


def locate_by_report(ends: list[tuple[float, float, float] | None], feeds: list[float | None],
                     position: tuple[float, float, float], lo: int, hi: int, seconds: float,
                     acked: int = 0, tolerance_mm: float = POSITION_TOLERANCE_MM,
                     origin: tuple[float, float, float] | None = None) -> ReportedResume | None:
    """The tool was at ``position`` (a real-position report) when commands [0, lo) had
    surely completed and commands [hi, ...) were not sent; it then moved for at most
    ``seconds`` (until the controller reset) along the program.  Resuming at the command
    the report places it in (:func:`locate_by_position`) skips nothing: the tool was there
    or before.  What runs twice is bounded by the motion at the fastest programmed feed of
    the commands from there to ``hi`` during ``seconds`` (a rapid in between: unbounded by
    time, the path up to ``hi``), walked along the path.  None when the position is not on
    exactly one place of the window."""
    start = locate_by_position(ends, position, lo, hi, tolerance_mm, acked=acked, origin=origin)
    if start is None:
        return None
    hi = min(hi, len(ends))
    origin = ends[start - 1] if start > 0 else None
    before = math.dist(origin, position) if origin is not None else 0.0
    speeds = []
    cursor = tuple(position)
    for k in range(start, hi):
        end = ends[k]
        if end is not None and math.dist(cursor, end) > 0:
            speeds.append(feeds[k])
        cursor = end if end is not None else cursor
    after = None if not speeds or None in speeds else max(s for s in speeds if s) / 60.0 * max(seconds, 0.0)
    remaining = math.inf if after is None else after
    walked, last, cursor = 0.0, start, tuple(position)
    for k in range(start, hi):
        end = ends[k]
        if end is None:
            last, remaining = hi - 1, 0.0
            walked = math.inf
            break
        step = math.dist(cursor, end)
        last = k
        if step >= remaining:
            walked += remaining
            break
        walked += step
        remaining -= step
        cursor = end
    bound_mm = None if math.isinf(walked) else before + walked
    return ReportedResume(start, bound_mm, max(last, start) - start + 1, before, after)
