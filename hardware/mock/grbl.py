"""grbl 1.1 personality of the mock firmware (after grbl ``protocol.c``/``report.c``).

* No line numbers or checksums; one ``ok`` or ``error:N`` per line, sent once the line is
  parsed and its motion planned (the planner has ``planner_blocks`` blocks); the RX buffer
  (``rx_buffer``, 128 bytes) is what a character-counting host fills.
* Real-time bytes are taken out of the stream on arrival: ``?`` status report
  (``<Idle|MPos:x,y,z|Bf:blocks,bytes|FS:f,0>``), ``!`` hold, ``~`` resume, ``0x18``
  soft reset (``ALARM:3`` if moving, then the banner).
* ``G38.2 Z.. F..`` probes down: ``[PRB:x,y,z:1]`` then ``ok``; no contact: ``ALARM:5``,
  ``[PRB:x,y,z:0]``, ``ok`` (grbl 1.1 ``mc_probe_cycle``); starting inside the part:
  ``ALARM:4``, ``ok``.  The alarm locks G-code (``error:9``) until ``$X`` or ``$H``.
* A damaged line (``checksum_rate``) is rejected with ``error:2`` and not executed.
* Opening the port resets the controller (DTR), and so does a disconnect.
"""

from __future__ import annotations

from collections.abc import Generator

from .firmware import SLOW_S, FirmwareCore, Wait, normalized, split_words

_MODAL = {"G17", "G21", "G90", "G91", "G94", "G54", "M9", "M8", "M7", "G40", "G49", "G80", "G4"}
_STATUS = ord("?")


