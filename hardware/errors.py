"""Exception family of the hardware package (independent of ``app``).

Every error carries a human message and, where it helps, the offending ``field`` and
``value`` (like ``app.domain.errors``), so the service can translate them without parsing text:

=====================  =========================================================  =======
class                  meaning                                                    HTTP-ish
=====================  =========================================================  =======
HardwareError          base class                                                 500
InvalidConfig          bad URL / options / dialect / profile (caller's mistake)   422
LinkError              port unreachable, disconnect, timeout with no answer       503
FirmwareReset          the controller restarted (banner seen) mid-conversation    503
ProtocolError          the firmware's replies cannot be reconciled                502
FirmwareError          ``error:N`` / ``Error:...`` / ``ALARM:N`` / ``!!`` halt      502
CommandRejected        a FirmwareError: the firmware refused the command itself   422
                       (unsupported, malformed) and stays ready
ProbeFailed            the probe reached its lower limit without a trigger        422
MachineBusy            a program or command already owns the machine              409
MachineStateError      the request does not fit the machine's state               409
=====================  =========================================================  =======
"""

from __future__ import annotations

from typing import Any


class HardwareError(Exception):
    """Base of all hardware errors; ``status`` hints at the HTTP status for the service."""

    status: int = 500

    def __init__(self, message: str, *, field: str | None = None, value: Any = None) -> None:
        super().__init__(message)
        self.message = message
        self.field = field
        self.value = value


class InvalidConfig(HardwareError, ValueError):
    """A port URL, URL option, dialect, window mode or profile value is unusable."""

    status = 422


class LinkError(HardwareError):
    """The transport failed: port unreachable, device disconnected, or no answer in time.

    ``last_line`` is, when known, the line number of the last command the host knows
    the firmware acknowledged (used for resume)."""

    status = 503

    def __init__(self, message: str, *, field: str | None = None, value: Any = None,
                 last_line: int | None = None) -> None:
        super().__init__(message, field=field, value=value)
        self.last_line = last_line
        self.resume_line: int | None = None  # a failed stream's lower bound of where it resumes


class FirmwareReset(LinkError):
    """The controller printed its start banner while commands were outstanding."""


class ProtocolError(HardwareError):
    """Replies that cannot be reconciled with what was sent (e.g. resend of a line no
    longer in the history, grbl ``ok`` lost with no way to tell if the line ran)."""

    status = 502


class FirmwareError(HardwareError):
    """The firmware rejected a command or halted (``error:N``, ``Error:``, ``ALARM:N``,
    ``!!``).  ``code`` is the numeric code when the dialect has one; ``command`` the
    command it answered."""

    status = 502

    def __init__(self, message: str, *, code: int | None = None, command: str | None = None,
                 field: str | None = None, value: Any = None,
                 reply_lines: tuple[str, ...] = ()) -> None:
        super().__init__(message, field=field, value=value)
        self.code = code
        self.command = command
        self.reply_lines = reply_lines  # what the controller answered (ALARM:9, ok ...)
        self.line_index: int | None = None  # stream(): index of the rejected command


class CommandRejected(FirmwareError):
    """The firmware refused one command for what it says (unsupported, malformed: a Marlin
    ``Error:`` or grbl ``error:N`` about the command, not a halt, an alarm or a damaged
    line) and is ready for the next: the sender's mistake, not the machine's."""

    status = 422


class ProbeFailed(HardwareError):
    """The probe found no surface.  ``reason``: ``no_contact`` (it travelled to its lower
    limit without triggering) or ``triggered_before_motion`` (grbl ``ALARM:4``: the probe
    was already triggered, so nothing was measured — check the probe and its wiring)."""

    status = 422

    def __init__(self, message: str, *, x: float | None = None, y: float | None = None,
                 field: str | None = None, value: Any = None,
                 reason: str = "no_contact") -> None:
        super().__init__(message, field=field, value=value)
        self.x = x
        self.y = y
        self.reason = reason


class MachineBusy(HardwareError):
    """Another program or blocking command already owns the machine."""

    status = 409


class MachineStateError(HardwareError):
    """The request does not fit the machine's current state (e.g. stop while idle)."""

    status = 409


class ControllerLocked(MachineStateError):
    """The firmware itself refuses motion in its current state (grbl Alarm, Hold, Door,
    Check): the message names the state, why, and how an operator clears it."""
