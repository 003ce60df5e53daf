"""Process outputs of the serial machine: :class:`OutputGuard`, built with the machine's
``SerialCommands``.

``connect`` (after identifying), a ``disconnect`` of an idle machine on a healthy link, and
every ``stream`` before its first command send the profile's ``safe_off`` (``dispense_off``
+ ``outputs_off``): a program starts with every output off unless it turns one on.  A
controller that kept running through a lost link gets it queued after what it had accepted
(the resume helper settles where the program stands first); a grbl locked in Alarm gets
none (it refuses G-code; its reset switched spindle and coolant off).  ``emergency_stop``
cannot send anything after the stop: what the firmware's own stop leaves on is
``Dialect.estop_keeps`` (Marlin's ``kill()`` keeps fan and ``M42`` outputs until the board
resets, i.e. the reconnect).  ``last`` (``status()["outputs"]``) says when ``safe_off`` was
last sent, or why not."""

from __future__ import annotations

from typing import Any

from .errors import FirmwareError
from .machine_host import SerialCommands

__all__ = ["DISCONNECT_SAFE_OFF_S", "OutputGuard"]

DISCONNECT_SAFE_OFF_S = 5.0  # longest a disconnect waits for its safe_off to be answered


class OutputGuard:
    """Sends ``safe_off`` and keeps what became of it (see the module docstring)."""

    def __init__(self, commands: SerialCommands) -> None:
        self.commands = commands
        self.last: dict[str, Any] | None = None  # the last safe_off: when, whether sent, why not

    def send_safe_off(self, when: str, timeout_s: float | None = None) -> bool:
        """Send the profile's ``safe_off`` (``when``: connect, disconnect, program) and note
        it in ``last`` (for ``status()``); False when the controller refuses G-code in
        its current state and the commands were not sent.

        grbl refuses every G-code line in Alarm with ``error:9`` (protocol.c,
        ``protocol_main_loop``: "Everything else is gcode. Block if in alarm or jog mode."
        -> ``STATUS_SYSTEM_GC_LOCK``); it is only in Alarm after a reset, and every reset
        runs ``mc_reset()`` ("Kill spindle and coolant": ``spindle_stop(); coolant_stop();``,
        motion_control.c) and re-initialises with ``spindle_init(); coolant_init();``
        (main.c): its outputs are off already.  A command the firmware does not have
        (grbl ``error:20``, ``Dialect.unknown_error``: e.g. a Marlin fan command in a grbl
        profile) switches no output of it: noted in ``last["why"]``, the others still go."""
        c = self.commands
        known = c.controller
        if known is not None and known.locks_motion and c.rules.lock_error is not None:
            self.last = {"safe_off": when, "sent": False,
                         "why": f"the controller is in {known.name}: its reset switched its outputs off"}
            return False
        wait = c.timeout_s * 10 if timeout_s is None else timeout_s
        unknown: list[str] = []
        for command in c.profile.safe_off:
            try:
                c.send(command, wait)
            except FirmwareError as exc:
                if exc.code is not None and exc.code == c.rules.unknown_error:
                    unknown.append(command)  # no such output on this firmware: it cannot be on
                    continue
                if exc.code is None or exc.code != c.rules.lock_error:
                    raise
                self.last = {"safe_off": when, "sent": False,
                             "why": "the controller refused G-code (locked): its reset switched its outputs off"}
                return False
        self.last = {"safe_off": when, "sent": True, "why": None if not unknown else (
            f"the controller does not know {', '.join(unknown)} (error:{c.rules.unknown_error}): "
            "the profile names an output this firmware does not have")}
        return True

    def note_estop(self) -> None:
        """After an emergency stop nothing more can be sent: note what the firmware's own
        stop leaves on (``Dialect.estop_keeps``) until the reconnect resets it."""
        rules, profile = self.commands.rules, self.commands.profile
        kept = [k for k in (profile.dispense_on, *profile.safe_off) if rules.keeps_through_estop(k)]
        words = ", ".join(dict.fromkeys(k.split()[0] for k in kept))
        self.last = {"safe_off": "emergency stop", "sent": False, "why": (
            f"the firmware's stop leaves {words} outputs as they were until the controller resets: connect again"
            if kept else "the controller's emergency stop switched its outputs off")}
