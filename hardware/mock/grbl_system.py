"""grbl's ``$`` system commands, settings, boot and homing for the mock (a mixin of
``hardware.mock.grbl.GrblFirmware``; see that module's docstring)."""

from __future__ import annotations

from collections.abc import Generator
from typing import TYPE_CHECKING

from .firmware import FirmwareCore, Wait, split_words

VERSION = "1.1h.20190830"
BANNER = "Grbl 1.1h ['$' for help]"
#: grbl 1.1h defaults (defaults.h, DEFAULTS_GENERIC) in ``$$`` order
DEFAULT_SETTINGS = {
    0: "10", 1: "25", 2: "0", 3: "0", 4: "0", 5: "0", 6: "0", 10: "1", 11: "0.010",
    12: "0.002", 13: "0", 20: "0", 21: "0", 22: "0", 23: "0", 24: "25.000", 25: "500.000",
    26: "250", 27: "1.000", 30: "1000", 31: "0", 32: "0", 100: "250.000", 101: "250.000",
    102: "250.000", 110: "500.000", 111: "500.000", 112: "500.000", 120: "10.000",
    121: "10.000", 122: "10.000", 130: "200.000", 131: "200.000", 132: "200.000",
}
HOMING_S = 1.5  # model seconds a homing cycle takes


