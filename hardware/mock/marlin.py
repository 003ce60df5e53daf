"""Marlin personality of the mock firmware (after Marlin 2.x ``queue.cpp``/``gcode.cpp``).

* Lines with ``N`` must be ``last_N + 1`` (except ``M110``) and carry a correct ``*``
  checksum; otherwise ``Error:<reason>, Last Line: n`` then ``Resend: n+1`` then ``ok``,
  and the rest of the RX buffer is flushed (``gcode_line_error``).
* Accepted lines go into a command ring buffer of ``command_buffer`` slots (BUFSIZE; the
  running command holds one); ``ok`` is sent after a command was *processed* (for moves:
  planned), with ``ADVANCED_OK`` as ``ok N<n> P<planner free> B<buffer free>``.
* ``echo:busy: processing`` every 2 s (scaled) while a command runs long.
* ``M112`` is caught by the emergency parser on arrival: ``Error:Printer halted. kill()
  called!`` and nothing more until the port is reopened (reset).
* ``G30 [X Y]`` probes down and prints ``Bed X: x Y: y Z: z``; a miss prints
  ``Error:Probing Failed``.  ``G38.2 X.. Y.. Z.. F..`` probes toward the target in any
  direction and stops at the trigger (miss: ``Error:Failed to reach target``).  ``M114``
  prints the planned position (2 decimals; ``M114 D`` adds ``Logical: X: Y: Z:`` with 3).
* ``M154 S<s>`` (AUTO_REPORT_POSITION, ``Cap:AUTOREPORT_POS:1``) prints the same *planned*
  position every s seconds (``report_current_position_projected``, Marlin 2.0.9-2.1.2).
* With ``realtime_reports`` (REALTIME_REPORTING_COMMANDS) the emergency parser answers
  ``S000`` on arrival with the position from the steppers and ``S_XYZ:<state>``; the line
  then reaches the queue and gets a plain ``ok``.  Without it: ``Unknown command``, ``ok``.
  Contacts and readings follow ``hardware.mock.physics`` (ball stylus, pre-travel, drift).
* ``T<n>`` selects tool n (T0 the probe, T1.. the world's nozzles; waits for the moves
  before it); an unknown tool prints ``echo:T<n> Invalid extruder`` then ``ok``.
"""

from __future__ import annotations

import re
from collections.abc import Generator

from ..dialects import dialect
from ..protocol import checksum
from .firmware import SLOW_S, FirmwareCore, Wait, normalized, split_words

_NUMBERED = re.compile(r"^N(-?\d+)\s*")
_TOOL = re.compile(r"^T\d+$")
G30_FEED_MM_MIN = 300.0  # the mock's G30 probing speed (5 mm/s)
_SILENT = {"G21", "G90", "G91", "G92", "M82", "M83", "M84", "M17", "M18", "M104", "M140",
           "M106", "M107", "M117", "M400", "G4", "M110", "T0", "M211", "M220", "M221"}


