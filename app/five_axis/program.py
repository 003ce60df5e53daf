"""G-code text for five-axis and nominal three-axis traverses.

Feed modes of the five-axis program (documented in its header comment):

* ``"inverse_time"`` (default): ``G93``; each ``G1 X Y Z A C F`` line's F is 1 / (segment
  duration in minutes), the duration being the time the contact point needs at the set
  feed along the trace.  Any controller then reproduces the intended constant feed along
  the workpiece, independent of how far the linear and rotary axes move.
* ``"tcp"``: ``G94``; F (mm/min) is the nozzle tip's straight-line machine-coordinate
  distance of the segment divided by its duration: what a controller that feeds only the
  X Y Z path length (rotaries slaved) needs for the same timing.  Segments with no linear
  motion fall back to the nominal feed.

Dispensing: with ``ProgramStyle.dispense_on`` / ``dispense_off`` set, the on command is
written right after the approach move to the first pose and the off command right after
the last print move, so every ``G1`` between them dispenses (both programs).

Angles are written in degrees, lengths in mm (the user-facing boundary).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from app.gcode.writer import DEFAULT_PROBING_DIALECT, ProgramBuilder, format_number
from app.geometry.tolerance import LENGTH_EPS_MM

__all__ = ["FeedMode", "ProgramStyle", "approach", "dispense", "end_program", "five_axis_program",
           "nominal_program"]

FeedMode = Literal["inverse_time", "tcp"]


@dataclass(frozen=True)
class ProgramStyle:
    """Formatting and approach of a program.

    dialect: G-code dialect of :mod:`app.gcode.writer`; job_id: header id; decimals:
    digits for mm and degrees; safe_z_mm: machine Z for the approach rapids (None: no
    rapids, the first line moves straight to the start pose at approach_feed_mm_min).
    dispense_on / dispense_off: one G-code line each (e.g. ``"M8"`` / ``"M9"``, LinuxCNC
    ``"M64 P0"`` / ``"M65 P0"``) written after the approach move / after the last print
    move; None: not written.  program_end: the machine's program end (e.g. ``"M2"``);
    None: the dialect's (grbl and linuxcnc ``M2``, Marlin none).
    """

    dialect: str = DEFAULT_PROBING_DIALECT
    job_id: str | None = None
    decimals: int = 4
    safe_z_mm: float | None = None
    approach_feed_mm_min: float = 300.0
    dispense_on: str | None = None
    dispense_off: str | None = None
    program_end: str | None = None


def end_program(b: ProgramBuilder, style: ProgramStyle) -> None:
    """The profile's program end, else the dialect's."""
    if style.program_end is not None:
        b.raw(style.program_end.strip())
    else:
        b.end()


def dispense(b: ProgramBuilder, command: str | None) -> None:
    """Write one dispense command line (nothing for None)."""
    if command is not None:
        b.raw(command.strip())


def approach(b: ProgramBuilder, style: ProgramStyle, xyz: npt.NDArray[np.float64],
              rotary: dict[str, float]) -> None:
    if style.safe_z_mm is not None:
        b.rapid(z=style.safe_z_mm)
        words = [f"X{format_number(xyz[0], style.decimals, 'x')}",
                 f"Y{format_number(xyz[1], style.decimals, 'y')}"]
        words += [f"{k.upper()}{format_number(v, style.decimals, k)}" for k, v in rotary.items()]
        b.raw("G0 " + " ".join(words))
    b.move(x=xyz[0], y=xyz[1], z=xyz[2], feed_mm_min=style.approach_feed_mm_min, **rotary)


def dispensed_path(b: ProgramBuilder, xyz_mm: npt.NDArray[np.float64], a_deg: npt.NDArray[np.float64],
                   c_deg: npt.NDArray[np.float64],
                   durations_s: npt.NDArray[np.float64], feed_mode: FeedMode, nominal_feed_mm_min: float,
                   style: ProgramStyle) -> None:
    """Approach pose 0, dispense on, one ``G1 X Y Z A C F`` per later pose (inverse-time or
    tip feed), dispense off, back to G94.  xyz_mm (k,3) mm in the program's frame; a_deg,
    c_deg (k,) degrees; durations_s (k-1,) segment times (s)."""
    b.raw("G94")
    approach(b, style, xyz_mm[0], {"a": float(a_deg[0]), "c": float(c_deg[0])})
    dispense(b, style.dispense_on)
    b.raw("G93" if feed_mode == "inverse_time" else "G94")
    seg_len = np.linalg.norm(np.diff(xyz_mm, axis=0), axis=1)
    for j in range(1, xyz_mm.shape[0]):
        dt = float(durations_s[j - 1])
        if feed_mode == "inverse_time":
            feed = 60.0 / dt
        else:
            feed = seg_len[j - 1] / dt * 60.0 if seg_len[j - 1] > LENGTH_EPS_MM else nominal_feed_mm_min
        b.move(x=xyz_mm[j, 0], y=xyz_mm[j, 1], z=xyz_mm[j, 2], feed_mm_min=feed,
               a=float(a_deg[j]), c=float(c_deg[j]))
    dispense(b, style.dispense_off)
    b.raw("G94")


def five_axis_program(xyz_mm: npt.NDArray[np.float64], a_deg: npt.NDArray[np.float64], c_deg: npt.NDArray[np.float64],
                      durations_s: npt.NDArray[np.float64], feed_mode: FeedMode, nominal_feed_mm_min: float,
                      style: ProgramStyle, header: list[str]) -> str:
    """Program text: approach to pose 0, dispense on, one ``G1 X Y Z A C F`` per later
    pose, dispense off.

    xyz_mm (k,3) machine tip positions; a_deg, c_deg (k,); durations_s (k-1,) segment
    times; header: comment lines written after the standard header.
    """
    b = ProgramBuilder(style.dialect, "five_axis", style.job_id, decimals=style.decimals,
                       feed_decimals=3)
    for line in header:
        b.comment(line)
    dispensed_path(b, xyz_mm, a_deg, c_deg, durations_s, feed_mode, nominal_feed_mm_min, style)
    end_program(b, style)
    return b.text()


def nominal_program(xyz_mm: npt.NDArray[np.float64], feed_mm_min: float, style: ProgramStyle,
                    header: list[str]) -> str:
    """Three-axis comparison program: approach, dispense on, ``G1 X Y Z F`` through the
    tip positions (k,3) mm, dispense off."""
    b = ProgramBuilder(style.dialect, "five_axis_nominal", style.job_id,
                       decimals=style.decimals, feed_decimals=1)
    for line in header:
        b.comment(line)
    b.raw("G94")
    approach(b, style, xyz_mm[0], {})
    dispense(b, style.dispense_on)
    for j in range(1, xyz_mm.shape[0]):
        b.move(x=xyz_mm[j, 0], y=xyz_mm[j, 1], z=xyz_mm[j, 2], feed_mm_min=feed_mm_min)
    dispense(b, style.dispense_off)
    end_program(b, style)
    return b.text()
