"""The firmware's own state (grbl ``Idle``, ``Run``, ``Hold:0``, ``Jog``, ``Alarm``,
``Door:1``, ``Check``, ``Home``, ``Sleep``) as the host learns it from what the firmware
says, and how an operator clears each state that refuses motion.  Pure: no I/O.

    state = next_controller_state(None, Alarm("ALARM:5", 5, "Probe fail"), now=1.0, lock_error=9)
    state.name, state.locks_motion, state.clear   # "Alarm", True, "check the machine, then unlock ($X ..."
"""

from __future__ import annotations

from dataclasses import dataclass

from .events import Alarm, FirmwareErrorEvent, Message, ReplyEvent, StartBanner, StatusReport

#: how an operator clears each controller state that refuses motion (grbl names)
CLEARING = {
    "Alarm": "check the machine, then unlock ($X; its position may be wrong: home when you can) or home ($H)",
    "Hold": "resume with cycle start (~), or stop",
    "Door": "close the safety door, then resume with cycle start (~)",
    "Check": "leave check mode ($C; grbl resets)",
    "Sleep": "reset the controller (reconnect)",
}


@dataclass(frozen=True)
class ControllerState:
    """The firmware's own state as the host last learned it (grbl: ``Idle``, ``Run``,
    ``Hold:0``, ``Jog``, ``Alarm``, ``Door:1``, ``Check``, ``Home``, ``Sleep``), ``reason``
    (the alarm that caused it, e.g. ``ALARM:5 Probe fail...``), ``since`` (host time)."""

    state: str
    reason: str | None = None
    since: float = 0.0

    @property
    def name(self) -> str:
        """The state without its sub-state (``Hold:0`` -> ``Hold``)."""
        return self.state.split(":")[0]

    @property
    def locks_motion(self) -> bool:
        """True when the firmware refuses or holds every motion until an operator clears it."""
        return self.name in CLEARING

    @property
    def clear(self) -> str | None:
        """How an operator clears it (None when nothing needs clearing)."""
        return CLEARING.get(self.name)

    def as_dict(self) -> dict[str, str | None]:
        return {"state": self.name, "detail": self.state, "reason": self.reason, "clear": self.clear}


def next_controller_state(known: ControllerState | None, event: ReplyEvent, now: float,
                          lock_error: int | None) -> ControllerState | None:
    """The state after ``event`` (``known`` before it): a status report names it; an alarm
    locks it (with its reason) until the firmware says it unlocked or a status says
    otherwise; a start banner is Idle unless grbl adds that it boots locked; a G-code
    refused with ``lock_error`` (grbl ``error:9``) proves a lock the host may have missed."""
    in_alarm = known is not None and known.name == "Alarm"
    if isinstance(event, StatusReport):
        keep = known.reason if known is not None and in_alarm and event.state.startswith("Alarm") else None
        return ControllerState(event.state, keep, now)
    if isinstance(event, Alarm):
        return ControllerState("Alarm", f"ALARM:{event.code} {event.message}".strip(), now)
    if isinstance(event, StartBanner):
        return ControllerState("Idle", None, now)
    if isinstance(event, Message):
        text = event.text.strip()
        if "'$X' to unlock" in text or "$X to unlock" in text:
            reason = known.reason if known is not None and in_alarm and known.reason else \
                "the controller started locked (homing required, or an alarm before its reset)"
            return ControllerState("Alarm", reason, now)
        if text.startswith("Caution: Unlocked"):
            return ControllerState("Idle", None, now)
        return known
    if isinstance(event, FirmwareErrorEvent) and lock_error is not None and event.code == lock_error \
            and (known is None or known.name not in ("Alarm", "Jog")):
        return ControllerState("Alarm", f"error:{event.code} {event.message}".strip(), now)
    return known
