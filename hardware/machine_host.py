"""The state and operations that ``hardware.machine.Machine``'s parts share, declared once.

``Machine`` is assembled from parts kept in their own modules (``machine_grbl``,
``machine_outputs``, ``machine_probe``, ``machine_resume``).  Each part's methods take
``self: SerialHost``: they read and write only what this protocol declares, mypy checks
every such access against it, and every call on a ``Machine`` checks that ``Machine``
provides all of it (``Machine.__init__`` sets every attribute).
"""

from __future__ import annotations

import threading
from collections.abc import Iterable
from typing import Any, Protocol

from .controller_state import ControllerState
from .dialects import Dialect
from .events import ProbeReport
from .link import CommandResult, Link
from .machine_types import Identity, MachineProfile, _Interrupted
from .resume import ResumeLocation

__all__ = ["SerialHost"]


class SerialHost(Protocol):
    """What the parts of ``hardware.machine.Machine`` use of it (see the module docstring)."""

    # configuration (set by the constructor)
    url: str
    rules: Dialect
    dialect: str
    profile: MachineProfile
    timeout_s: float  # one command's answer, s (motion waits ten times this)
    boot_wait_s: float
    boot_quiet_s: float
    # the connection and what it learned
    link: Link | None
    identity: Identity | None
    planner_blocks: int  # Marlin BLOCK_BUFFER_SIZE; grbl: from [OPT:..]
    outputs: dict[str, Any] | None  # the last safe_off: when, whether sent, why not
    _connected_at: float | None  # time.monotonic() of the last connect
    # the one-operation-at-a-time rule (hardware.machine_state)
    _state: str
    _hold: threading.Lock
    # the program: progress, interruption and resume evidence
    progress: tuple[int, int] | None
    _interrupted: _Interrupted | None
    last_preamble: list[str]
    rejected_lines: list[int]
    last_resume: ResumeLocation | None
    _resume_commands: list[str] | None  # the interrupted program's commands (for locate_resume)
    _stream_started: float | None  # time.monotonic() when the last stream started
    _stream_origin: tuple[float, float, float] | None  # where the tool stood still before it, mm

    @property
    def state(self) -> str: ...

    @property
    def live_link(self) -> Link: ...

    @property
    def controller(self) -> ControllerState | None: ...

    @property
    def held_moves(self) -> int: ...

    def _claim(self, state: str) -> None: ...

    def _release(self, state: str = "idle") -> None: ...

    def _claim_motion(self, state: str, what: str, *, check: bool = True) -> None: ...

    def _run(self, commands: Iterable[str]) -> list[CommandResult]: ...

    def _wait_motion(self) -> str: ...

    def _position(self) -> tuple[float, float, float]: ...

    def _send_safe_off(self, when: str, timeout_s: float | None = None) -> bool: ...

    def resume_line(self) -> int: ...

    def _require_grbl_link(self) -> Link: ...

    def _wait_not_jogging(self) -> None: ...

    def _precise_position(self) -> ProbeReport: ...

    def _recover_toward(self, back: str) -> None: ...

    def _recover_after_probe(self, z_start: float) -> None: ...

    def _locate_by_position(self, bound: int, acked: int, sent: int, total: int) -> ResumeLocation: ...

    def _locate_by_report(self, fallback: ResumeLocation, report: Any, sent: int, total: int) -> ResumeLocation: ...

    def _with_repeats(self, found: ResumeLocation, sent: int) -> ResumeLocation: ...
