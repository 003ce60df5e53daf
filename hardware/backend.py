"""What every machine backend offers the service: the :class:`Machine` protocol.

Two backends implement it, checked by mypy (``tests/hardware/test_backend.py`` asserts
both at runtime too):

* :class:`hardware.machine.Machine` - Marlin and grbl over a serial link (``/dev/...``,
  ``socket://``, ``mock://``);
* :class:`hardware.linuxcnc.LinuxCNCMachine` - LinuxCNC over linuxcncrsh (``linuxcnc://``).

Blocking operations hold the machine (``MachineBusy`` for a second caller); ``pause``,
``resume``, ``cancel``, ``stop``, ``emergency_stop`` and ``status`` work from any thread.
Positions are (x, y, z) mm in the machine's work coordinates; feeds mm/min.  What only one
backend has (grbl's ``unlock``, the serial link's ``locate_resume``) is reached by narrowing
to that backend's class.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any, Protocol, runtime_checkable

from .console_log import ConsoleLog
from .machine_state import InterruptedProgram
from .machine_types import Identity, MachineProfile, ProbeResult, StreamReport
from .program_clock import ProgramClock

__all__ = ["Machine"]


@runtime_checkable
class Machine(Protocol):
    """A machine the service drives (see the module docstring)."""

    @property
    def url(self) -> str:
        """The port it was built for (``hardware.port_url.PortUrl`` reads it)."""

    @property
    def dialect(self) -> str:
        """``marlin``, ``grbl`` or ``linuxcnc``."""

    @property
    def profile(self) -> MachineProfile: ...

    @property
    def link(self) -> object | None:
        """The open link (None while disconnected)."""

    @property
    def identity(self) -> Identity | None: ...

    @property
    def progress(self) -> tuple[int, int] | None:
        """(executed, total) commands of the running program."""

    @property
    def homed(self) -> bool: ...

    @property
    def last_preamble(self) -> list[str]:
        """The modal replay sent before the last resumed program's first command."""

    @property
    def console(self) -> ConsoleLog: ...

    @property
    def clock(self) -> ProgramClock: ...

    @property
    def state(self) -> str:
        """disconnected | idle | busy | printing | paused | error."""

    @property
    def link_lost(self) -> bool: ...

    @property
    def estopped(self) -> bool: ...

    @property
    def interrupted_program(self) -> InterruptedProgram | None:
        """What is known of the program a failure stopped, recorded when it was lost and
        kept in the machine state (``hardware.machine_state.InterruptedProgram``, one type for
        every backend); None when no program waits for a resume."""

    @property
    def acked_line_no(self) -> int | None: ...

    @property
    def home_command(self) -> str: ...

    def connect(self) -> Identity: ...

    def disconnect(self) -> None: ...

    def send(self, command: str) -> object:
        """A raw console command; the reply (its ``reply_lines`` when it has them)."""

    def home(self) -> tuple[float, float, float]: ...

    def move(self, x: float | None = None, y: float | None = None, z: float | None = None,
             feed_mm_min: float | None = None) -> tuple[float, float, float]: ...

    def position(self) -> tuple[float, float, float]: ...

    def probe(self, x: float, y: float, z_start: float | None = None, z_min: float | None = None,
              feed_mm_min: float | None = None) -> ProbeResult: ...

    def probe_toward(self, start: tuple[float, float, float], target: tuple[float, float, float],
                     feed_mm_min: float | None = None) -> ProbeResult: ...

    def select_tool(self, tool: int) -> None: ...

    def stream(self, lines: Iterable[str], on_progress: Callable[[int, int], None] | None = None,
               start_line: int = 0) -> StreamReport: ...

    def resume_line(self) -> int:
        """After reconnecting: the first command of the interrupted program not known to be
        executed (what its record tells, asking the controller where it must)."""

    def adopt_interrupted(self, total: int, acked_index: int, acked_line_no: int | None) -> None:
        """Before connecting in a new process: take over what an earlier one recorded
        (``InterruptedProgram.adopted``)."""

    def program_status(self) -> dict[str, Any] | None:
        """The program on this machine, running or interrupted
        (``hardware.machine_state.MachineState.program_status``); None when neither."""

    def pause(self) -> None: ...

    def resume(self) -> None: ...

    def cancel(self) -> None: ...

    def stop(self) -> None: ...

    def emergency_stop(self) -> None: ...

    def status(self) -> dict[str, Any]: ...
