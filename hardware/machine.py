"""A printer as one object: connect/identify, home, move, probe, stream programs with
pause/resume/cancel, emergency stop, and resume after a disconnect.

    machine = Machine("mock://bench", "marlin", MachineProfile(dispense_on="M106"))
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

import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

from .console_log import ConsoleLog
from .dialects import DEFAULT_DIALECT
from .dialects import dialect as dialect_rules
from .errors import FirmwareError, FirmwareReset, HardwareError, InvalidConfig, LinkError, MachineStateError
from .events import Capability, FirmwareInfo, PositionReport, ReplyEvent, StartBanner
from .link import CommandResult, Link, PendingCommand
from .machine_grbl import GrblOperations
from .machine_outputs import DISCONNECT_SAFE_OFF_S, OutputOperations
from .machine_probe import ProbeOperations
from .machine_resume import ResumeOperations
from .machine_state import ClaimedOperations, axis_words, connected
from .machine_types import STATES, Identity, MachineProfile, ProbeResult, StreamReport, _Interrupted
from .program_clock import ProgramClock
from .protocol import validate_program
from .resume import ResumeLocation

REPORT_INTERVAL_S = 0.1  # while streaming: a real-position report this often (hardware.reports)

__all__ = ["STATES", "Identity", "Machine", "MachineProfile", "ProbeResult", "StreamReport"]

class Machine(GrblOperations, ResumeOperations, ProbeOperations, OutputOperations, ClaimedOperations):
    """See the module docstring.  Blocking operations hold the machine (``MachineBusy``
    for a second caller); pause/resume/cancel/stop/status work from any thread."""

    def __init__(self, url: str, dialect: str = DEFAULT_DIALECT, profile: MachineProfile | None = None,
                 *, baudrate: int = 115200, window: str = "windowed", timeout_s: float = 30.0,
                 boot_wait_s: float = 2.0, boot_quiet_s: float = 0.1, poke_s: float = 2.5
                 ) -> None:
        self.url = url
        self.rules = dialect_rules(dialect)  # what this firmware does (hardware.dialects)
        self.dialect = self.rules.name
        self.profile = profile or MachineProfile()
        self.baudrate = baudrate
        self.window = window
        self.timeout_s = timeout_s
        self.boot_wait_s = boot_wait_s
        self.boot_quiet_s = boot_quiet_s
        self.poke_s = poke_s
        self.link: Link | None = None
        self.identity: Identity | None = None
        self.progress: tuple[int, int] | None = None  # (executed, total) of the running program
        self.acked_line_no: int | None = None  # firmware line number of the last acknowledged command
        self._state = "disconnected"
        self._hold = threading.Lock()
        self._resume_event = threading.Event()
        self._resume_event.set()
        self._cancel = False
        self._interrupted: _Interrupted | None = None
        self._estopped = False
        self.planner_blocks = 16  # Marlin BLOCK_BUFFER_SIZE; grbl: from [OPT:..] (15)
        self.last_preamble: list[str] = []  # what the last stream sent before its first command
        self.rejected_lines: list[int] = []  # command indices the controller rejected
        self.outputs: dict[str, Any] | None = None  # the last safe_off: when, whether sent, why not
        self.console = ConsoleLog()  # every line sent and received, across reconnects
        self.homed = False  # homed since this connection (the host's record: Marlin and grbl do not report it)
        self.clock = ProgramClock()  # elapsed time and time left of the running program
        self._connected_at: float | None = None  # time.monotonic() of the last connect
        self.last_resume: ResumeLocation | None = None  # what locate_resume found last
        self._resume_commands: list[str] | None = None  # the interrupted program (locate_resume)
        self._stream_started: float | None = None  # time.monotonic() when the last stream started
        self._stream_origin: tuple[float, float, float] | None = None  # where the tool stood before it

    # ------------------------------------------------------------------ state
    @property
    def link_lost(self) -> bool:
        """True when the transport failed under a connected machine (not after an emergency
        stop): reconnecting and resuming is safe."""
        return self.link is not None and not self.link.healthy and not self._estopped

    @property
    def live_link(self) -> Link:
        """The open link; ``MachineStateError`` while disconnected."""
        return connected(self.link)

    @property
    def state(self) -> str:
        """disconnected | idle | busy | printing | paused | error."""
        if self.link is None:
            return "disconnected"
        if not self.link.healthy and self._state in ("idle", "busy"):
            return "error"
        return self._state

    # ------------------------------------------------------------------ connection
    def connect(self) -> Identity:
        """Open the port, wait for the boot chatter, number lines (Marlin ``M110 N0``,
        unless an interrupted program waits for ``resume_line``) and identify."""
        if self.link is not None:
            self.disconnect()
        self._connected_at = time.monotonic()  # a controller that kept running stopped by now at the latest
        self.link = Link.open(self.url, baudrate=self.baudrate, dialect=self.dialect,
                              timeout_s=self.timeout_s, window=self.window, poke_s=self.poke_s,
                              console=self.console)
        self._state = "busy"
        self._estopped = False
        self.homed = False
        try:
            banner = self._await_boot() if self.rules.boot_banner else self._await_quiet()
            reset = any(isinstance(e, StartBanner) for e in banner)
            if self._interrupted is not None and reset:
                self._interrupted.reset = True
            if self.rules.line_numbers and (self._interrupted is None or self._interrupted.reset):
                self.link.reset_line_numbers(1)
            self.identity = self._identify(banner, reset)
            self._outputs_off_on_connect(reset)
        except HardwareError:
            self._state = "error"
            raise
        self._state = "idle"
        return self.identity

    def _await_quiet(self) -> list[ReplyEvent]:
        link = self.live_link
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

    def _identify(self, banner: list[ReplyEvent], reset: bool) -> Identity:
        command = self.rules.identify_command
        result = self.live_link.send(command, self.timeout_s)
        fields: dict[str, str] = {}
        caps: dict[str, bool] = {}
        for event in result.events:
            if isinstance(event, FirmwareInfo):
                fields.update(event.fields)
            elif isinstance(event, Capability):
                caps[event.name] = event.enabled
        fields.update(self._build_fields(result.events))
        if self.rules.build_info:
            self._apply_build_info(fields)
        elif (self.rules.request_queued and caps.get("EMERGENCY_PARSER") and self.live_link.mode == "windowed"
              and self.live_link.advanced_ok):
            # S000 answered with the steppers' position (REALTIME_REPORTING_COMMANDS): nothing
            # in M115 says so; its plain ok needs ADVANCED_OK to stay apart from the others
            caps["REALTIME_REPORTING_COMMANDS"] = self.live_link.probe_realtime_reports(min(1.0, self.timeout_s))
        version = fields.get("VER", "").split(":")[0]  # [VER:1.1h.20190830:user string]
        name = (fields.get("FIRMWARE_NAME") or ("grbl " + version)).strip()
        return Identity(self.dialect, name, fields, caps, tuple(e.raw for e in banner), reset)

    def disconnect(self) -> None:
        """Close the link (a running program fails with ``LinkError``).  An idle machine on a
        healthy link (not emergency-stopped) gets ``safe_off`` first (best effort, within
        ``DISCONNECT_SAFE_OFF_S``): nothing is left dispensing behind a closed port."""
        link = self.link
        if link is not None and link.healthy and not self._estopped and self._state == "idle" \
                and self._hold.acquire(blocking=False):
            try:
                self._send_safe_off("disconnect", min(self.timeout_s, DISCONNECT_SAFE_OFF_S))
            except HardwareError:
                pass  # the port closes anyway; the next connect sends safe_off again
            finally:
                self._hold.release()
        self.link = None
        self._cancel = True
        self._resume_event.set()
        if link is not None:
            link.close()
        self._state = "disconnected"

    # ------------------------------------------------------------------ simple commands
    def send(self, command: str) -> CommandResult:
        """Raw console command (blocking; FirmwareError when rejected).  G-code while the
        controller refuses motion (grbl Alarm, Hold, Door, Check) is ``ControllerLocked``
        naming the state and how to clear it; ``$`` system commands always go through."""
        system = command.strip().startswith("$")
        self._claim_motion("busy", f"run {command.strip()[:40]!r}", check=not system)
        try:
            result = self.live_link.send(command, self.timeout_s * 10)
        except FirmwareError as exc:
            raise self._locked_reply(exc, f"run {command.strip()[:40]!r}") from exc
        finally:
            self._release()
        if command.strip().upper() == self.home_command.strip().upper():
            self.homed = True  # the operator homed from the console
        return result

    def _claim_motion(self, state: str, what: str, *, check: bool = True) -> None:
        """Claim the machine for an operation that moves it (``what``, for the message):
        ``ControllerLocked`` while the firmware refuses motion (see ``_refuse_locked``)."""
        self._claim(state)
        if not check:
            return
        try:
            self._refuse_locked(what)
        except HardwareError:
            self._release()
            raise

    def _run(self, commands: Iterable[str]) -> list[CommandResult]:
        return [self.live_link.send(c, self.timeout_s * 10) for c in commands]

    @property
    def home_command(self) -> str:
        """What ``home`` sends: the profile's command, else the dialect's (G28 / $H)."""
        return self.profile.home_command or self.rules.home_command

    def home(self) -> tuple[float, float, float]:
        """Home all axes; returns the position afterwards."""
        command = self.home_command
        self._claim("busy")
        self.homed = False  # until this homing succeeds
        try:
            try:
                self._run([command])
            except FirmwareError as exc:
                if self.rules.homing_disabled_error is not None and exc.code == self.rules.homing_disabled_error:
                    raise MachineStateError("homing is disabled on this controller ($22=0): "
                                            "unlock instead, or enable homing", field="home",
                                            value=command) from exc
                raise
            self.homed = True
            return self._position()
        finally:
            self._release()

    def _wait_motion(self) -> str:
        return self.rules.wait_moves

    def move(self, x: float | None = None, y: float | None = None, z: float | None = None,
             feed_mm_min: float | None = None) -> tuple[float, float, float]:
        """Absolute straight move; returns once the motion is finished."""
        feed = feed_mm_min or self.profile.travel_feed_mm_min
        words = axis_words(x, y, z)
        self._claim_motion("busy", "move")
        try:
            if self.rules.jog_locks_gcode:
                self._wait_not_jogging()  # G-code during a jog is error:9
            self._run(["G90", f"G1{words} F{feed:.1f}", self._wait_motion()])
            return self._position()
        finally:
            self._release()

    def position(self) -> tuple[float, float, float]:
        """Current position: Marlin ``M114`` (planned), grbl status ``MPos``."""
        self._claim("busy")
        try:
            return self._position()
        finally:
            self._release()

    def _position(self) -> tuple[float, float, float]:
        if self.rules.position_by_status:
            status = self.live_link.query_status()
            mpos = status.mpos or (0.0, 0.0, 0.0)
            return (mpos[0], mpos[1], mpos[2])
        result = self.live_link.send("M114", self.timeout_s)
        report = result.payload
        if not isinstance(report, PositionReport):
            raise FirmwareError("M114 returned no position", command="M114")
        return (report.axes.get("X", 0.0), report.axes.get("Y", 0.0), report.axes.get("Z", 0.0))

    # ------------------------------------------------------------------ programs
    def stream(self, lines: Iterable[str], on_progress: Callable[[int, int], None] | None = None,
               start_line: int = 0) -> StreamReport:
        """Send a program (comments/blank lines dropped) from command ``start_line``.
        ``InvalidConfig`` (field ``program``) when a line is not G-code.

        Returns when every command is acknowledged, or when cancelled (after the commands
        in flight were answered).  On ``LinkError`` the machine remembers what is known to
        be executed (see ``resume_line``) and re-raises."""
        commands = validate_program(lines)
        total = len(commands)
        if not 0 <= start_line <= total:
            raise InvalidConfig(f"start_line must be within 0..{total}", field="start_line",
                                value=start_line)
        self._claim_motion("printing", "start a program")
        self._cancel = False
        self._resume_event.set()
        self._interrupted = None
        self.last_resume = None  # located for the program interrupted before this one
        link = self.live_link
        started = time.monotonic()
        inflight: deque[tuple[int, PendingCommand]] = deque()
        executed = start_line
        acked_line: int | None = None
        self.progress = (executed, total)
        self.clock.start(start_line)
        seqs: dict[int, int] = {}  # command index -> completion order (Link.status_marks)
        self._note_stream_start(start_line)  # where the tool stands, for reports (hardware.reports)
        try:
            self._replay_modes(commands, start_line)
        except HardwareError as exc:
            if isinstance(exc, LinkError):  # nothing of the program was sent: it resumes where it was to start
                self._interrupted = _Interrupted(total, start_line, None, [], True, start_line)
                self._resume_commands = list(commands)
            self._release("error" if not link.healthy else "idle")
            raise

        def retire_oldest() -> None:
            """Wait for the oldest in-flight command (its LinkError propagates, leaving it
            in flight) and count it as executed."""
            nonlocal executed, acked_line
            index_done, pending = inflight[0]
            outcome = pending.result()
            inflight.popleft()
            seqs[index_done] = pending.seq
            executed, acked_line = index_done + 1, outcome.line_no
            self.progress = (executed, total)
            self.acked_line_no = acked_line
            if on_progress is not None:
                on_progress(executed, total)

        if not self.rules.request_queued or link.realtime_reports:
            link.report_interval_s = REPORT_INTERVAL_S  # the reader asks; the stream never waits for it
        try:
            for index in range(start_line, total):
                link.wait_room(commands[index])  # see every answer before the next line
                while inflight and inflight[0][1].done():
                    retire_oldest()
                if not self._resume_event.is_set():
                    self._state = "paused"
                    self._resume_event.wait()
                    self._state = "printing"
                if self._cancel:
                    break
                inflight.append((index, link.send_async(commands[index])))
            while inflight:
                retire_oldest()
            if not self._resume_event.is_set() and not self._cancel:  # paused after its last line went out:
                self._state = "paused"  # the program holds there until resumed (the pause is not lost)
                self._resume_event.wait()
                self._state = "printing"
        except LinkError as exc:
            while inflight and inflight[0][1].done() and inflight[0][1].failure is None \
                    and (answer := inflight[0][1].outcome) is not None and answer.status != "error":
                index_done, pending = inflight.popleft()  # answered before the failure
                executed, acked_line = index_done + 1, answer.line_no
                seqs[index_done] = pending.seq
            self.progress = (executed, total)
            self._interrupted = _Interrupted(total, executed, acked_line,
                                             [(p.line_no, i) for i, p in inflight],
                                             isinstance(exc, FirmwareReset),
                                             self._moved_bound(commands, executed, seqs),
                                             report=self._report_evidence(seqs, start_line, exc))
            self._release("error")
            exc.resume_line = executed  # lower bound; resume_line() refines it
            raise
        except FirmwareError as exc:
            executed = self._drain_after_rejection(exc, inflight, executed)
            self.progress = (executed, total)
            self._interrupted = _Interrupted(total, executed, acked_line, [], False, executed)
            self._release("error" if not link.healthy or self._estopped else "idle")
            raise
        except HardwareError:
            self._interrupted = _Interrupted(total, executed, acked_line, [], True)
            self._release("error" if not link.healthy or self._estopped else "idle")
            raise
        finally:
            link.report_interval_s = 0.0
        cancelled = self._cancel
        self._release("idle")
        return StreamReport(executed, total, start_line, cancelled, time.monotonic() - started,
                            dict(link.stats))

    @property
    def estopped(self) -> bool:
        """True after an emergency stop, until the next ``connect``."""
        return self._estopped

    @property
    def interrupted_program(self) -> _Interrupted | None:
        """What is known of a program that stopped on a link failure (``resume_line``)."""
        return self._interrupted

    def pause(self) -> None:
        """Stop sending program lines (commands already sent still run)."""
        if self._state != "printing":
            raise MachineStateError(f"cannot pause while {self.state}", field="state",
                                    value=self.state)
        self._resume_event.clear()
        self.clock.pause()
        if self.rules.feed_hold is not None and self.link is not None:
            self.link.realtime(self.rules.feed_hold)  # feed hold: motion already planned stops too
        self._state = "paused"

    def resume(self) -> None:
        """Continue a paused program."""
        if self._state != "paused":
            raise MachineStateError(f"cannot resume while {self.state}", field="state",
                                    value=self.state)
        if self.rules.cycle_start is not None and self.link is not None:
            self.link.realtime(self.rules.cycle_start)  # cycle start after the feed hold
        self._state = "printing"
        self.clock.resume()
        self._resume_event.set()

    def cancel(self) -> None:
        """End the program after the commands in flight (no emergency stop)."""
        if self._state not in ("printing", "paused"):
            raise MachineStateError(f"no program to cancel while {self.state}", field="state",
                                    value=self.state)
        self._cancel = True
        self._resume_event.set()

    def stop(self) -> None:
        """The service's stop: emergency stop while something runs; ``MachineStateError``
        while idle or disconnected (nothing is sent, the machine stays as it is)."""
        state = self.state
        if state not in ("printing", "paused", "busy"):
            raise MachineStateError(f"nothing to stop: machine is {state}", field="state",
                                    value=state)
        self.emergency_stop()

    def emergency_stop(self) -> None:
        """Out-of-band emergency stop (M112 / 0x18) whatever runs; the machine goes to
        ``error`` (Marlin halts until reconnected; grbl resets)."""
        if self.link is None:
            raise MachineStateError("machine is not connected", field="state", value="disconnected")
        self._cancel = True
        self._estopped = True
        self.homed = False
        self._resume_event.set()
        self.link.emergency_stop()
        self._state = "error"
        self._note_estop_outputs()

    def status(self) -> dict[str, Any]:
        """JSON-friendly snapshot for the API: state, identity, ``program`` (see
        ``program_status``), link counters, the controller's own state and ``outputs``."""
        return {"state": self.state, "dialect": self.dialect, "url": self.url,
                "firmware": self.identity.firmware if self.identity else None,
                "program": self.program_status(),
                "link": dict(self.link.stats) if self.link else None,
                "controller": self.last_controller_state(),
                "controller_state": self.controller.as_dict() if self.controller is not None else None,
                "outputs": dict(self.outputs) if self.outputs is not None else None,
                "fallbacks": list(self.link.fallbacks) if self.link else []}