class MarlinFirmware(FirmwareCore):
    """Marlin 2 behaviour; see module docstring."""

    dialect = "marlin"
    DISCONNECT_WHEN_RECORDED = True

    def cold_start(self) -> None:
        super().cold_start()
        self.last_n = 0

    # ------------------------------------------------------------------ receive path
    def realtime(self, data: bytes, now: float) -> bytes:
        """The emergency parser sees every byte on arrival: ``M112`` kills (the line goes no
        further); with ``realtime_reports`` an ``S000`` line is answered at once with the
        real stepper position (``report_current_position_moving``) and still goes on to
        the command queue, which acknowledges it in turn (a plain ``ok``)."""
        if self.world.realtime_reports and b"S000" in data:
            for line in data.split(b"\n"):
                if (normalized(line.decode("latin-1")) or "").upper() == "S000":
                    self.report_moving(now)
        if b"M112" not in data:
            return data
        kept = []
        for line in data.split(b"\n"):
            text = normalized(line.decode("latin-1")) or ""
            if text.split(" ")[0] == "M112":
                self.kill(now)
            else:
                kept.append(line)
        return b"\n".join(kept)

    def auto_report(self, now: float) -> None:
        """``M154``'s report is ``report_current_position_projected``: the position of the
        last G-code *planned* (and the planner's step counts), not where the tool is."""
        x, y, z = self.position
        self.emit(f"X:{x:.2f} Y:{y:.2f} Z:{z:.2f} E:0.00 Count X:{round(x * 80)} "
                  f"Y:{round(y * 80)} Z:{round(z * 400)}", now)

    def report_moving(self, now: float) -> None:
        """Marlin's ``report_current_position_moving``: the position from the steppers
        (where the tool is inside the running block), then the grbl-like state
        (``S_XYZ:5`` running, ``S_XYZ:3`` idle)."""
        x, y, z = self.machine_position(now)
        self.emit(f"X:{x:.2f} Y:{y:.2f} Z:{z:.2f} E:0.00 Count X:{round(x * 80)} "
                  f"Y:{round(y * 80)} Z:{round(z * 400)}", now)
        self.emit(f"S_XYZ:{5 if self.moving() else 3}", now)

    def kill(self, now: float) -> None:
        """Emergency stop: halt everything; only a reset (reopen) brings it back.  As
        Marlin's ``kill()``/``minkill()`` (MarlinCore.cpp): heaters and a cutter go off,
        a fan (``M106``) or ``M42`` pin keeps its level until the reset
        (``Dialect.estop_keeps``): a dispenser on a fan output stays on while halted."""
        self.emit("Error:Printer halted. kill() called!", now)
        kept = self.dispensing and dialect(self.dialect).keeps_through_estop(self.world.dispense_commands[0])
        self.cold_start()
        self.dispensing = kept
        self.world.stats.stops += 1
        self.world.stats.executed_at_stop = self.world.transcript.executed_count
        self.halted = True

    def pump(self, now: float) -> bool:
        # Marlin reads serial lines only between commands (a blocking command, including
        # one waiting for a planner block, keeps the main loop from reading).
        progressed = False
        if self.current is not None:
            return False
        while len(self.queue) < self.world.command_buffer:
            raw = self.take_line()
            if raw is None:
                break
            progressed = True
            self.accept(raw.decode("latin-1"), now)
        if self.current is None and self.queue and not self.halted:
            line_no, command = self.queue.popleft()
            if self.due("reset", command):
                self.reset(now)
            else:
                self.start(line_no, command, now)
            progressed = True
        return progressed

    def line_error(self, reason: str, now: float) -> None:
        """``gcode_line_error`` + ``flush_and_request_resend``."""
        self.emit(f"Error:{reason}, Last Line: {self.last_n}", now)
        self.rx.clear()
        self.emit(f"Resend: {self.last_n + 1}", now)
        self.emit("ok", now)

    def accept(self, text: str, now: float) -> None:
        """Check one received line and queue its command."""
        text = text.strip()
        if not text:
            return
        match = _NUMBERED.match(text)
        star_at = text.rfind("*")
        faulty = match is not None and "M110" not in text  # a lost M110 cannot be resent
        if (faulty and match is not None and star_at > match.end()
                and self.chance(self.faults.checksum_rate, "checksum")):
            i = self.rng.randrange(match.end(), star_at)
            flipped = chr(ord(text[i]) ^ 0x01)
            text = text[:i] + (flipped if flipped not in "*\r\n;(" else "#") + text[i + 1:]
        if faulty and match is not None and self.chance(self.faults.line_number_rate, "line_number"):
            digits = match.group(1)
            i = self.rng.randrange(len(digits)) if digits[0] != "-" else len(digits) - 1
            wrong = str((int(digits[i]) + 1 + self.rng.randrange(8)) % 10)
            text = f"N{digits[:i]}{wrong}{digits[i + 1:]}" + text[match.end(1):]
            match = _NUMBERED.match(text)
        line_no = None
        if match:
            line_no = int(match.group(1))
            is_m110 = "M110" in text
            if line_no != self.last_n + 1 and not is_m110:
                return self.line_error("Line Number is not Last Line Number+1", now)
            body, star, given = text.rpartition("*")
            if not star:
                return self.line_error("No Checksum with line number", now)
            if not given.strip().isdigit() or int(given) != checksum(body):
                return self.line_error("checksum mismatch", now)
            self.last_n = line_no
            if is_m110:
                _, params = split_words(normalized(body) or "")
                self.last_n = int(params.get("N", line_no))
        elif "*" in text:
            return self.line_error("No Line Number with checksum", now)
        command = normalized(text)
        if command:
            self.queue.append((line_no, command))

    # ------------------------------------------------------------------ execution
    def keepalive(self, now: float) -> None:
        self.emit("echo:busy: processing", now)

    def ok(self, line_no: int | None, now: float) -> None:
        """Acknowledge a processed command (with the ok faults)."""
        if self.chance(self.faults.drop_ok_rate, "drop_ok"):
            return
        if self.world.advanced_ok:
            free_p = self.world.planner_blocks - len(self.planner)
            free_b = self.world.command_buffer - 1 - len(self.queue)
            number = f" N{line_no}" if line_no is not None else ""
            text = f"ok{number} P{free_p} B{max(free_b, 0)}"
        else:
            text = "ok"
        self.emit(text, now)
        if self.chance(self.faults.duplicate_ok_rate, "duplicate_ok"):
            self.emit(text, now)
        if line_no is not None and self.chance(self.faults.resend_rate, "resend"):
            self.emit(f"Resend: {max(self.last_n - self.rng.randrange(0, 2), 1)}", now)
            self.emit("ok", now)

    # one flat dispatch over cases; splitting it hides their order
    def run(self, line_no: int | None, command: str, now: float) -> Generator[Wait, None, None]:  # noqa: C901
        head, params = split_words(command)
        if self.chance(self.faults.busy_rate, "busy"):
            for _ in range(self.rng.randrange(2, 6)):
                self.emit("echo:busy: processing", now)
        if self.chance(self.faults.slow_rate, "slow"):
            if not self.scale:
                self.emit("echo:busy: processing", now)
            yield from self.dwell(SLOW_S, now)
        if head in ("G0", "G1"):
            if "F" in params:
                self.feed = params["F"]
            yield from self.plan_move(self.target_of(params), self.feed, now)
        elif (yield from self.run_shared(command, head, params)):
            pass  # dispense on/off, G90, G91, G92
        elif head == "G28":
            yield from self.plan_move([0.0, 0.0, 0.0], self.world.rapid_feed_mm_min, now)
            yield ("drain",)
            self.homed = True
        elif head in ("M400", "G4"):
            yield ("drain",)
            seconds = params.get("P", 0.0) / 1000.0 + params.get("S", 0.0)
            self.advance_clock(seconds)
            yield from self.dwell(seconds, now)
        elif _TOOL.match(head):
            yield ("drain",)  # a tool change waits for the moves before it
            if not self.select_tool(int(head[1:])):
                self.emit(f"echo:{head} Invalid extruder", now)
        elif head == "G30":
            yield from self.g30(params, now)
        elif head == "G38.2" or head == "G38.3":
            yield from self.g38(head, params, now)
        elif head == "M114":
            x, y, z = self.position
            self.emit(f"X:{x:.2f} Y:{y:.2f} Z:{z:.2f} E:0.00 Count X:{round(x * 80)} "
                      f"Y:{round(y * 80)} Z:{round(z * 400)}", now)
            if "D" in command.split()[1:]:  # M114 D: the detailed report, 3 decimals
                self.emit(f"Logical: X:{x:.3f} Y:{y:.3f} Z:{z:.3f}", now)
        elif head == "M42":  # set a pin (the UV lamp's output): immediate, as Marlin's M42
            self.world.set_output(f"P{int(params.get('P', -1))}", params.get("S", 255.0))
        elif head == "M115":
            self.identify(now)
        elif head == "M154":  # AUTO_REPORT_POSITION: S<seconds> (a byte), 0 = off
            self.auto_report_s = float(max(0, min(255, int(params.get("S", 0)))))
            self.auto_report_at = now + self.auto_report_s * self.scale \
                if self.auto_report_s and self.scale else float("inf")
        elif head == "M105":
            self.record(command, now)
            self.emit("ok T:21.50 /0.00 B:21.20 /0.00 @:0 B@:0", now)
            return
        elif head == "S000" and self.world.realtime_reports:
            pass  # answered by the emergency parser on arrival; the queue only acknowledges it
        elif head not in _SILENT:
            self.emit(f'echo:Unknown command: "{command}"', now)
        self.record(command, now)
        self.ok(line_no, now)

    def g30(self, params: dict[str, float], now: float) -> Generator[Wait, None, None]:
        """Probe straight down at X Y from the current height (5 mm/s down, and as much
        back up on the machine clock: the carriage ends where it started)."""
        x = params.get("X", self.position[0])
        y = params.get("Y", self.position[1])
        z_start = self.position[2]
        yield from self.plan_move([x, y, z_start], self.world.rapid_feed_mm_min, now)
        yield ("drain",)
        touch = self.touch((x, y, z_start), (x, y, self.world.probe_z_min), G30_FEED_MM_MIN)
        travel = touch.travel_mm if touch.status != "inside" else z_start - self.world.probe_z_min
        self.advance_clock(touch.travel_mm / G30_FEED_MM_MIN * 60.0)  # back up
        yield from self.dwell(max(travel, 0.0) / 5.0, now)  # 5 mm/s probing speed
        if touch.status == "hit":
            rx, ry, rz = touch.reading
            self.emit(f"Bed X: {rx:.3f} Y: {ry:.3f} Z: {rz:.3f}", now)
        else:
            self.emit("Error:Probing Failed", now)

    def g38(self, head: str, params: dict[str, float], now: float
            ) -> Generator[Wait, None, None]:
        """Probe toward X Y Z (any direction): the carriage stops at the trigger (read it
        with M114); no contact: the target, and ``Error:Failed to reach target`` (G38.2)."""
        yield ("drain",)
        target = self.target_of(params)
        feed = params.get("F", self.feed)
        touch = self.touch(tuple(self.position), tuple(target), feed)
        yield from self.dwell(touch.travel_mm / max(feed, 1e-9) * 60.0, now)
        if touch.status != "inside":
            self.position = list(touch.reading)
        if touch.status != "hit" and head == "G38.2":
            self.emit("Error:Failed to reach target", now)

    def identify(self, now: float) -> None:
        self.emit("FIRMWARE_NAME:Marlin 2.1.2.1 (mock) SOURCE_CODE_URL:github.com/MarlinFirmware/"
                  "Marlin PROTOCOL_VERSION:1.0 MACHINE_TYPE:Conforma mock KINEMATICS:Cartesian "
                  f"EXTRUDER_COUNT:{max(1, len(self.world.tools))} UUID:00000000-0000-0000-0000-000000000000", now)
        caps = {"SERIAL_XON_XOFF": 0, "EEPROM": 0, "AUTOREPORT_POS": 1, "AUTOREPORT_TEMP": 0, "EMERGENCY_PARSER": 1,
                "Z_PROBE": 1, "ADVANCED_OK": int(self.world.advanced_ok)}
        for name, flag in caps.items():
            self.emit(f"Cap:{name}:{flag}", now)

    # ------------------------------------------------------------------ resets
    def banner(self, now: float) -> None:
        self.emit("start", now)
        self.emit("echo:Marlin 2.1.2.1 (mock)", now)
        self.emit("echo: Last Updated: 2024-01-01 | Author: (conforma mock)", now)

    def reset(self, now: float) -> None:
        """Controller restart: buffers, planned motion, bytes on their way and the line
        number lost, banner printed."""
        self.lose_planned_motion(now)
        self.wire.clear()
        self.cold_start()
        self.banner(now)

    hard_reset = reset

    def on_attach(self, now: float, first: bool) -> None:
        if first or self.halted:
            self.reset(now)
