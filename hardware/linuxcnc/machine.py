"""A LinuxCNC controller behind the same interface as :class:`hardware.machine.Machine`.

    machine = LinuxCNCMachine("linuxcnc://127.0.0.1:5007", MachineProfile(
        dispense_on="M64 P0", dispense_off="M65 P0", probe_command="G38.2"))
    machine.connect()             # hello, enable, estop off, machine on (no motion)
    machine.home()                # all joints
    machine.move(x=10, y=5)       # MDI, returns when the motion is done
    machine.probe(10, 5)          # G38.2 down, result from #5061-#5063 / #5070, retract
    machine.stream(lines)         # writes a program file, open + run, polls progress

Two linuxcncrsh sessions: the *command* session (MDI, programs, status) and the *stop*
session, which is used only by :meth:`emergency_stop` (it takes control with
``set enable`` and sends ``set estop on``): a stop is never queued behind a command that
waits for motion.  After an emergency stop, a controller error or a lost link the machine
is in ``error`` and sends nothing until :meth:`connect` (no automatic motion after a
failure).  When the command session is lost while a program runs, the stop session aborts
the program (best effort): LinuxCNC has no link watchdog and would go on unsupervised.

Process outputs: an e-stop keeps ``M64`` outputs on and MDI cannot run in e-stop, so the
controller's ``ON_ABORT_COMMAND`` switches them off (``sim/remap/on_abort.ngc``); the host
sends ``safe_off`` on connect (homed), after homing, before each program and on disconnect.

Programs: the commands (comments dropped) are written to ``<programs>/conforma-<sha>.ngc``
with ``M2`` appended when the program has no end, opened by absolute path and run.  The
progress is ``get program_line`` (file line n running => commands before it executed).
Probe results are the G38.2 result parameters, read back with a ``(DEBUG,...)`` message
(#5061-#5063 in the active work coordinates, #5070 = 1 when the probe tripped).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterable

from ..console_log import ConsoleLog
from ..dialects import LINUXCNC_DISPENSE
from ..errors import FirmwareError, HardwareError, InvalidConfig, LinkError, MachineStateError, ProbeFailed
from ..machine_state import ClaimedOperations, axis_words, connected
from ..machine_types import Identity, MachineProfile, ProbeResult, StreamReport, _Interrupted
from ..program_clock import ProgramClock
from ..protocol import validate_program
from .rsh import RshRejected, RshSession
from .url import parse_url, passwords

__all__ = ["LinuxCNCMachine"]

_NO_CONTACT = "without making contact"


class LinuxCNCMachine(ClaimedOperations):
    """See the module docstring.  Blocking calls hold the machine (``MachineBusy`` for a
    second caller); pause/resume/cancel/stop/status work from any thread."""

    dialect = "linuxcnc"

    def __init__(self, url: str, profile: MachineProfile | None = None, *,
                 connect_pw: str | None = None, enable_pw: str | None = None, program_dir: str | None = None,
                 timeout_s: float = 10.0, motion_timeout_s: float = 3600.0,
                 poll_s: float = 0.02) -> None:
        self.url = url
        self.address = parse_url(url, program_dir)
        self.profile = profile or MachineProfile(*LINUXCNC_DISPENSE, probe_command="G38.2")
        self._connect_pw, self._enable_pw = passwords(connect_pw, enable_pw)
        self.timeout_s = timeout_s
        self.motion_timeout_s = motion_timeout_s
        self.poll_s = poll_s
        self.link: RshSession | None = None      # the command session
        self._stop_link: RshSession | None = None
        self.identity: Identity | None = None
        self.progress: tuple[int, int] | None = None
        self._state = "disconnected"
        self._hold = threading.Lock()
        self._cancel = False
        self._pause_requested = False
        self._estopped = False
        self._interrupted: tuple[int, int] | None = None   # (total, executed) at the loss
        self._probe_seq = 0
        self.last_preamble: list[str] = []  # the modal replay written before a resumed program
        self.console = ConsoleLog()  # MDI commands sent and the controller's answers, across reconnects
        self.homed = False  # every joint homed, as the controller reported at connect and after homing
        self.clock = ProgramClock()  # elapsed time and time left of the running program

    # ------------------------------------------------------------------ state
    @property
    def link_lost(self) -> bool:
        """True when the command session failed (not after an emergency stop)."""
        return self.link is not None and not self.link.healthy and not self._estopped

    @property
    def state(self) -> str:
        """disconnected | idle | busy | printing | paused | error."""
        if self.link is None:
            return "disconnected"
        if not self.link.healthy and self._state in ("idle", "busy", "printing", "paused"):
            return "error"
        return self._state

    def _fail_state(self) -> str:
        return "error" if self._estopped or self.link is None or not self.link.healthy else "idle"

    # ------------------------------------------------------------------ connection
    def _open_session(self) -> RshSession:
        a = self.address
        return RshSession.open(a.host, a.port, self._connect_pw, timeout_s=self.timeout_s)

    def connect(self) -> Identity:
        """Open both sessions, take control, leave e-stop and switch the machine on.
        Nothing moves; ``home()`` is the caller's decision."""
        if self.link is not None:
            self._close_sessions()
        self._state = "busy"
        self._estopped = False
        try:
            self._stop_link = self._open_session()
            self.link = self._open_session()
            self.link.enable(self._enable_pw)
            for _ in range(50):  # errors left over from before this connection
                if self.link.pop_error() is None:
                    break
            self.link.set("estop", "off")
            self.link.set("machine", "on")
            homed = self.link.get("joint_homed")
            kins = self.link.get("kinematics_type")
            self.homed = self._homed(homed)
            if self.homed and self.link.get("program_status").upper() == "IDLE":
                self._mdi(self.profile.safe_off)  # an output left on before this connection goes off
        except HardwareError:
            self._state = "error"
            raise
        server = self.link.server or "linuxcncrsh"
        self.identity = Identity("linuxcnc", f"LinuxCNC ({server})",
                                 {"server": server, "joint_homed": homed, "kinematics_type": kins},
                                 {}, (), False)
        self._state = "idle"
        return self.identity

    def _close_sessions(self) -> None:
        for session in (self.link, self._stop_link):
            if session is not None:
                session.close()
        self.link, self._stop_link = None, None

    def _homed(self, joint_homed: str) -> bool:
        """True when ``get joint_homed`` says every joint this machine has is homed."""
        flags, joints = [h.upper() == "YES" for h in joint_homed.split()], self.address.joints
        return all(flags[:joints]) if joints is not None else any(flags)

    def disconnect(self) -> None:
        """Close both sessions; a running program is aborted first (never unsupervised), an
        idle machine gets ``safe_off`` first (best effort)."""
        if self._state in ("printing", "paused"):
            self._abort_best_effort()
        elif self._state == "idle" and self.link is not None and self.link.healthy and not self._estopped:
            with contextlib.suppress(HardwareError):
                if self._homed(self.link.get("joint_homed")):
                    self._mdi(self.profile.safe_off)
        self._cancel = True
        self._close_sessions()
        self._state = "disconnected"

    # ------------------------------------------------------------------ MDI
    def _mode(self, mode: str) -> None:
        connected(self.link).set_mode(mode)

    def _mdi(self, commands: Iterable[str]) -> None:
        """Run MDI commands one by one, each to completion; the controller's error (if
        any) becomes ``FirmwareError``.  Refuses after an emergency stop."""
        self._mode("mdi")
        for command in commands:
            if self._estopped:
                raise MachineStateError("emergency stop: reconnect first", field="state", value="error")
            connected(self.link).pop_error()
            self.console.record("sent", command)
            try:
                # "set mdi" is answered once the controller received it (not after the
                # motion): a reply lost by linuxcncrsh becomes a LinkError after timeout_s
                # instead of an hour-long hang; "wait done" waits for the motion
                connected(self.link).set("mdi", command)
                connected(self.link).set("wait", "done", timeout_s=self.motion_timeout_s)
            except RshRejected as exc:
                raise FirmwareError(exc.message, command=command) from exc
            except LinkError:  # no watchdog on the controller: the move must not go on unsupervised
                self._abort_best_effort()
                raise
            error = connected(self.link).pop_error()
            self.console.record("received", f"error: {error}" if error is not None else "done")
            if error is not None:
                raise FirmwareError(f"LinuxCNC: {error}", command=command)
            if self._estopped:
                raise MachineStateError("emergency stop during MDI", field="state", value="error")

    def send(self, command: str) -> str:
        """One MDI command (blocking); returns the controller's operator message or ``ok``."""
        self._claim("busy")
        try:
            self._mdi([command])
            return connected(self.link).get("operator_display")
        finally:
            self._release(self._fail_state())

    @property
    def home_command(self) -> str:
        """What homing is recorded as: the profile's command, else ``set home -1``."""
        return self.profile.home_command or "set home -1"

    def home(self) -> tuple[float, float, float]:
        """Home all joints (``set home -1``) and wait until every joint reports homed."""
        self._claim("busy")
        try:
            self._mode("manual")
            connected(self.link).set("teleop_enable", "off")  # homing needs joint mode
            connected(self.link).set("home", "-1")
            deadline = time.monotonic() + self.motion_timeout_s
            joints, last, stable_since = self.address.joints, None, time.monotonic()
            while True:
                error = connected(self.link).pop_error()
                if error is not None:
                    raise FirmwareError(f"LinuxCNC: {error}", command="home")
                homed = [h.upper() == "YES" for h in connected(self.link).get("joint_homed").split()]
                now = time.monotonic()
                if homed != last:
                    last, stable_since = homed, now
                if joints is not None and len(homed) >= joints and all(homed[:joints]):
                    break
                if joints is None and any(homed) and now - stable_since > 0.5:
                    break
                if now > deadline:
                    raise LinkError("homing did not finish in time", field="home")
                time.sleep(self.poll_s)
            self.homed = True
            self._mdi(self.profile.safe_off)  # first chance after a connect to an un-homed machine
            return self._position()
        finally:
            self._release(self._fail_state())

    def move(self, x: float | None = None, y: float | None = None, z: float | None = None,
             feed_mm_min: float | None = None) -> tuple[float, float, float]:
        """Absolute straight move (G90 G1); returns once the motion is finished."""
        feed = feed_mm_min or self.profile.travel_feed_mm_min
        words = axis_words(x, y, z)
        self._claim("busy")
        try:
            self._mdi([f"G90 G1{words} F{feed:.1f}"])
            return self._position()
        finally:
            self._release(self._fail_state())

    def position(self) -> tuple[float, float, float]:
        """Actual X Y Z in absolute (machine) coordinates (``get abs_act_pos``)."""
        if self.link is None:
            raise MachineStateError("machine is not connected", field="state", value="disconnected")
        return self._position()

    def _position(self) -> tuple[float, float, float]:
        values = [float(v) for v in connected(self.link).get("abs_act_pos").split()]
        return values[0], values[1], values[2]

    def joint_positions(self) -> list[float]:
        """Every joint's actual position (mm / deg), ``get joint_pos``."""
        if self.link is None:
            raise MachineStateError("machine is not connected", field="state", value="disconnected")
        return [float(v) for v in self.link.get("joint_pos").split()]

    # ------------------------------------------------------------------ probing
    def probe(self, x: float, y: float, z_start: float | None = None, z_min: float | None = None,
              feed_mm_min: float | None = None) -> ProbeResult:
        """Travel to (x, y) at ``z_start``, ``G38.2`` down to ``z_min``, read the trip
        point, retract to ``z_start``.  ``ProbeFailed`` (retracted) when nothing is hit;
        a probe already tripped at the start is a ``FirmwareError``."""
        p = self.profile
        z_start = p.clearance_z if z_start is None else z_start
        z_min = p.probe_z_min if z_min is None else z_min
        feed = feed_mm_min or p.probe_feed_mm_min
        if z_min >= z_start:
            raise InvalidConfig("z_min must be below z_start", field="z_min", value=z_min)
        travel = p.travel_feed_mm_min
        retract = f"G90 G1 Z{z_start:.4f} F{travel:.1f}"
        self._claim("busy")
        try:
            self._mdi([retract, f"G90 G1 X{x:.4f} Y{y:.4f} F{travel:.1f}"])
            try:
                self._mdi([f"G38.2 Z{z_min:.4f} F{feed:.1f}"])
            except FirmwareError as exc:
                if _NO_CONTACT not in exc.message:
                    raise
                self._mdi([retract])
                raise ProbeFailed(f"probe at ({x:.3f}, {y:.3f}) found no surface above "
                                  f"z={z_min:.3f}", x=x, y=y, field="probe", value=[x, y]) from exc
            px, py, pz, tripped = self._probe_parameters()
            self._mdi([retract])
            if tripped != 1.0:
                raise ProbeFailed(f"probe at ({x:.3f}, {y:.3f}) did not trip", x=x, y=y,
                                  field="probe", value=[x, y])
            return ProbeResult(px, py, pz)
        finally:
            self._release(self._fail_state())

    def _probe_parameters(self) -> tuple[float, float, float, float]:
        self._probe_seq += 1
        tag = f"conforma-probe-{self._probe_seq}"
        self._mdi([f"(DEBUG,{tag} #5061 #5062 #5063 #5070)"])
        words = connected(self.link).get("operator_display").split()
        if len(words) != 5 or words[0] != tag:
            raise FirmwareError(f"no probe result from LinuxCNC (operator display {' '.join(words)[:60]!r})",
                                command="G38.2")
        return tuple(float(w) for w in words[1:])  # type: ignore[return-value]

    def select_tool(self, tool: int) -> None:
        """``T<tool> M6`` by MDI (no ``G43``: no tool-length offset is applied, programs stay
        in carriage coordinates as on serial machines).  LinuxCNC's T0 means "no tool"; the
        tool must be in the controller's tool table, else ``InvalidConfig`` (field ``tool``)."""
        if isinstance(tool, bool) or not isinstance(tool, int) or not 0 <= tool <= 99:
            raise InvalidConfig("tool must be an integer 0..99", field="tool", value=tool)
        self._claim("busy")
        try:
            try:
                self._mdi([f"T{tool} M6"])
            except FirmwareError as exc:
                raise InvalidConfig(f"LinuxCNC refused tool T{tool}: {exc.message}", field="tool",
                                    value=tool) from exc
        finally:
            self._release(self._fail_state())

    def probe_toward(self, start: tuple[float, float, float], target: tuple[float, float, float],
                     feed_mm_min: float | None = None) -> ProbeResult:
        """Travel to ``start`` (Z up first, then XY, then Z down), ``G38.2`` toward ``target``
        (any direction), read #5061-#5063, go straight back to ``start``.  ``ProbeFailed``
        when nothing is touched (the machine is back at ``start``)."""
        sx, sy, sz = (float(v) for v in start)
        tx, ty, tz = (float(v) for v in target)
        if max(abs(sx - tx), abs(sy - ty), abs(sz - tz)) < 1e-6:
            raise InvalidConfig("probe target equals its start", field="target", value=[tx, ty, tz])
        p = self.profile
        feed = feed_mm_min or p.probe_feed_mm_min
        travel = p.travel_feed_mm_min
        back = f"G90 G1 X{sx:.4f} Y{sy:.4f} Z{sz:.4f} F{travel:.1f}"
        where = [round(tx, 4), round(ty, 4), round(tz, 4)]
        self._claim("busy")
        try:
            here = self._position()
            self._mdi([f"G90 G1 Z{max(here[2], sz):.4f} F{travel:.1f}", f"G1 X{sx:.4f} Y{sy:.4f} F{travel:.1f}",
                       f"G1 Z{sz:.4f} F{travel:.1f}"])
            try:
                self._mdi([f"G38.2 X{tx:.4f} Y{ty:.4f} Z{tz:.4f} F{feed:.1f}"])
            except FirmwareError as exc:
                if _NO_CONTACT not in exc.message:
                    raise
                self._mdi([back])
                raise ProbeFailed(f"probe from {[sx, sy, sz]} toward {where} touched nothing", x=tx, y=ty,
                                  field="probe", value=where) from exc
            px, py, pz, tripped = self._probe_parameters()
            self._mdi([back])
            if tripped != 1.0:
                raise ProbeFailed(f"probe toward {where} did not trip", x=tx, y=ty, field="probe", value=where)
            return ProbeResult(px, py, pz)
        finally:
            self._release(self._fail_state())

    # ------------------------------------------------------------------ programs
    def stream(self, lines: Iterable[str], on_progress: Callable[[int, int], None] | None = None,
               start_line: int = 0) -> StreamReport:
        """Run the program from command ``start_line`` on the controller (see the module
        docstring); returns when it ended or was cancelled (``set abort``)."""
        from .program_run import resume_preamble, run_program, write_program

        commands = validate_program(lines)
        total = len(commands)
        if not 0 <= start_line <= total:
            raise InvalidConfig(f"start_line must be within 0..{total}", field="start_line",
                                value=start_line)
        self._claim("printing")
        self._cancel = False
        self._pause_requested = False
        self._interrupted = None
        self.progress = (start_line, total)
        self.clock.start(start_line)
        started = time.monotonic()
        try:
            if start_line == total:
                executed, cancelled = total, False
            else:
                self._mdi(self.profile.safe_off)  # the program starts with every output off
                preamble = resume_preamble(self, commands, start_line)
                path = write_program(self.address.program_dir, preamble + commands[start_line:])
                executed, cancelled = run_program(self, path, start_line, total, on_progress,
                                                  skip=len(preamble))
        except LinkError as exc:
            executed = self.progress[0]
            self._interrupted = (total, executed)
            self._abort_best_effort()
            self._release("error")
            exc.resume_line = executed
            raise
        except HardwareError:
            self._release(self._fail_state())
            raise
        self._release("idle")
        return StreamReport(executed, total, start_line, cancelled, time.monotonic() - started, {})

    # ------------------------------------------------------------------ interruption (the
    # same calls as hardware.machine.Machine: the service's interrupted/resume workflow)
    @property
    def estopped(self) -> bool:
        """True after an emergency stop until the next connect."""
        return self._estopped

    @property
    def acked_line_no(self) -> None:
        """LinuxCNC numbers no lines on the wire (progress is its ``program_line``)."""
        return None

    @property
    def interrupted_program(self) -> _Interrupted | None:
        """What is known of a program whose link was lost: commands [0, acked_index) done."""
        if self._interrupted is None:
            return None
        total, executed = self._interrupted
        return _Interrupted(total, executed, None, [], False, executed)

    def adopt_interrupted(self, total: int, acked_index: int, acked_line_no: int | None) -> None:
        """A new process resumes a program an earlier one recorded (before connecting)."""
        self._interrupted = (int(total), int(acked_index))

    def resume_line(self) -> int:
        """After reconnecting: the first command not known to be executed.  A program the
        controller still runs is aborted first."""
        if self._interrupted is None:
            raise MachineStateError("no interrupted program to resume", field="state")
        if self.link is None or not self.link.healthy:
            raise MachineStateError("connect before resuming", field="state", value="disconnected")
        if self.link.get("program_status").upper() != "IDLE":
            self.link.set("abort")
        return self._interrupted[1]

    def pause(self) -> None:
        """Pause the running program (the controller decelerates and holds)."""
        if self._state != "printing":
            raise MachineStateError(f"cannot pause while {self.state}", field="state", value=self.state)
        connected(self.link).set("pause")
        self.clock.pause()
        self._state = "paused"

    def resume(self) -> None:
        """Continue a paused program."""
        if self._state != "paused":
            raise MachineStateError(f"cannot resume while {self.state}", field="state", value=self.state)
        connected(self.link).set("resume")
        self.clock.resume()
        self._state = "printing"

    def cancel(self) -> None:
        """Abort the running program (controlled stop, no emergency stop)."""
        if self._state not in ("printing", "paused"):
            raise MachineStateError(f"no program to cancel while {self.state}", field="state",
                                    value=self.state)
        self._cancel = True

    def stop(self) -> None:
        """The service's stop: emergency stop while something runs; ``MachineStateError``
        while idle or disconnected."""
        state = self.state
        if state not in ("printing", "paused", "busy"):
            raise MachineStateError(f"nothing to stop: machine is {state}", field="state", value=state)
        self.emergency_stop()

    def emergency_stop(self) -> None:
        """``set estop on`` over the stop session (reopened if it died); machine -> error."""
        if self.link is None:
            raise MachineStateError("machine is not connected", field="state", value="disconnected")
        self._estopped = True
        self._cancel = True
        self.homed = False
        self.console.record("sent", "set estop on")
        session = self._stop_link
        if session is None or not session.healthy:
            session = self._stop_link = self._open_session()
        session.enable(self._enable_pw)
        session.set("estop", "on")
        self._state = "error"

    def _abort_best_effort(self) -> None:
        try:
            session = self._stop_link
            if session is None or not session.healthy:
                session = self._stop_link = self._open_session()
            session.enable(self._enable_pw)
            session.set("abort")
        except HardwareError:
            pass

    def status(self) -> dict[str, object]:
        """JSON-friendly snapshot for the API (state, identity, program progress)."""
        executed, total = self.progress or (None, None)
        return {"state": self.state, "dialect": self.dialect, "url": self.url,
                "firmware": self.identity.firmware if self.identity else None,
                "program": None if self.progress is None or self.state not in ("printing", "paused")
                else {"line": executed, "total": total},
                "link": None, "fallbacks": []}
