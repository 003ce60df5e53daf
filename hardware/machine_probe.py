"""Probing on the serial machine: :class:`Prober`, built with the machine's
``SerialCommands``.  It travels to a station, touches down with the firmware's probe command
(Marlin ``G30`` / ``G38.2``, grbl ``G38.2``), reads the contact point and retracts; failures
leave the machine idle, unlocked and retracted.  Also probing toward any point
(``probe_toward``, always ``G38.2``) and tool selection (``T<n>``)."""

from __future__ import annotations

import re

from .errors import FirmwareError, InvalidConfig, ProbeFailed
from .events import ProbeReport
from .machine_args import ProbeDown, ProbeToward, check_tool, probe_down, probe_missed, probe_toward
from .machine_host import SerialCommands
from .machine_types import ProbeResult

__all__ = ["MAX_TOOL", "Prober"]

_LOGICAL = re.compile(r"Logical:\s*X:\s*([-+]?[\d.]+)\s+Y:\s*([-+]?[\d.]+)\s+Z:\s*([-+]?[\d.]+)")
MAX_TOOL = 255


class Prober:
    """Probes and selects tools on a connected serial machine (see the module docstring)."""

    def __init__(self, commands: SerialCommands) -> None:
        self.commands = commands

    def probe(self, x: float, y: float, z_start: float | None = None, z_min: float | None = None,
              feed_mm_min: float | None = None) -> ProbeResult:
        """Travel to (x, y) at ``z_start`` (default clearance), probe down to ``z_min``,
        retract; ``ProbeFailed`` when nothing is hit (the machine is left idle, unlocked
        and retracted)."""
        c = self.commands
        down = probe_down(c.profile, x, y, z_start, z_min, feed_mm_min)
        kind = c.profile.probe_command or c.rules.probe_command
        c.claim_motion("busy", "probe")
        try:
            c.run(["G90", down.retract, f"G1 X{x:.4f} Y{y:.4f} F{down.travel:.1f}"])
            command = f"G30 X{x:.4f} Y{y:.4f}" if kind == "G30" else f"G38.2 Z{down.z_min:.4f} F{down.feed:.1f}"
            try:
                result = c.send(command)
            except FirmwareError as exc:
                self._recover(down.retract)
                raise _already_triggered(exc, down) or probe_missed(down, f": {exc.message}") from exc
            if kind == "G30" or c.rules.probe_reports_contact:
                report = result.payload  # "Bed X: .. Y: .. Z: .." / "[PRB:x,y,z:1]"
            else:  # Marlin G38.2 prints nothing: it stopped at the contact point (M114 D: 3 decimals)
                report = self._precise_position()
            if not isinstance(report, ProbeReport) or not report.triggered or report.z < down.z_min:
                self._recover(down.retract)
                raise probe_missed(down)
            c.run([down.retract, c.wait_motion])
            return ProbeResult(report.x, report.y, report.z)
        finally:
            c.state.release()

    def select_tool(self, tool: int) -> None:
        """``T<tool>`` (0 = the touch probe, 1.. = nozzles); waits for its ``ok``.  The
        firmware applies no offsets: programs are written in carriage coordinates.
        ``InvalidConfig`` (field ``tool``) for a number out of range or one the firmware
        refuses (Marlin ``Invalid extruder``)."""
        check_tool(tool, MAX_TOOL)
        c = self.commands
        c.state.claim("busy")
        try:
            result = c.send(f"T{tool}")
        finally:
            c.state.release()
        if any("invalid extruder" in line.lower() for line in result.reply_lines):
            raise InvalidConfig(f"the firmware has no tool T{tool}", field="tool", value=tool)

    def probe_toward(self, start: tuple[float, float, float], target: tuple[float, float, float],
                     feed_mm_min: float | None = None) -> ProbeResult:
        """Probe from ``start`` toward ``target`` (mm, carriage coordinates, any direction)
        with ``G38.2``; return the carriage position at the trigger.

        Travel to ``start`` at the travel feed: Z up first (to the higher of the current
        and the start height), then XY, then Z down, each its own move (the caller gives a
        start that is safe to reach that way).  Afterwards (hit or miss) the machine goes
        straight back to ``start``.  ``ProbeFailed`` when nothing is touched before the
        target (``reason`` ``triggered_before_motion`` when the probe was already
        triggered); ``InvalidConfig`` (field ``target``) when target equals start."""
        c = self.commands
        toward = probe_toward(c.profile, start, target, feed_mm_min)
        c.claim_motion("busy", "probe")
        try:
            here = c.position()
            c.run(["G90", *toward.approach(here[2])])
            try:
                result = c.send(toward.command)
            except FirmwareError as exc:
                self._recover(toward.back)
                raise _already_triggered(exc, toward) or probe_missed(toward, f": {exc.message}") from exc
            report = result.payload if c.rules.probe_reports_contact else self._precise_position()
            if not isinstance(report, ProbeReport) or not report.triggered:
                self._recover(toward.back)
                raise probe_missed(toward)
            c.run([toward.back, c.wait_motion])
            return ProbeResult(report.x, report.y, report.z)
        finally:
            c.state.release()

    def _precise_position(self) -> ProbeReport:
        """Marlin: where G38.2 stopped, from ``M114 D`` (3 decimals; plain M114 has 2)."""
        c = self.commands
        result = c.send("M114 D", c.timeout_s)
        for line in result.reply_lines:
            match = _LOGICAL.search(line)
            if match:
                x, y, z = (float(v) for v in match.groups())
                return ProbeReport(x, y, z)
        return ProbeReport(*c.position())

    def _recover(self, back: str) -> None:
        """After a failed probe: unlock (grbl's probe alarm), then ``back`` and wait for it."""
        c = self.commands
        if c.rules.unlock_command is not None:
            c.send(c.rules.unlock_command, c.timeout_s)
        c.run([back, c.wait_motion])


def _already_triggered(exc: FirmwareError, probe: ProbeDown | ProbeToward) -> ProbeFailed | None:
    """grbl's ``ALARM:4``: the probe was triggered before it moved; None for any other failure."""
    if not any(line.strip() == "ALARM:4" for line in exc.reply_lines):
        return None
    if isinstance(probe, ProbeDown):
        x, y = probe.x, probe.y
        return ProbeFailed(f"probe at ({x:.3f}, {y:.3f}) was already triggered before it moved (grbl ALARM:4): "
                           "check the probe", x=x, y=y, field="probe", value=[x, y],
                           reason="triggered_before_motion")
    return ProbeFailed(f"probe toward {probe.where} was already triggered before it moved (grbl ALARM:4): "
                       "check the probe", x=probe.target[0], y=probe.target[1], field="probe", value=probe.where,
                       reason="triggered_before_motion")
