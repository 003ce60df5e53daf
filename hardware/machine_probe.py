"""Probing of ``hardware.machine.Machine`` (a mixin): travel to a station, touch down with
the firmware's probe command (Marlin ``G30`` / ``G38.2``, grbl ``G38.2``), read the contact
point, retract; failures leave the machine idle, unlocked and retracted.  Also probing
toward any point (``probe_toward``, always ``G38.2``) and tool selection (``T<n>``)."""

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING

from .errors import FirmwareError, InvalidConfig, ProbeFailed
from .events import ProbeReport
from .machine_types import ProbeResult

if TYPE_CHECKING:
    from .machine_host import SerialHost

_LOGICAL = re.compile(r"Logical:\s*X:\s*([-+]?[\d.]+)\s+Y:\s*([-+]?[\d.]+)\s+Z:\s*([-+]?[\d.]+)")
MAX_TOOL = 255


class ProbeOperations:
    """Part of ``Machine`` (what it uses of it: ``hardware.machine_host.SerialHost``); every
    method expects a connected machine."""

    def probe(self: SerialHost, x: float, y: float, z_start: float | None = None, z_min: float | None = None,
              feed_mm_min: float | None = None) -> ProbeResult:
        """Travel to (x, y) at ``z_start`` (default clearance), probe down to ``z_min``,
        retract; ``ProbeFailed`` when nothing is hit (the machine is left idle, unlocked
        and retracted)."""
        p = self.profile
        z_start = p.clearance_z if z_start is None else z_start
        z_min = p.probe_z_min if z_min is None else z_min
        feed = feed_mm_min or p.probe_feed_mm_min
        if z_min >= z_start:
            raise InvalidConfig("z_min must be below z_start", field="z_min", value=z_min)
        kind = p.probe_command or self.rules.probe_command
        travel = p.travel_feed_mm_min
        self._claim_motion("busy", "probe")
        try:
            self._run(["G90", f"G1 Z{z_start:.4f} F{travel:.1f}",
                       f"G1 X{x:.4f} Y{y:.4f} F{travel:.1f}"])
            command = f"G30 X{x:.4f} Y{y:.4f}" if kind == "G30" else f"G38.2 Z{z_min:.4f} F{feed:.1f}"
            try:
                result = self.live_link.send(command, self.timeout_s * 10)
            except FirmwareError as exc:
                self._recover_after_probe(z_start)
                if any(line.strip() == "ALARM:4" for line in exc.reply_lines):
                    raise ProbeFailed(f"probe at ({x:.3f}, {y:.3f}) was already triggered "
                                      "before it moved (grbl ALARM:4): check the probe",
                                      x=x, y=y, field="probe", value=[x, y],
                                      reason="triggered_before_motion") from exc
                raise ProbeFailed(f"probe at ({x:.3f}, {y:.3f}) found no surface above "
                                  f"z={z_min:.3f}: {exc.message}", x=x, y=y, field="probe",
                                  value=[x, y]) from exc
            if kind == "G30" or self.rules.probe_reports_contact:
                report = result.payload  # "Bed X: .. Y: .. Z: .." / "[PRB:x,y,z:1]"
            else:  # Marlin G38.2 prints nothing: it stopped at the contact point (M114 D: 3 decimals)
                report = self._precise_position()
            if not isinstance(report, ProbeReport) or not report.triggered or report.z < z_min:
                self._recover_after_probe(z_start)
                raise ProbeFailed(f"probe at ({x:.3f}, {y:.3f}) found no surface above "
                                  f"z={z_min:.3f}", x=x, y=y, field="probe", value=[x, y])
            self._run([f"G1 Z{z_start:.4f} F{travel:.1f}", self._wait_motion()])
            return ProbeResult(report.x, report.y, report.z)
        finally:
            self._release()

    def select_tool(self: SerialHost, tool: int) -> None:
        """``T<tool>`` (0 = the touch probe, 1.. = nozzles); waits for its ``ok``.  The
        firmware applies no offsets: programs are written in carriage coordinates.
        ``InvalidConfig`` (field ``tool``) for a number out of range or one the firmware
        refuses (Marlin ``Invalid extruder``)."""
        if isinstance(tool, bool) or not isinstance(tool, int) or not 0 <= tool <= MAX_TOOL:
            raise InvalidConfig(f"tool must be an integer 0..{MAX_TOOL}", field="tool", value=tool)
        self._claim("busy")
        try:
            result = self.live_link.send(f"T{tool}", self.timeout_s * 10)
        finally:
            self._release()
        if any("invalid extruder" in line.lower() for line in result.reply_lines):
            raise InvalidConfig(f"the firmware has no tool T{tool}", field="tool", value=tool)

    def probe_toward(self: SerialHost, start: tuple[float, float, float], target: tuple[float, float, float],
                     feed_mm_min: float | None = None) -> ProbeResult:
        """Probe from ``start`` toward ``target`` (mm, carriage coordinates, any direction)
        with ``G38.2``; return the carriage position at the trigger.

        Travel to ``start`` at the travel feed: Z up first (to the higher of the current
        and the start height), then XY, then Z down, each its own move (the caller gives a
        start that is safe to reach that way).  Afterwards (hit or miss) the machine goes
        straight back to ``start``.  ``ProbeFailed`` when nothing is touched before the
        target (``reason`` ``triggered_before_motion`` when the probe was already
        triggered); ``InvalidConfig`` (field ``target``) when target equals start."""
        start = _point(start, "start")
        target = _point(target, "target")
        if math.dist(start, target) < 1e-6:
            raise InvalidConfig("probe target equals its start", field="target", value=list(target))
        p = self.profile
        feed = feed_mm_min or p.probe_feed_mm_min
        if not feed > 0:
            raise InvalidConfig("feed_mm_min must be > 0", field="feed_mm_min", value=feed)
        travel = p.travel_feed_mm_min
        sx, sy, sz = start
        back = f"G1 X{sx:.4f} Y{sy:.4f} Z{sz:.4f} F{travel:.1f}"
        self._claim_motion("busy", "probe")
        try:
            here = self._position()
            self._run(["G90", f"G1 Z{max(here[2], sz):.4f} F{travel:.1f}",
                       f"G1 X{sx:.4f} Y{sy:.4f} F{travel:.1f}", f"G1 Z{sz:.4f} F{travel:.1f}"])
            tx, ty, tz = target
            command = f"G38.2 X{tx:.4f} Y{ty:.4f} Z{tz:.4f} F{feed:.1f}"
            where = [round(v, 4) for v in target]
            try:
                result = self.live_link.send(command, self.timeout_s * 10)
            except FirmwareError as exc:
                self._recover_toward(back)
                if any(line.strip() == "ALARM:4" for line in exc.reply_lines):
                    raise ProbeFailed(f"probe toward {where} was already triggered before it "
                                      "moved (grbl ALARM:4): check the probe", x=tx, y=ty,
                                      field="probe", value=where,
                                      reason="triggered_before_motion") from exc
                raise ProbeFailed(f"probe from {list(start)} toward {where} touched nothing: "
                                  f"{exc.message}", x=tx, y=ty, field="probe", value=where) from exc
            report = result.payload if self.rules.probe_reports_contact else self._precise_position()
            if not isinstance(report, ProbeReport) or not report.triggered:
                self._recover_toward(back)
                raise ProbeFailed(f"probe from {list(start)} toward {where} touched nothing",
                                  x=tx, y=ty, field="probe", value=where)
            self._run([back, self._wait_motion()])
            return ProbeResult(report.x, report.y, report.z)
        finally:
            self._release()

    def _precise_position(self: SerialHost) -> ProbeReport:
        """Marlin: where G38.2 stopped, from ``M114 D`` (3 decimals; plain M114 has 2)."""
        result = self.live_link.send("M114 D", self.timeout_s)
        for line in result.reply_lines:
            match = _LOGICAL.search(line)
            if match:
                x, y, z = (float(v) for v in match.groups())
                return ProbeReport(x, y, z)
        return ProbeReport(*self._position())

    def _recover_toward(self: SerialHost, back: str) -> None:
        if self.rules.unlock_command is not None:
            self.live_link.send(self.rules.unlock_command, self.timeout_s)
        self._run([back, self._wait_motion()])

    def _recover_after_probe(self: SerialHost, z_start: float) -> None:
        if self.rules.unlock_command is not None:
            self.live_link.send(self.rules.unlock_command, self.timeout_s)
        self._run([f"G1 Z{z_start:.4f} F{self.profile.travel_feed_mm_min:.1f}",
                   self._wait_motion()])



def _point(value: tuple[float, float, float], field: str) -> tuple[float, float, float]:
    try:
        point = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise InvalidConfig(f"{field} must be (x, y, z) in mm", field=field, value=str(value)[:60]) from None
    if len(point) != 3 or not all(math.isfinite(v) for v in point):
        raise InvalidConfig(f"{field} must be three finite numbers (mm)", field=field,
                            value=str(value)[:60])
    return (point[0], point[1], point[2])
