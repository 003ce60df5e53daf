"""grbl 1.1h personality of the mock firmware (after grbl's ``protocol.c``, ``system.c``,
``report.c``, ``motion_control.c`` and the "Grbl v1.1 Interface" document).

* No line numbers or checksums; one ``ok`` or ``error:N`` per line, sent once the line is
  parsed and its motion *planned* (the planner has ``planner_blocks`` - 1 usable blocks; a
  block leaves it once the stepper has prepared all its step segments, ``segment_buffer``
  - 1 of 10 ms, so up to that many more acknowledged short moves wait unmoved there);
  the RX buffer (``rx_buffer``, 128 bytes) is what a character-counting host fills.
  ``error:1`` (no command letter) and ``error:2`` (bad number) come from the parser.
* Real-time bytes are taken out of the stream on arrival: ``?`` status report, ``!`` feed
  hold (planned motion freezes: ``Hold:0``; lines are still parsed until the planner is
  full), ``~`` cycle start, ``0x18`` soft reset (``ALARM:3`` if moving, then the banner).
* Status ``<State|MPos:x,y,z|Bf:blocks,bytes|FS:f,s>``: the state is Run only while
  motion is planned — a ``G4`` dwell reports Idle, as grbl does; ``$10`` is the report
  mask (bit 0: MPos, else WPos; bit 1: the ``Bf:`` buffer field, off by default); the
  position is where the tool is inside the running block, not the planned end.
  ``Ln:`` (the N word of the running block) only with the ``line_numbers`` compile option.
* Power-up (opening the port resets an Arduino): the bootloader swallows input for
  ``boot_s`` (times ``time_scale``), then the banner; on a fresh EEPROM ``error:7`` and the
  default settings come first.  With homing enabled (``homing``, ``$22=1``) grbl boots in
  Alarm (``[MSG:'$H'|'$X' to unlock]``); ``$H`` with homing disabled is ``error:5``; a
  failing homing cycle (``homing_fails``) prints ``ALARM:9``, ``ok`` and resets itself.
* ``$C`` toggles check mode (lines parsed, nothing moves or runs); leaving it soft-resets.
* ``$J=...`` jogs (state Jog; G-code lines meanwhile get ``error:9``).
* ``G38.2 X.. Y.. Z.. F..`` probes toward the target (any direction; no axis word:
  ``error:26``, the target where it is: ``error:33``): ``[PRB:x,y,z:1]`` then ``ok``; no
  contact: ``ALARM:5``, ``[PRB:x,y,z:0]``, ``ok``; starting inside the part (the probe
  already triggered): ``ALARM:4``, ``ok`` and no motion.  Contacts and readings follow
  ``hardware.mock.physics``.
* ``T<n>`` (a T word alone) selects tool n, as grbl's parser keeps it (n > 255:
  ``error:38``); ``M6`` stays unsupported (``error:20``).
  The alarm locks G-code (``error:9``) until ``$X`` or ``$H``.
* A damaged line (``checksum_rate``) is rejected with ``error:2`` and not executed.
"""

from __future__ import annotations

import re
from collections.abc import Generator

from .firmware import SLOW_S, FirmwareCore, Wait, normalized, split_words
from .grbl_system import GrblSystem

_MODAL = {"G17", "G21", "G20", "G90", "G91", "G94", "G54", "G55", "G56", "G57", "G58", "G59",
          "M9", "M8", "M7", "G40", "G49", "G80", "G4", "M2", "M30"}
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)")
RESET_S = 0.02  # model seconds grbl needs to re-initialise after a soft reset
_LINE_N = re.compile(r"^[Nn]\s*(\d+)")
_TOOL = re.compile(r"^T\d+$")
MAX_TOOL_NUMBER = 255


def syntax_error(command: str) -> int | None:
    """grbl's first parser check of a line: 1 when a word has no letter, 2 when a letter
    has no valid number (``gc_execute_line``); None when the words are well formed."""
    text = command.replace(" ", "").upper()
    i = 0
    while i < len(text):
        if not text[i].isalpha():
            return 1
        match = _NUMBER.match(text, i + 1)
        if match is None:
            return 2
        i = match.end()
    return None


