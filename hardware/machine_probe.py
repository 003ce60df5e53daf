"""Probing of ``hardware.machine.Machine`` (a mixin): travel to a station, touch down with
the firmware's probe command (Marlin ``G30`` / ``G38.2``, grbl ``G38.2``), read the contact
point, retract; failures leave the machine idle, unlocked and retracted."""

from __future__ import annotations

from .errors import FirmwareError, InvalidConfig, ProbeFailed
from .events import ProbeReport
from .machine_types import ProbeResult


class ProbeOperations:
    """Mixin of ``Machine``; every method expects a connected machine."""

    def probe(self, x: float, y: float, z_start: float | None = None, z_min: float | None = None,
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
        kind = p.probe_command or ("G30" if self.dialect == "marlin" else "G38.2")
        travel = p.travel_feed_mm_min
        self._claim("busy")
        try:
            self._run(["G90", f"G1 Z{z_start:.4f} F{travel:.1f}",
                       f"G1 X{x:.4f} Y{y:.4f} F{travel:.1f}"])
            command = f"G30 X{x:.4f} Y{y:.4f}" if kind == "G30" else f"G38.2 Z{z_min:.4f} F{feed:.1f}"
            try:
                result = self.link.send(command, self.timeout_s * 10)
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
            if kind == "G30" or self.dialect == "grbl":
                report = result.payload  # "Bed X: .. Y: .. Z: .." / "[PRB:x,y,z:1]"
            else:  # Marlin G38.2 prints nothing: it stopped at the contact point
                report = ProbeReport(*self._position())
            if not isinstance(report, ProbeReport) or not report.triggered or report.z < z_min:
                self._recover_after_probe(z_start)
                raise ProbeFailed(f"probe at ({x:.3f}, {y:.3f}) found no surface above "
                                  f"z={z_min:.3f}", x=x, y=y, field="probe", value=[x, y])
            self._run([f"G1 Z{z_start:.4f} F{travel:.1f}", self._wait_motion()])
            return ProbeResult(report.x, report.y, report.z)
        finally:
            self._release()

    def _recover_after_probe(self, z_start: float) -> None:
        if self.dialect == "grbl":
            self.link.send("$X", self.timeout_s)
        self._run([f"G1 Z{z_start:.4f} F{self.profile.travel_feed_mm_min:.1f}",
                   self._wait_motion()])

