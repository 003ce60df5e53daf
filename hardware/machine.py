"""A printer as one object: connect/identify, home, move, probe, stream programs with
pause/resume/cancel, emergency stop, and resume after a disconnect.

    machine = Machine("mock://bench", "marlin", MachineProfile(dispense_on="M106 S255"))
    identity = machine.connect()
    machine.home()
    point = machine.probe(10.0, 20.0)                 # ProbeResult(x, y, z) or ProbeFailed
    report = machine.stream(lines, on_progress=cb)    # cb(executed, total)
    ...
    except LinkError as exc:                          # USB dropped mid-program
        machine.connect()
        machine.stream(lines, start_line=machine.resume_line())

The service maps this 1:1: ``connect``/``disconnect``/``status()``/``pause``/``resume``/
``stop`` endpoints, ``probe_run`` calls ``probe`` per point, ``print`` calls ``stream``
from its single-worker queue; ``MachineBusy``/``MachineStateError`` become 409,
``InvalidConfig`` 422, ``LinkError``/``FirmwareError`` 502/503.

Indices count *commands* (normalised, non-empty lines: the same list ``commands_sha256``
hashes), so ``start_line=n`` skips the first n commands.

What "known executed" means (``resume_line``):

* A command is executed when the firmware acknowledged it as processed (``ok``; Marlin
  ``ok N<n>`` also covers every earlier line).
* Marlin, disconnected without a reset: the firmware keeps running what it accepted and
  keeps its line number.  On reconnect (no ``M110``) the machine sends ``N<next> M114``;
  the firmware accepts it or answers ``Resend: L+1`` — every line up to L was accepted and
  Marlin executes every accepted line, so lines <= L count as executed.
* Marlin after a reset (banner seen, or L went backwards), and grbl always (a disconnect
  resets an Arduino-based controller and flushes its buffer): ``ok`` means *planned*, so
  up to a planner's worth of acknowledged moves (grbl: 15, from ``[OPT:]``; Marlin: 16)
  may never have run.  The bound walks back that many planner blocks from the last
  acknowledged command, tightened by the last grbl status report (Idle: nothing planned;
  ``Bf:`` free blocks); a few moves may run twice, none is skipped.  The controller lost
  its position: home before continuing.
* While a program streams the controller reports where the tool really is, ten times a
  second (grbl ``?``, Marlin ``S000``; ``hardware.reports``): after a reset
  ``locate_resume()`` resumes from the last report instead of the planner bound.
* After a rejected line (``FirmwareError``, ``exc.line_index``) the controller still runs
  the lines it already held (grbl: up to a buffer's worth); ``stream`` waits for them and
  ``resume_line()`` is the index after them (``rejected_lines`` lists the rejected ones).

Process outputs (``hardware.machine_outputs``): ``connect``, a ``disconnect`` of an idle
machine on a healthy link and every ``stream`` before its first command send the profile's
``safe_off``: a program starts with every output off unless it turns one on.

``stream(start_line=n)`` then replays the modal state the skipped commands left (units,
coordinate system, motion mode, feed, the start point at clearance height, G90/G91, the
dispenser, turned back on only where the program had it on;
``hardware.resume.modal_preamble``; ``last_preamble`` shows what preceded command n).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from typing import Any

from .console_log import ConsoleLog
from .controller_state import ControllerState
from .dialects import DEFAULT_DIALECT
from .dialects import dialect as dialect_rules
from .errors import FirmwareError, HardwareError, MachineStateError
from .events import Capability, FirmwareInfo, ReplyEvent, StartBanner
from .link import CommandResult, Link
from .machine_args import straight_move
from .machine_grbl import GrblControl
from .machine_host import SerialCommands
from .machine_outputs import DISCONNECT_SAFE_OFF_S, OutputGuard
from .machine_probe import Prober
from .machine_resume import ResumeHelper
from .machine_state import MachineState, StateReadout, base_status
from .machine_stream import ProgramStream
from .machine_types import STATES, Identity, MachineProfile, ProbeResult, StreamReport
from .program_clock import ProgramClock
from .resume import ResumeLocation

__all__ = ["STATES", "Identity", "Machine", "MachineProfile", "ProbeResult", "StreamReport"]


class Machine(StateReadout[Link]):
    """See the module docstring.  Blocking operations hold the machine (``MachineBusy``
    for a second caller); pause/resume/cancel/stop/status work from any thread.

    Composed of collaborators, each built with what it uses: ``machine_state`` (link, state,
    claim, cancel and emergency-stop flags, progress, the interrupted program's record:
    ``hardware.machine_state``, read through ``StateReadout``), ``commands`` (commands and
    positions over the link, the controller's lock: ``hardware.machine_host``), ``grbl``
    (boot, build info, unlock, jog: ``hardware.machine_grbl``), ``output_guard``
    (``safe_off``: ``hardware.machine_outputs``), ``prober`` (``hardware.machine_probe``),
    ``resumer`` (resuming the interrupted program: ``hardware.machine_resume``) and
    ``programs`` (streaming: ``hardware.machine_stream``).
    Its public calls delegate to them."""

    def __init__(self, url: str, dialect: str = DEFAULT_DIALECT, profile: MachineProfile | None = None,
                 *, baudrate: int = 115200, window: str = "windowed", timeout_s: float = 30.0,
                 boot_wait_s: float = 2.0, boot_quiet_s: float = 0.1, poke_s: float = 2.5
                 ) -> None:
        self.url = url
        self.rules = dialect_rules(dialect)  # what this firmware does (hardware.dialects)
        self.dialect = self.rules.name
        self.profile = profile or MachineProfile(*self.rules.dispense)
        self.baudrate = baudrate
        self.window = window
        self.timeout_s = timeout_s
        self.poke_s = poke_s
        self.identity: Identity | None = None
        self.console = ConsoleLog()  # every line sent and received, across reconnects
        self.homed = False  # homed since this connection (the host's record: Marlin and grbl do not report it)
        self.clock = ProgramClock()  # elapsed time and time left of the running program
        super().__init__(MachineState(error_when_lost=("idle", "busy")))
        self.commands = SerialCommands(self.machine_state, self.rules, self.profile, timeout_s)
        self.grbl = GrblControl(self.commands, boot_wait_s=boot_wait_s, boot_quiet_s=boot_quiet_s)
        self.output_guard = OutputGuard(self.commands)
        self.prober = Prober(self.commands)
        self.resumer = ResumeHelper(self.commands, self.grbl, self.output_guard)
        self.programs = ProgramStream(self.commands, self.resumer, self.clock)

    # ------------------------------------------------------------------ state
    @property
    def live_link(self) -> Link:
        """The open link; ``MachineStateError`` while disconnected."""
        return self.machine_state.live_link

    @property
    def acked_line_no(self) -> int | None:
        """The firmware's line number of the last acknowledged command."""
        return self.programs.acked_line_no

    @property
    def last_preamble(self) -> list[str]:
        """What the last stream sent before its first command."""
        return self.resumer.last_preamble

    @property
    def rejected_lines(self) -> list[int]:
        """Command indices the controller rejected in the last stream."""
        return self.resumer.rejected_lines

    @property
    def last_resume(self) -> ResumeLocation | None:
        """What ``locate_resume`` found last (None: nothing yet, or forgotten)."""
        return self.resumer.last_resume

    @last_resume.setter
    def last_resume(self, found: ResumeLocation | None) -> None:
        self.resumer.last_resume = found

    @property
    def outputs(self) -> dict[str, Any] | None:
        """The last ``safe_off``: when, whether sent, why not."""
        return self.output_guard.last

    @property
    def planner_blocks(self) -> int:
        """Marlin's BLOCK_BUFFER_SIZE (16); grbl's from ``[OPT:..]`` (15)."""
        return self.grbl.planner_blocks

    @property
    def held_moves(self) -> int:
        """Acknowledged moves the controller may hold unmoved (``GrblControl.held_moves``)."""
        return self.grbl.held_moves

    @property
    def controller(self) -> ControllerState | None:
        """The firmware's own state with its reason (``hardware.session_types``), or None."""
        return self.commands.controller

    @property
    def home_command(self) -> str:
        """What ``home`` sends: the profile's command, else the dialect's (G28 / $H)."""
        return self.profile.home_command or self.rules.home_command

    # ------------------------------------------------------------------ connection
    def connect(self) -> Identity:
        """Open the port, wait for the boot chatter, number lines (Marlin ``M110 N0``,
        unless an interrupted program waits for ``resume_line``) and identify."""
        if self.link is not None:
            self.disconnect()
        self.resumer.connected_at = time.monotonic()  # a controller that kept running stopped by now at the latest
        link = self.machine_state.link = Link.open(
            self.url, baudrate=self.baudrate, dialect=self.dialect, timeout_s=self.timeout_s, window=self.window,
            poke_s=self.poke_s, console=self.console)
        self.machine_state.connecting()
        self.homed = False
        try:
            banner = self.grbl.await_boot() if self.rules.boot_banner else self.grbl.await_quiet()
            reset = any(isinstance(e, StartBanner) for e in banner)
            gap = self.machine_state.interrupted
            if gap is not None and reset:
                gap.reset = True
            if self.rules.line_numbers and (gap is None or gap.reset):
                link.reset_line_numbers(1)
            self.identity = self._identify(banner, reset)
            # a controller that kept running settles where its program stands, then every
            # output goes off (queued after what it accepted; hardware.machine_outputs)
            self.resumer.settle_on_connect(reset)
            self.output_guard.send_safe_off("connect")
        except HardwareError:
            self.machine_state.current = "error"
            raise
        self.machine_state.current = "idle"
        return self.identity

    def _identify(self, banner: list[ReplyEvent], reset: bool) -> Identity:
        link = self.live_link
        result = link.send(self.rules.identify_command, self.timeout_s)
        fields: dict[str, str] = {}
        caps: dict[str, bool] = {}
        for event in result.events:
            if isinstance(event, FirmwareInfo):
                fields.update(event.fields)
            elif isinstance(event, Capability):
                caps[event.name] = event.enabled
        fields.update(self.grbl.build_fields(result.events))
        if self.rules.build_info:
            self.grbl.apply_build_info(fields)
        elif self.rules.request_queued and caps.get("EMERGENCY_PARSER") and link.mode == "windowed" \
                and link.advanced_ok:
            # S000 answered with the steppers' position (REALTIME_REPORTING_COMMANDS): nothing
            # in M115 says so; its plain ok needs ADVANCED_OK to stay apart from the others
            caps["REALTIME_REPORTING_COMMANDS"] = link.probe_realtime_reports(min(1.0, self.timeout_s))
        version = fields.get("VER", "").split(":")[0]  # [VER:1.1h.20190830:user string]
        name = (fields.get("FIRMWARE_NAME") or ("grbl " + version)).strip()
        return Identity(self.dialect, name, fields, caps, tuple(e.raw for e in banner), reset)

    def disconnect(self) -> None:
        """Close the link (a running program fails with ``LinkError``).  An idle machine on a
        healthy link (not emergency-stopped) gets ``safe_off`` first (best effort, within
        ``DISCONNECT_SAFE_OFF_S``): nothing is left dispensing behind a closed port."""
        st = self.machine_state
        link = st.link
        if link is not None and link.healthy and not st.estopped and st.current == "idle" \
                and st.hold.acquire(blocking=False):
            try:
                self.output_guard.send_safe_off("disconnect", min(self.timeout_s, DISCONNECT_SAFE_OFF_S))
            except HardwareError:
                pass  # the port closes anyway; the next connect sends safe_off again
            finally:
                st.hold.release()
        st.link = None
        st.cancel_requested = True
        self.programs.open_gate()
        if link is not None:
            link.close()
        st.current = "disconnected"

    # ------------------------------------------------------------------ simple commands
    def send(self, command: str) -> CommandResult:
        """Raw console command (blocking; FirmwareError when rejected).  G-code while the
        controller refuses motion (grbl Alarm, Hold, Door, Check) is ``ControllerLocked``
        naming the state and how to clear it; ``$`` system commands always go through."""
        what = f"run {command.strip()[:40]!r}"
        self.commands.claim_motion("busy", what, check=not command.strip().startswith("$"))
        try:
            result = self.commands.send(command)
        except FirmwareError as exc:
            raise self.commands.locked_reply(exc, what) from exc
        finally:
            self.machine_state.release()
        if command.strip().upper() == self.home_command.strip().upper():
            self.homed = True  # the operator homed from the console
        return result

    def home(self) -> tuple[float, float, float]:
        """Home all axes; returns the position afterwards."""
        command = self.home_command
        self.machine_state.claim("busy")
        self.homed = False  # until this homing succeeds
        try:
            try:
                self.commands.send(command)
            except FirmwareError as exc:
                if self.rules.homing_disabled_error is not None and exc.code == self.rules.homing_disabled_error:
                    raise MachineStateError("homing is disabled on this controller ($22=0): "
                                            "unlock instead, or enable homing", field="home",
                                            value=command) from exc
                raise
            self.homed = True
            return self.commands.position()
        finally:
            self.machine_state.release()

    def move(self, x: float | None = None, y: float | None = None, z: float | None = None,
             feed_mm_min: float | None = None) -> tuple[float, float, float]:
        """Absolute straight move; returns once the motion is finished."""
        move = straight_move(self.profile, x, y, z, feed_mm_min)
        c = self.commands
        c.claim_motion("busy", "move")
        try:
            if self.rules.jog_locks_gcode:
                c.wait_not_jogging()  # G-code during a jog is error:9
            c.run(["G90", move, c.wait_motion])
            return c.position()
        finally:
            self.machine_state.release()

    def position(self) -> tuple[float, float, float]:
        """Current position: Marlin ``M114`` (planned), grbl status ``MPos``."""
        self.machine_state.claim("busy")
        try:
            return self.commands.position()
        finally:
            self.machine_state.release()

    # ------------------------------------------------------------------ grbl (hardware.machine_grbl)
    def controller_state(self) -> str:
        """grbl's own state from a fresh status report (``Idle``, ``Run``, ``Hold:0``...)."""
        return self.grbl.controller_state()

    def last_controller_state(self) -> str | None:
        """The firmware's own state as last learned (no query); None when unknown."""
        return self.grbl.last_controller_state()

    def unlock(self) -> None:
        """``$X``: leave grbl's Alarm lock; ``MachineStateError`` on Marlin."""
        self.grbl.unlock()

    def feed_hold(self) -> None:
        """grbl ``!``: decelerate and hold planned motion (works from any thread)."""
        self.grbl.feed_hold()

    def cycle_start(self) -> None:
        """grbl ``~``: resume after a feed hold."""
        self.grbl.cycle_start()

    def jog(self, x: float = 0.0, y: float = 0.0, z: float = 0.0,
            feed_mm_min: float | None = None) -> tuple[float, float, float]:
        """Relative ``$J=`` jog; returns the position once the jog has finished."""
        return self.grbl.jog(x, y, z, feed_mm_min)

    def can_home(self) -> bool:
        """grbl: homing cycle enabled (``$22=1``); Marlin: always."""
        return self.grbl.can_home()

    # ------------------------------------------------------------------ probing (hardware.machine_probe)
    def probe(self, x: float, y: float, z_start: float | None = None, z_min: float | None = None,
              feed_mm_min: float | None = None) -> ProbeResult:
        """Probe down at (x, y) (``Prober.probe``); ``ProbeFailed`` when nothing is hit."""
        return self.prober.probe(x, y, z_start, z_min, feed_mm_min)

    def probe_toward(self, start: tuple[float, float, float], target: tuple[float, float, float],
                     feed_mm_min: float | None = None) -> ProbeResult:
        """Probe from ``start`` toward ``target`` (``Prober.probe_toward``)."""
        return self.prober.probe_toward(start, target, feed_mm_min)

    def select_tool(self, tool: int) -> None:
        """``T<tool>`` (0 = the touch probe, 1.. = nozzles; ``Prober.select_tool``)."""
        self.prober.select_tool(tool)

    # ------------------------------------------------------------------ programs (hardware.machine_stream)
    def stream(self, lines: Iterable[str], on_progress: Callable[[int, int], None] | None = None,
               start_line: int = 0) -> StreamReport:
        """Send a program from command ``start_line`` (``ProgramStream.stream``)."""
        return self.programs.stream(lines, on_progress, start_line)

    def pause(self) -> None:
        """Stop sending program lines (commands already sent still run)."""
        self.programs.pause()

    def resume(self) -> None:
        """Continue a paused program."""
        self.programs.resume()

    def cancel(self) -> None:
        """End the program after the commands in flight (no emergency stop)."""
        self.programs.cancel()

    # ------------------------------------------------------------------ resume (hardware.machine_resume)
    def resume_line(self) -> int:
        """After reconnecting: index of the first command not known to be executed."""
        return self.resumer.resume_line()

    def adopt_interrupted(self, total: int, acked_index: int, acked_line_no: int | None) -> None:
        """Before ``connect`` in a new host process: take over an interrupted program."""
        self.resumer.adopt_interrupted(total, acked_index, acked_line_no)

    def locate_resume(self) -> ResumeLocation:
        """After reconnecting: where the interrupted program continues, and on what evidence."""
        return self.resumer.locate_resume()

    def program_status(self) -> dict[str, Any] | None:
        """The program on this machine, running or interrupted (``ResumeHelper.program_status``)."""
        return self.resumer.program_status()

    # ------------------------------------------------------------------ stop
    def stop(self) -> None:
        """The service's stop: emergency stop while something runs; ``MachineStateError``
        while idle or disconnected (nothing is sent, the machine stays as it is)."""
        self.machine_state.require_stoppable()
        self.emergency_stop()

    def emergency_stop(self) -> None:
        """Out-of-band emergency stop (M112 / 0x18) whatever runs, never queued behind an
        operation (no claim); the machine goes to ``error`` (Marlin halts until reconnected;
        grbl resets)."""
        st = self.machine_state
        link = st.stopping()
        self.homed = False
        self.programs.open_gate()
        link.emergency_stop()
        st.current = "error"
        self.output_guard.note_estop()

    def status(self) -> dict[str, Any]:
        """JSON-friendly snapshot for the API: state, identity, ``program`` (see
        ``program_status``), link counters, the controller's own state and ``outputs``."""
        link, controller, outputs = self.link, self.controller, self.outputs
        return {**base_status(self.machine_state, self.dialect, self.url, self.identity, self.program_status()),
                "link": dict(link.stats) if link else None,
                "controller": self.last_controller_state(),
                "controller_state": controller.as_dict() if controller is not None else None,
                "outputs": dict(outputs) if outputs is not None else None,
                "fallbacks": list(link.fallbacks) if link else []}