class GrblFirmware(GrblSystem, FirmwareCore):
    """grbl behaviour; see module docstring."""

    dialect = "grbl"

    def cold_start(self) -> None:
        super().cold_start()
        self.feed = 0.0  # grbl boots with no feed rate: G1 without F is error:22
        self.alarm = getattr(self, "alarm", False)
        self.check_mode = False
        self.spindle, self.spindle_speed = "M5", 0.0  # grbl's reset stops spindle and coolant
        for output in ("spindle", "M7", "M8"):
            if self.world.outputs.get(output):
                self.world.set_output(output, 0.0)
        self.jogging = False
        self.homing_until: float | None = None
        self.booting_until = float("-inf")
        self.wcs = "G54"
        self.first_report = True
        self.load_eeprom()

    # ------------------------------------------------------------------ receive path
    def realtime(self, data: bytes, now: float) -> bytes:
        if now < self.booting_until:
            self.count_fault("lost_in_bootloader")
            return b""
        if not any(b in data for b in (b"?", b"!", b"~", b"\x18")):
            return data
        kept = bytearray()
        for byte in data:
            if byte == ord("?"):
                self.status(now)
            elif byte == ord("!"):
                if not self.alarm and not self.check_mode:
                    self.hold(now)
            elif byte == ord("~"):
                self.cycle_start(now)
            elif byte == 0x18:
                self.soft_reset(now)
                kept.clear()
            else:
                kept.append(byte)
        return bytes(kept)

    def block_capacity(self) -> int:
        return self.world.planner_blocks - 1  # BLOCK_BUFFER_SIZE 16 holds 15 blocks

    def state_name(self, now: float) -> str:
        """grbl's machine state as the status report names it."""
        if self.homing_until is not None:
            return "Home"
        if self.alarm:
            return "Alarm"
        if self.held_since is not None:
            return "Hold:0"
        if self.check_mode:
            return "Check"
        if self.moving():
            return "Jog" if self.jogging else "Run"
        return "Idle"  # also while a G4 dwell blocks the parser

    def status(self, now: float) -> None:
        mask = int(self.settings[10])
        x, y, z = self.machine_position(now)
        kind = "MPos" if mask & 1 else "WPos"
        fields = [self.state_name(now), f"{kind}:{x:.3f},{y:.3f},{z:.3f}"]
        if mask & 2:
            free_blocks = self.world.planner_blocks - 1 - len(self.planner) + self.segmented(now)
            queued = len(self.rx) + sum(len(d) for _, d in self.wire)
            fields.append(f"Bf:{free_blocks},{self.world.rx_buffer - 1 - queued}")
        if self.world.line_numbers and self.blocks and self.blocks[0][1]:
            fields.append(f"Ln:{self.blocks[0][1]}")
        fields.append(f"FS:{self.feed:.0f},0")
        if self.first_report:
            fields.append("WCO:0.000,0.000,0.000")
            self.first_report = False
        self.emit("<" + "|".join(fields) + ">", now)

    def soft_reset(self, now: float) -> None:
        """Ctrl-X: motion stops at once (position kept, planned motion lost), banner; the
        spindle and coolant (the dispenser) go off, as grbl's ``mc_reset()`` ("Kill spindle
        and coolant": ``spindle_stop(); coolant_stop();``, motion_control.c) and the
        re-initialisation after it (``spindle_init(); coolant_init();``, main.c)."""
        moving = self.moving() or self.homing_until is not None
        position = list(self.machine_position(now))
        self.lose_planned_motion(now)
        self.world.stats.stops += 1
        self.world.stats.executed_at_stop = self.world.transcript.executed_count
        self.wire.clear()
        if moving:
            self.emit("ALARM:3", now)
        alarm = self.alarm or moving
        self.cold_start()
        self.position = position
        self.alarm = alarm
        # re-initialising takes a moment; serial_reset_read_buffer drops what arrives meanwhile
        self.booting_until = now + RESET_S * self.scale if self.scale else float("-inf")
        self.out_free_at = max(self.out_free_at, now + RESET_S * self.scale)
        self.banner(now)

    def pump(self, now: float) -> bool:
        if self.current is not None or self.homing_until is not None:
            return False
        raw = self.take_line()
        if raw is None:
            return False
        self.world.stats.lines_received += 1
        text = raw.decode("latin-1").strip()
        if text and self.due("reset", text):
            self.hard_reset(now)
            return True
        if text and self.due("disconnect", text):
            self.disconnect(now)  # the line is lost with the receive buffer
            return True
        if text and self.chance(self.faults.checksum_rate, "checksum"):
            self.reply("error:2", now)
            return True
        number = _LINE_N.match(text)
        self.line_n = int(number.group(1)) if number else None
        command = normalized(text) if text else None
        if command is None:
            self.reply("ok", now)
        elif command.startswith("$"):
            self.system_command(command, now)
        elif syntax_error(command) is not None:
            self.reply(f"error:{syntax_error(command)}", now)
        elif self.alarm or (self.jogging and self.moving()):
            self.reply("error:9", now)
        else:
            self.jogging = False
            self.start(None, command, now)
        return True

    def hard_reset(self, now: float) -> None:
        """The board restarts: planned motion lost, position zeroed, banner, then the
        bootloader ignores input for ~1 s (with time_scale 0: until the port reopens)."""
        self.lose_planned_motion(now)
        self.wire.clear()  # bytes arriving while the board restarts are lost
        self.cold_start()
        self.banner(now)
        self.booting_until = now + 1.0 * self.scale if self.scale else float("inf")

    def reply(self, text: str, now: float) -> None:
        """Send ``ok``/``error:N`` (with the ok faults)."""
        if text == "ok" and self.chance(self.faults.drop_ok_rate, "drop_ok"):
            return
        self.emit(text, now)
        if text == "ok" and self.chance(self.faults.duplicate_ok_rate, "duplicate_ok"):
            self.emit(text, now)

    def switch_output(self, command: str, head: str, params: dict[str, float]) -> None:
        """``M3``/``M4``/``M5`` (spindle: PWM at the modal S word, 0 after reset, so a bare
        ``M3`` switches nothing; world output ``"spindle"``) or ``M7``/``M8``/``M9`` (mist and
        flood coolant, plain pins: outputs ``"M7"``/``"M8"``, e.g. a UV lamp or a dispenser),
        and the dispenser when ``command`` is its on/off command."""
        if head in ("M3", "M4", "M5"):
            self.spindle_speed = params.get("S", self.spindle_speed)
            self.spindle = head
            self.world.set_output("spindle", self.spindle_speed if head != "M5" else 0.0)
        else:
            if head == "M9":
                self.world.set_output("M7", 0.0)
            self.world.set_output("M8" if head != "M7" else "M7", 0.0 if head == "M9" else 1.0)
        switch = self.world.dispenser_switch(command, head, params)
        if switch is not None:  # a dispenser on the spindle output runs at its S: off at S0
            self.dispensing = switch and (head not in ("M3", "M4") or self.spindle_speed > 0)

    # ------------------------------------------------------------------ execution
    def run(self, line_no: int | None, command: str, now: float) -> Generator[Wait, None, None]:
        head, params = split_words(command)
        if self.chance(self.faults.slow_rate, "slow"):
            yield from self.dwell(SLOW_S, now)
        if head in ("G0", "G1"):
            if "F" in params:
                self.feed = params["F"] * (25.4 if self.inches else 1.0)
            if head == "G1" and self.feed <= 0:
                self.reply("error:22", now)
                return
            if not self.check_mode:
                feed = self.world.rapid_feed_mm_min if head == "G0" else self.feed
                yield from self.plan_move(self.target_of(params), feed, now)
        elif head in ("G54", "G55", "G56", "G57", "G58", "G59"):
            self.wcs = head
        elif self.check_mode and head in ("G4", "G28", "G30", "G38.2", "G38.3"):
            pass  # check mode: parsed, nothing runs
        elif head in ("M3", "M4", "M5", "M7", "M8", "M9"):  # spindle, coolant: synced with motion
            yield ("drain",)
            if not self.check_mode:  # check mode parses them, switches nothing (coolant_sync, spindle_sync)
                self.switch_output(command, head, params)
        elif (yield from self.run_shared(command, head, params)):
            pass  # dispense on/off, G20, G21, G90, G91, G92
        elif head == "G4":
            if "P" not in params:
                self.reply("error:28", now)
                return
            yield ("drain",)
            self.advance_clock(params["P"])
            yield from self.dwell(params["P"], now)
        elif _TOOL.match(head):
            if int(head[1:]) > MAX_TOOL_NUMBER:
                self.reply("error:38", now)  # STATUS_GCODE_MAX_VALUE_EXCEEDED
                return
            yield ("drain",)
            self.active_tool = int(head[1:])  # kept even when the mock has no such nozzle
        elif head in ("G28", "G30"):
            yield from self.plan_move([0.0, 0.0, 0.0], self.world.rapid_feed_mm_min, now)
        elif head in ("G38.2", "G38.3"):
            done = yield from self.g38(head, params, now)
            if not done:
                return
        elif head not in _MODAL:
            self.reply("error:20", now)
            return
        if not self.check_mode:
            self.record(command, now)
        self.reply("ok", now)

    def g38(self, head: str, params: dict[str, float], now: float
            ) -> Generator[Wait, None, bool]:
        if "F" in params:
            self.feed = params["F"]
        if self.feed <= 0:
            self.reply("error:22", now)
            return False
        if not any(a in params for a in "XYZ"):
            self.reply("error:26", now)  # STATUS_GCODE_NO_AXIS_WORDS
            return False
        target = self.target_of(params)
        if all(abs(t - p) <= 1e-9 for t, p in zip(target, self.position)):
            self.reply("error:33", now)  # STATUS_GCODE_INVALID_TARGET
            return False
        yield ("drain",)
        touch = self.touch(tuple(self.position), tuple(target), self.feed)
        if touch.status == "inside":  # grbl 1.1 mc_probe_cycle: alarm, no motion, the line still gets ok
            self.raise_alarm(4, now)
            return True
        yield from self.dwell(touch.travel_mm / max(self.feed, 1e-9) * 60.0, now)
        self.position = list(touch.reading)
        x, y, z = self.position
        if touch.status != "hit" and head == "G38.2":
            self.raise_alarm(5, now)  # then [PRB:..:0] and ok, like grbl 1.1
        flag = 1 if touch.status == "hit" else 0
        self.emit(f"[PRB:{x:.3f},{y:.3f},{z:.3f}:{flag}]", now)
        return True

    def raise_alarm(self, code: int, now: float) -> None:
        """Probe alarm (not critical): report it and lock G-code until ``$X``/``$H``."""
        self.emit(f"ALARM:{code}", now)
        self.alarm = True
