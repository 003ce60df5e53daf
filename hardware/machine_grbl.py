"""grbl-specific operations of ``hardware.machine.Machine`` (a mixin): waiting for the boot
banner, build info (``[OPT:...]``), the controller's own state (Idle, Run, Hold, Jog, Alarm,
Check, Home), unlock, feed hold / cycle start, jogging and homing availability."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from .controller_state import ControllerState
from .errors import ControllerLocked, FirmwareError, LinkError, MachineStateError
from .events import Feedback, ReplyEvent, StartBanner

if TYPE_CHECKING:
    from .link import Link
    from .machine_host import SerialHost

JOG_POLL_S = 0.05


class GrblOperations:
    """Part of ``Machine`` (what it uses of it: ``hardware.machine_host.SerialHost``); every
    method expects a connected grbl machine."""

    planner_blocks: int  # set from [OPT:..]

    def _await_boot(self: SerialHost) -> list[ReplyEvent]:
        """Opening the port resets an Arduino: its bootloader swallows whatever is sent for
        up to ~2 s, then grbl prints (on a fresh EEPROM ``error:7`` and its settings, then)
        the banner.  Wait for the banner, up to ``boot_wait_s``, then for ``boot_quiet_s``
        of silence; a board that did not reset (no banner) must answer a status query."""
        link = self.live_link
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

    def _apply_build_info(self: SerialHost, fields: dict[str, str]) -> None:
        """``[OPT:V,15,128]``: the planner's usable blocks and the RX buffer in bytes."""
        parts = fields.get("OPT", "").split(",")
        if len(parts) >= 3 and parts[1].isdigit() and parts[2].isdigit():
            self.planner_blocks = int(parts[1])
            self.live_link.set_rx_buffer(int(parts[2]))

    @staticmethod
    def _build_fields(events: tuple[ReplyEvent, ...]) -> dict[str, str]:
        return {e.tag: e.value for e in events if isinstance(e, Feedback) and e.tag == "OPT"}

    def controller_state(self: SerialHost) -> str:
        """grbl's own state from a fresh status report (``Idle``, ``Run``, ``Hold:0``,
        ``Jog``, ``Alarm``, ``Check``, ``Home``...)."""
        if self.link is None:
            raise MachineStateError("machine is not connected", field="state", value="disconnected")
        return self.link.query_status().state

    def last_controller_state(self: SerialHost) -> str | None:
        """The firmware's own state as last learned (status reports, alarms, banners,
        unlock messages; no query), e.g. ``Idle``, ``Alarm``, ``Hold:0``; None when unknown."""
        known = self.controller
        return known.state if known is not None else None

    @property
    def controller(self: SerialHost) -> ControllerState | None:
        """The firmware's own state with its reason (``hardware.session_types``), or None."""
        return self.link.session.controller if self.link is not None else None

    def _refuse_locked(self: SerialHost, what: str) -> None:
        """``ControllerLocked`` naming the state, why and how to clear it, when the firmware
        refuses or holds motion now (grbl Alarm, Hold, Door, Check)."""
        known = self.controller
        if known is not None and known.locks_motion and self.rules.position_by_status:
            self.live_link.query_status()  # never refuse on a stale state: ask the firmware now
            known = self.controller
        if known is not None and known.locks_motion:
            raise ControllerLocked(GrblOperations._locked_message(known, what), field="controller", value=known.state)

    @staticmethod
    def _locked_message(known: ControllerState, what: str) -> str:
        why = f" ({known.reason})" if known.reason else ""
        return f"the controller is in {known.name}{why}: cannot {what}; {known.clear}"

    def _locked_reply(self: SerialHost, exc: FirmwareError, what: str) -> FirmwareError | ControllerLocked:
        """A command the firmware refused with its lock error (grbl ``error:9``) as the
        ``ControllerLocked`` it means; any other rejection unchanged."""
        code = self.rules.lock_error
        if code is None or exc.code != code:
            return exc
        known = self.controller or ControllerState("Alarm", str(exc))
        if not known.locks_motion:  # jogging: G-code waits for the jog to end
            return exc
        return ControllerLocked(GrblOperations._locked_message(known, what), field="controller", value=known.state)

    def unlock(self: SerialHost) -> None:
        """``$X``: leave grbl's Alarm lock (the position may be wrong: home when you can).
        ``MachineStateError`` on a firmware without an alarm lock (Marlin)."""
        command = self.rules.unlock_command
        if command is None:
            raise MachineStateError(f"{self.dialect} has no alarm lock to clear", field="dialect",
                                    value=self.dialect)
        self._claim("busy")
        try:
            self.live_link.send(command, self.timeout_s)
            self.live_link.query_status()  # the state after the unlock, for status()
        finally:
            self._release()

    def feed_hold(self: SerialHost) -> None:
        """grbl ``!``: decelerate and hold planned motion (works from any thread)."""
        link = self._require_grbl_link()
        assert self.rules.feed_hold is not None  # _require_grbl_link checked it
        link.realtime(self.rules.feed_hold)

    def cycle_start(self: SerialHost) -> None:
        """grbl ``~``: resume after a feed hold."""
        link = self._require_grbl_link()
        assert self.rules.cycle_start is not None  # _require_grbl_link checked it
        link.realtime(self.rules.cycle_start)

    def _require_grbl_link(self: SerialHost) -> Link:
        if self.link is None:
            raise MachineStateError("machine is not connected", field="state", value="disconnected")
        if self.rules.feed_hold is None or self.rules.cycle_start is None:
            raise MachineStateError("feed hold and cycle start are grbl real-time commands",
                                    field="dialect", value=self.dialect)
        return self.link

    def jog(self: SerialHost, x: float = 0.0, y: float = 0.0, z: float = 0.0,
            feed_mm_min: float | None = None) -> tuple[float, float, float]:
        """Relative ``$J=`` jog; returns the position once the jog has finished (G-code is
        locked with ``error:9`` while grbl jogs)."""
        feed = feed_mm_min or self.profile.travel_feed_mm_min
        words = "".join(f" {a}{v:.4f}" for a, v in zip("XYZ", (x, y, z)) if v)
        self._claim_motion("busy", "jog")
        try:
            self.live_link.send(f"$J=G91{words} F{feed:.1f}", self.timeout_s)
            self._wait_not_jogging()
            return self._position()
        finally:
            self._release()

    def _wait_not_jogging(self: SerialHost) -> None:
        """Poll grbl's status until it no longer jogs."""
        deadline = time.monotonic() + self.timeout_s * 10
        while self.live_link.query_status().state == "Jog":
            if time.monotonic() > deadline:
                raise LinkError("jog did not finish", field="timeout_s")
            time.sleep(JOG_POLL_S)

    def can_home(self: SerialHost) -> bool:
        """grbl: homing cycle enabled (``$22=1``); Marlin: always."""
        if self.rules.homing_setting is None:
            return True
        self._claim("busy")
        try:
            result = self.live_link.send("$$", self.timeout_s)
        finally:
            self._release()
        return any(line.strip() == self.rules.homing_setting for line in result.reply_lines)