class GrblSystem(FirmwareCore):
    """grbl's part of ``GrblFirmware`` over the firmware core: ``$`` commands, EEPROM settings,
    power-up and homing."""

    # grbl's state (set by GrblFirmware.cold_start)
    settings: dict[int, str]
    check_mode: bool
    jogging: bool
    homing_until: float | None
    booting_until: float
    wcs: str
    spindle: str   # "M3" | "M4" | "M5"
    spindle_speed: float   # the modal S word

    if TYPE_CHECKING:  # GrblFirmware's
        def reply(self, text: str, now: float) -> None: ...

        def soft_reset(self, now: float) -> None: ...

    def load_eeprom(self) -> None:
        """Settings as stored; a fresh EEPROM fails to read (``error:7``) and is restored."""
        world = self.world
        if world.grbl_eeprom is None:
            world.grbl_eeprom = dict(DEFAULT_SETTINGS)
            world.grbl_eeprom[22] = "1" if world.homing else "0"
            world.grbl_eeprom_fresh = world.fresh_eeprom
        self.settings = world.grbl_eeprom

    # ------------------------------------------------------------------ power-up / reset
    def banner(self, now: float) -> None:
        self.emit("", now)
        self.emit(BANNER, now)
        if self.alarm:
            self.emit("[MSG:'$H'|'$X' to unlock]", now)

    def power_up(self, now: float, position: list[float] | None) -> None:
        """DTR reset: the bootloader swallows input for ``boot_s``, then grbl starts."""
        self.lose_planned_motion(now)
        self.alarm = False
        self.cold_start()
        if position is not None:
            self.position = position
        self.load_eeprom()
        boot = self.world.boot_s * self.scale
        self.booting_until = now + boot if boot > 0 else float("-inf")
        self.out_free_at = max(self.out_free_at, now + boot)  # nothing leaves before the boot
        if self.world.grbl_eeprom_fresh:
            self.world.grbl_eeprom_fresh = False
            self.emit("error:7", now)  # settings_init: EEPROM read fail, defaults restored
            for key, value in self.settings.items():
                self.emit(f"${key}={value}", now)
        self.alarm = self.settings[22] == "1"  # HOMING_INIT_LOCK
        self.banner(now)

    def on_attach(self, now: float, first: bool) -> None:
        self.power_up(now, None if first else list(self.machine_position(now)))

    def disconnect(self, now: float) -> None:
        """USB drop: the board resets when it re-enumerates; planned motion is lost."""
        position = list(self.machine_position(now))
        self.lose_planned_motion(now)
        super().disconnect(now)
        self.cold_start()
        self.position = position

    # ------------------------------------------------------------------ $ commands
    def system_command(self, command: str, now: float) -> None:
        upper = command.upper().replace(" ", "")
        if upper.startswith("$J="):
            return self.jog(upper[3:], now)
        if "=" in upper and upper[1:].split("=")[0].isdigit():
            return self.set_setting(upper, now)
        handler = {"$X": self.unlock, "$H": self.home, "$I": self.build_info, "$G": self.modes,
                   "$$": self.dump_settings, "$C": self.toggle_check, "$#": self.parameters
                   }.get(upper)
        if handler is None:
            self.reply("error:3", now)
            return
        handler(now)

    def unlock(self, now: float) -> None:
        if self.alarm:
            self.alarm = False
            self.emit("[MSG:Caution: Unlocked]", now)
        self.reply("ok", now)

    def build_info(self, now: float) -> None:
        if self.moving():
            self.reply("error:8", now)
            return
        self.emit(f"[VER:{VERSION}:]", now)
        options = "VN" if self.world.line_numbers else "V"
        self.emit(f"[OPT:{options},{self.world.planner_blocks - 1},{self.world.rx_buffer}]", now)
        self.reply("ok", now)

    def modes(self, now: float) -> None:
        motion = "G91" if not self.absolute else "G90"
        units = "G20" if self.inches else "G21"
        outputs = self.world.outputs
        coolant = " ".join(word for word in ("M7", "M8") if outputs.get(word)) or "M9"  # report_gcode_modes
        feed = self.feed / (25.4 if self.inches else 1.0)
        self.emit(f"[GC:G0 {self.wcs} G17 {units} {motion} G94 M0 {self.spindle} {coolant} T0 F{feed:g} "
                  f"S{self.spindle_speed:g}]", now)
        self.reply("ok", now)

    def parameters(self, now: float) -> None:
        for name in ("G54", "G55", "G56", "G57", "G58", "G59", "G28", "G30", "G92"):
            self.emit(f"[{name}:0.000,0.000,0.000]", now)
        self.emit("[TLO:0.000]", now)
        self.emit("[PRB:0.000,0.000,0.000:0]", now)
        self.reply("ok", now)

    def dump_settings(self, now: float) -> None:
        if self.moving():
            self.reply("error:8", now)
            return
        for key, value in self.settings.items():
            self.emit(f"${key}={value}", now)
        self.reply("ok", now)

    def set_setting(self, text: str, now: float) -> None:
        key, value = text[1:].split("=", 1)
        if int(key) not in self.settings:
            self.reply("error:3", now)
            return
        if self.moving():
            self.reply("error:8", now)
            return
        try:
            number = float(value)
        except ValueError:
            self.reply("error:2", now)
            return
        if number < 0:
            self.reply("error:4", now)
            return
        self.settings[int(key)] = value
        self.reply("ok", now)

    def toggle_check(self, now: float) -> None:
        """``$C``: enter check mode; leaving it resets grbl (message, ok, then the banner)."""
        if self.check_mode:
            self.emit("[MSG:Disabled]", now)
            self.reply("ok", now)
            self.soft_reset(now)
            return
        if self.alarm or self.moving():
            self.reply("error:8", now)
            return
        self.check_mode = True
        self.emit("[MSG:Enabled]", now)
        self.reply("ok", now)

    def jog(self, line: str, now: float) -> None:
        """``$J=G91 X10 F500``: one jog block; G-code is locked (error:9) while it moves."""
        if self.alarm or (self.moving() and not self.jogging):
            self.reply("error:8", now)
            return
        head, params = split_words(line)
        words = dict(params)
        if head not in ("G90", "G91", "G20", "G21", "G53") and head[:1] in "XYZ":
            words[head[0]] = float(head[1:])
        if "F" not in words or not any(a in words for a in "XYZ"):
            self.reply("error:16", now)
            return
        absolute = self.absolute
        self.absolute = head != "G91" and absolute
        target = self.target_of(words)
        self.absolute = absolute
        self.jogging = True
        self.current = self.jog_motion(target, words["F"], now)
        self.waiting = None
        self._step(now)

    def jog_motion(self, target: list[float], feed: float, now: float
                   ) -> Generator[Wait, None, None]:
        yield from self.plan_move(target, feed, now)
        self.reply("ok", now)

    def home(self, now: float) -> None:
        if self.settings[22] != "1":
            self.reply("error:5", now)  # homing not enabled
            return
        if self.moving():
            self.reply("error:8", now)
            return
        self.homing_until = now
        self.current = self.homing_cycle(now)
        self.waiting = None
        self._step(now)

    def homing_cycle(self, now: float) -> Generator[Wait, None, None]:
        yield from self.dwell(HOMING_S, now)
        self.homing_until = None
        if self.world.homing_fails:
            # limits_go_home: mc_reset + ALARM:9; $H still answers ok, then grbl resets
            self.emit("ALARM:9", now)
            self.alarm = True
            self.reply("ok", now)
            self.cold_start()
            self.banner(now)
            return
        self.position = [0.0, 0.0, 0.0]
        self.homed, self.alarm = True, False
        self.reply("ok", now)