class GrblFirmware(FirmwareCore):
    """grbl behaviour; see module docstring."""

    dialect = "grbl"

    def cold_start(self) -> None:
        super().cold_start()
        self.alarm = False
        self.hold = False
        self.booting_until = float("-inf")

    # ------------------------------------------------------------------ receive path
    def realtime(self, data: bytes, now: float) -> bytes:
        if now < self.booting_until:
            return b""
        if not any(b in data for b in (b"?", b"!", b"~", b"\x18")):
            return data
        kept = bytearray()
        for byte in data:
            if byte == _STATUS:
                self.status(now)
            elif byte == ord("!"):
                self.hold = True
            elif byte == ord("~"):
                self.hold = False
            elif byte == 0x18:
                self.soft_reset(now)
                kept.clear()
            else:
                kept.append(byte)
        return bytes(kept)

    def status(self, now: float) -> None:
        if self.alarm:
            state = "Alarm"
        elif self.hold:
            state = "Hold:0"
        else:
            state = "Run" if (self.planner or self.current is not None) else "Idle"
        x, y, z = self.position
        free_blocks = self.world.planner_blocks - 1 - len(self.planner)
        free_bytes = self.world.rx_buffer - 1 - len(self.rx) - sum(len(d) for _, d in self.wire)
        self.emit(f"<{state}|MPos:{x:.3f},{y:.3f},{z:.3f}|Bf:{free_blocks},{free_bytes}"
                  f"|FS:{self.feed:.0f},0>", now)

    def soft_reset(self, now: float) -> None:
        moving = bool(self.planner) or self.current is not None
        position = list(self.position)
        self.wire.clear()
        if moving:
            self.emit("ALARM:3", now)
        self.cold_start()
        self.position = position
        self.alarm = moving
        self.banner(now)

    def pump(self, now: float) -> bool:
        if self.current is not None or self.hold:
            return False
        raw = self.take_line()
        if raw is None:
            return False
        text = raw.decode("latin-1").strip()
        if text and self.due("reset", text):
            self.cold_start()
            self.banner(now)
            # bootloader: input is lost for ~1 s (with time_scale 0: until the port reopens)
            self.booting_until = now + 1.0 * self.scale if self.scale else float("inf")
            return True
        if text and self.due("disconnect", text):
            self.disconnect(now)  # the line is lost with the receive buffer
            return True
        if text and self.chance(self.faults.checksum_rate, "checksum"):
            self.reply("error:2", now)
            return True
        command = normalized(text) if text else None
        if command is None:
            self.reply("ok", now)
        elif command.startswith("$"):
            self.system_command(command, now)
        elif self.alarm:
            self.reply("error:9", now)
        else:
            self.start(None, command, now)
        return True

    def reply(self, text: str, now: float) -> None:
        """Send ``ok``/``error:N`` (with the ok faults)."""
        if text == "ok" and self.chance(self.faults.drop_ok_rate, "drop_ok"):
            return
        self.emit(text, now)
        if text == "ok" and self.chance(self.faults.duplicate_ok_rate, "duplicate_ok"):
            self.emit(text, now)

    def system_command(self, command: str, now: float) -> None:
        upper = command.upper()
        if upper == "$X":
            self.alarm = False
            self.emit("[MSG:Caution: Unlocked]", now)
        elif upper == "$H":
            self.position = [0.0, 0.0, 0.0]
            self.homed, self.alarm = True, False
        elif upper == "$I":
            self.emit("[VER:1.1h.20190830:]", now)
            self.emit(f"[OPT:V,{self.world.planner_blocks - 1},{self.world.rx_buffer}]", now)
        elif upper == "$G":
            mode = "G90" if self.absolute else "G91"
            self.emit(f"[GC:G0 G54 G17 G21 {mode} G94 M5 M9 T0 F{self.feed:.0f} S0]", now)
        elif upper == "$$":
            for key, value in (("0", "10"), ("10", "1"), ("110", "500.000")):
                self.emit(f"${key}={value}", now)
        else:
            self.reply("error:3", now)
            return
        self.record(upper, now)
        self.reply("ok", now)

    # ------------------------------------------------------------------ execution
    def run(self, line_no: int | None, command: str, now: float) -> Generator[Wait, None, None]:
        head, params = split_words(command)
        if self.chance(self.faults.slow_rate, "slow"):
            yield from self.dwell(SLOW_S, now)
        if head in ("G0", "G1"):
            if "F" in params:
                self.feed = params["F"]
            if head == "G1" and self.feed <= 0:
                self.reply("error:22", now)
                return
            feed = self.world.rapid_feed_mm_min if head == "G0" else self.feed
            yield from self.plan_move(self.target_of(params), feed, now)
        elif (yield from self.run_shared(command, head, params)):
            pass  # dispense on/off, G90, G91, G92
        elif head == "G4":
            yield ("drain",)
            yield from self.dwell(params.get("P", 0.0), now)
        elif head in ("G28", "G30"):
            yield from self.plan_move([0.0, 0.0, 0.0], self.world.rapid_feed_mm_min, now)
        elif head in ("G38.2", "G38.3"):
            done = yield from self.g38(head, params, now)
            if not done:
                return
        elif head not in _MODAL:
            self.reply("error:20", now)
            return
        self.record(command, now)
        self.reply("ok", now)

    def g38(self, head: str, params: dict[str, float], now: float
            ) -> Generator[Wait, None, bool]:
        if "F" in params:
            self.feed = params["F"]
        if "Z" not in params or any(a in params and abs(params[a] - self.position[i]) > 1e-9
                                    for i, a in enumerate("XY")):
            self.reply("error:33", now)
            return False
        yield ("drain",)
        z_target = params["Z"] if self.absolute else self.position[2] + params["Z"]
        z = self.probe_down(z_target)
        if z == "inside":  # grbl 1.1 mc_probe_cycle: alarm, no motion, the line still gets ok
            self.raise_alarm(4, now)
            return True
        end = z if isinstance(z, float) else z_target
        yield from self.dwell(abs(self.position[2] - end) / max(self.feed, 1e-9) * 60.0, now)
        self.position[2] = end
        x, y, _ = self.position
        if not isinstance(z, float) and head == "G38.2":
            self.raise_alarm(5, now)  # then [PRB:..:0] and ok, like grbl 1.1
        flag = 1 if isinstance(z, float) else 0
        self.emit(f"[PRB:{x:.3f},{y:.3f},{end:.3f}:{flag}]", now)
        return True

    def raise_alarm(self, code: int, now: float) -> None:
        """Probe alarm (not critical): report it and lock G-code until ``$X``/``$H``."""
        self.emit(f"ALARM:{code}", now)
        self.alarm = True

    # ------------------------------------------------------------------ resets
    def banner(self, now: float) -> None:
        self.emit("", now)
        self.emit("Grbl 1.1h ['$' for help]", now)
        if self.alarm:
            self.emit("[MSG:'$H'|'$X' to unlock]", now)

    def on_attach(self, now: float, first: bool) -> None:
        position = list(self.position)
        self.cold_start()  # DTR reset; also ends a bootloader pause
        if not first:
            self.position = position
        self.banner(now)

    def disconnect(self, now: float) -> None:
        super().disconnect(now)
        position = list(self.position)
        self.cold_start()
        self.position = position
