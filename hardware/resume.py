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
    if None not in (x, y, z) and not state.g92:
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
