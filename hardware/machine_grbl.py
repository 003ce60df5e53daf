"""grbl's own operations on the serial machine: :class:`GrblControl` waits for the boot
banner, reads the build info (``[OPT:...]``: planner blocks, RX buffer), the controller's own
state (Idle, Run, Hold, Jog, Alarm, Check, Home), unlocks, sends feed hold / cycle start,
jogs and says whether homing is enabled.  Built with the machine's ``SerialCommands``."""

from __future__ import annotations

import time

from .errors import MachineStateError
from .events import Feedback, ReplyEvent, StartBanner
from .link import Link
from .machine_host import SerialCommands
from .machine_state import connected

__all__ = ["GrblControl"]

MARLIN_PLANNER_BLOCKS = 16  # Marlin's BLOCK_BUFFER_SIZE; grbl says its own in [OPT:..] (15)


class GrblControl:
    """grbl's settings and real-time operations (see the module docstring)."""

    def __init__(self, commands: SerialCommands, *, boot_wait_s: float, boot_quiet_s: float) -> None:
        self.commands = commands
        self.boot_wait_s = boot_wait_s  # longest wait for the boot banner, s
        self.boot_quiet_s = boot_quiet_s  # silence that ends the boot chatter, s
        self.planner_blocks = MARLIN_PLANNER_BLOCKS

    @property
    def held_moves(self) -> int:
        """Acknowledged moves the controller may hold unmoved: its planner's blocks plus what
        its stepper holds after the planner released them (``Dialect.stepper_queue``: grbl's
        step segments, each possibly the end of another short block)."""
        return self.planner_blocks + self.commands.rules.stepper_queue

    def await_boot(self) -> list[ReplyEvent]:
        """Opening the port resets an Arduino: its bootloader swallows whatever is sent for
        up to ~2 s, then grbl prints (on a fresh EEPROM ``error:7`` and its settings, then)
        the banner.  Wait for the banner, up to ``boot_wait_s``, then for ``boot_quiet_s``
        of silence; a board that did not reset (no banner) must answer a status query."""
        link = self.commands.link
        deadline = time.monotonic() + self.boot_wait_s
        banner_at = None
        seen = 0
        quiet_since = time.monotonic()
        while time.monotonic() < deadline:
            time.sleep(min(0.02, max(self.boot_quiet_s / 2, 0.001)))
            events = list(link.unsolicited)
            if banner_at is None and any(isinstance(e, StartBanner) for e in events):
                banner_at = time.monotonic()
            if len(events) != seen:
                seen, quiet_since = len(events), time.monotonic()
            elif banner_at is not None and time.monotonic() - quiet_since > self.boot_quiet_s:
                break
        events = list(link.unsolicited)
        link.unsolicited.clear()
        # the controller's state (Alarm when it boots locked); LinkError if nothing answers
        link.query_status(timeout_s=2.0)
        return events

    def await_quiet(self) -> list[ReplyEvent]:
        """A controller without a boot banner (Marlin): what it says until ``boot_quiet_s``
        of silence, at most ``boot_wait_s``."""
        link = self.commands.link
        deadline = time.monotonic() + self.boot_wait_s
        seen = 0
        quiet_since = time.monotonic()
        while time.monotonic() < deadline:
            time.sleep(min(0.02, self.boot_quiet_s / 2))
            if len(link.unsolicited) != seen:
                seen = len(link.unsolicited)
                quiet_since = time.monotonic()
            elif time.monotonic() - quiet_since > self.boot_quiet_s:
                break
        events = list(link.unsolicited)
        link.unsolicited.clear()
        return events

    def apply_build_info(self, fields: dict[str, str]) -> None:
        """``[OPT:V,15,128]``: the planner's usable blocks and the RX buffer in bytes."""
        parts = fields.get("OPT", "").split(",")
        if len(parts) >= 3 and parts[1].isdigit() and parts[2].isdigit():
            self.planner_blocks = int(parts[1])
            self.commands.link.set_rx_buffer(int(parts[2]))

    @staticmethod
    def build_fields(events: tuple[ReplyEvent, ...]) -> dict[str, str]:
        """The build info grbl's ``$I`` printed (``OPT``)."""
        return {e.tag: e.value for e in events if isinstance(e, Feedback) and e.tag == "OPT"}

    def controller_state(self) -> str:
        """grbl's own state from a fresh status report (``Idle``, ``Run``, ``Hold:0``,
        ``Jog``, ``Alarm``, ``Check``, ``Home``...)."""
        return connected(self.commands.state.link).query_status().state

    def last_controller_state(self) -> str | None:
        """The firmware's own state as last learned (status reports, alarms, banners,
        unlock messages; no query), e.g. ``Idle``, ``Alarm``, ``Hold:0``; None when unknown."""
        known = self.commands.controller
        return known.state if known is not None else None

    def unlock(self) -> None:
        """``$X``: leave grbl's Alarm lock (the position may be wrong: home when you can).
        ``MachineStateError`` on a firmware without an alarm lock (Marlin)."""
        c = self.commands
        command = c.rules.unlock_command
        if command is None:
            raise MachineStateError(f"{c.rules.name} has no alarm lock to clear", field="dialect",
                                    value=c.rules.name)
        c.state.claim("busy")
        try:
            c.send(command, c.timeout_s)
            c.link.query_status()  # the state after the unlock, for status()
        finally:
            c.state.release()

    def feed_hold(self) -> None:
        """grbl ``!``: decelerate and hold planned motion (works from any thread)."""
        link = self._realtime_link()
        assert self.commands.rules.feed_hold is not None  # _realtime_link checked it
        link.realtime(self.commands.rules.feed_hold)

    def cycle_start(self) -> None:
        """grbl ``~``: resume after a feed hold."""
        link = self._realtime_link()
        assert self.commands.rules.cycle_start is not None  # _realtime_link checked it
        link.realtime(self.commands.rules.cycle_start)

    def _realtime_link(self) -> Link:
        rules = self.commands.rules
        link = connected(self.commands.state.link)
        if rules.feed_hold is None or rules.cycle_start is None:
            raise MachineStateError("feed hold and cycle start are grbl real-time commands",
                                    field="dialect", value=rules.name)
        return link

    def jog(self, x: float = 0.0, y: float = 0.0, z: float = 0.0,
            feed_mm_min: float | None = None) -> tuple[float, float, float]:
        """Relative ``$J=`` jog; returns the position once the jog has finished (G-code is
        locked with ``error:9`` while grbl jogs)."""
        c = self.commands
        feed = feed_mm_min or c.profile.travel_feed_mm_min
        words = "".join(f" {a}{v:.4f}" for a, v in zip("XYZ", (x, y, z)) if v)
        c.claim_motion("busy", "jog")
        try:
            c.send(f"$J=G91{words} F{feed:.1f}", c.timeout_s)
            c.wait_not_jogging()
            return c.position()
        finally:
            c.state.release()

    def can_home(self) -> bool:
        """grbl: homing cycle enabled (``$22=1``); Marlin: always."""
        c = self.commands
        if c.rules.homing_setting is None:
            return True
        c.state.claim("busy")
        try:
            result = c.send("$$", c.timeout_s)
        finally:
            c.state.release()
        return any(line.strip() == c.rules.homing_setting for line in result.reply_lines)
