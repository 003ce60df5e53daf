"""A LinuxCNC controller behind the same interface as :class:`hardware.machine.Machine`.

    machine = LinuxCNCMachine("linuxcnc://127.0.0.1:5007", MachineProfile(
        dispense_on="M64 P0", dispense_off="M65 P0", probe_command="G38.2"))
    machine.connect()             # hello, enable, estop off, machine on (no motion)
    machine.home()                # all joints
    machine.move(x=10, y=5)       # MDI, returns when the motion is done
    machine.probe(10, 5)          # G38.2 down, result from #5061-#5063 / #5070, retract
    machine.stream(lines)         # writes a program file, open + run, polls progress

Two linuxcncrsh sessions: the *command* session (MDI, programs, status) and the *stop*
session (:mod:`hardware.linuxcnc.stop_session`), which is used only by :meth:`emergency_stop`
(it takes control with ``set enable`` and sends ``set estop on`` until the controller reports
it): a stop is never queued behind a command that waits for motion.  After an emergency
stop, a controller error or a lost link the machine is in ``error`` and sends nothing until
:meth:`connect` (no automatic motion after a failure).  When the command session is lost
while a program runs, the stop session aborts the program until the controller reports it
idle (``StopSession.abort``, bounded; the console tells whether it was confirmed): LinuxCNC
has no link watchdog and would go on unsupervised.  Homing, an MDI command and a program
ask the task for a no-op command every few seconds (:mod:`hardware.linuxcnc.task_watch`): a
task that died leaves a frozen status, which would otherwise read "busy" for an hour.

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
import re
import time
from collections.abc import Callable, Iterable
from typing import Any

from ..console_log import ConsoleLog
from ..dialects import LINUXCNC_DISPENSE
from ..errors import FirmwareError, HardwareError, InvalidConfig, LinkError, MachineStateError, ProbeFailed
from ..machine_args import (
    check_tool,
    probe_down,
    probe_missed,
    probe_toward,
    program_commands,
    straight_move,
    written_at,
)
from ..machine_state import InterruptedProgram, MachineState, StateReadout, base_status, connected
from ..machine_types import Identity, MachineProfile, ProbeResult, StreamReport
from ..program_clock import ProgramClock
from .rsh import RshRejected, RshSession
from .stop_session import StopSession
from .task_watch import TaskWatch
from .url import parse_url, passwords

__all__ = ["LinuxCNCMachine"]

_NO_CONTACT = "without making contact"
_OWN_MOVE = re.compile(r"G90 G1(?: [XYZ]-?\d+\.\d{4})+ F\d+\.\d")  # as move() and the probes write them
MAX_TOOL = 99  # the highest tool number select_tool accepts


class LinuxCNCMachine(StateReadout[RshSession]):
    """See the module docstring.  Blocking calls hold the machine (``MachineBusy`` for a
    second caller); pause/resume/cancel/stop/status work from any thread.  The command
    session, state, claim, flags, progress and the interrupted program's record live in
    ``machine_state`` (``hardware.machine_state``, kept as the serial machine keeps its own)."""

    dialect = "linuxcnc"

    def __init__(self, url: str, profile: MachineProfile | None = None, *,
                 connect_pw: str | None = None, enable_pw: str | None = None, program_dir: str | None = None,
                 hal_prefix: str | None = None, timeout_s: float = 10.0, motion_timeout_s: float = 3600.0,
                 poll_s: float = 0.02) -> None:
        self.url = url
        self.address = parse_url(url, program_dir)
        self.profile = profile or MachineProfile(*LINUXCNC_DISPENSE, probe_command="G38.2")
        self._connect_pw, self._enable_pw = passwords(connect_pw, enable_pw)
        # how this host's HAL commands reach the controller (hal_command; None: the environment's)
        self.hal_prefix = hal_prefix
        self.timeout_s = timeout_s
        self.motion_timeout_s = motion_timeout_s
        self.poll_s = poll_s
        # the command session is machine_state.link; a lost one is an error even mid-program
        super().__init__(MachineState(error_when_lost=("idle", "busy", "printing", "paused")))
        self._stopper = StopSession(self._open_session, self._enable_pw)
        self.identity: Identity | None = None
        self._probe_seq = 0
        self.last_preamble: list[str] = []  # the modal replay written before a resumed program
        self.console = ConsoleLog()  # MDI commands sent and the controller's answers, across reconnects
        self.homed = False  # every joint homed, as the controller reported at connect and after homing
        self.clock = ProgramClock()  # elapsed time and time left of the running program
        self._last_move: str | None = None  # the last command _mdi ran, when it was one of _OWN_MOVE

    # ------------------------------------------------------------------ connection
    def _open_session(self) -> RshSession:
        a = self.address
        return RshSession.open(a.host, a.port, self._connect_pw, timeout_s=self.timeout_s)

    def connect(self) -> Identity:
        """Open both sessions, take control, leave e-stop and switch the machine on.
        Nothing moves; ``home()`` is the caller's decision."""
        st = self.machine_state
        if st.link is not None:
            self._close_sessions()
        self._last_move = None
        st.connecting()
        try:
            self._stopper.open()
            link = st.link = self._open_session()
            link.enable(self._enable_pw)
            for _ in range(50):  # errors left over from before this connection
                if link.pop_error() is None:
                    break
            link.set("estop", "off")
            link.set("machine", "on")
            homed = link.get("joint_homed")
            kins = link.get("kinematics_type")
            self.homed = self._homed(homed)
            if self.homed and link.get("program_status").upper() == "IDLE":
                self._mdi(self.profile.safe_off)  # an output left on before this connection goes off
        except HardwareError:
            st.current = "error"
            raise
        server = link.server or "linuxcncrsh"
        self.identity = Identity("linuxcnc", f"LinuxCNC ({server})",
                                 {"server": server, "joint_homed": homed, "kinematics_type": kins},
                                 {}, (), False)
        st.current = "idle"
        return self.identity

    def _close_sessions(self) -> None:
        if self.machine_state.link is not None:
            self.machine_state.link.close()
        self.machine_state.link = None
        self._stopper.close()

    def _homed(self, joint_homed: str) -> bool:
        """True when ``get joint_homed`` says every joint this machine has is homed."""
        flags, joints = [h.upper() == "YES" for h in joint_homed.split()], self.address.joints
        return all(flags[:joints]) if joints is not None else any(flags)

    def disconnect(self) -> None:
        """Close both sessions; a running program is aborted first (never unsupervised), an
        idle machine gets ``safe_off`` first (best effort)."""
        st, link = self.machine_state, self.machine_state.link
        if st.current in ("printing", "paused"):
            self._stopper.abort(self.console)
        elif st.current == "idle" and link is not None and link.healthy and not st.estopped:
            with contextlib.suppress(HardwareError):
                if self._homed(link.get("joint_homed")):
                    self._mdi(self.profile.safe_off)
        st.cancel_requested = True
        self._close_sessions()
        st.current = "disconnected"

    # ------------------------------------------------------------------ MDI
    def _mode(self, mode: str) -> None:
        connected(self.link).set_mode(mode)

    def _mdi(self, commands: Iterable[str]) -> None:
        """Run MDI commands one by one, each to completion; the controller's error (if
        any) becomes ``FirmwareError``.  Refuses after an emergency stop."""
        self._mode("mdi")
        for command in commands:
            self._last_move = None
            if self.machine_state.estopped:
                raise MachineStateError("emergency stop: reconnect first", field="state", value="error")
            connected(self.link).pop_error()
            self.console.record("sent", command)
            try:
                # "set mdi" is answered once the controller received it (not after the
                # motion): a reply lost by linuxcncrsh becomes a LinkError after timeout_s
                # instead of an hour-long hang; "wait done" waits for the motion
                connected(self.link).set("mdi", command)
                self._await_interpreter()
                connected(self.link).set("wait", "done", timeout_s=self.motion_timeout_s)
            except RshRejected as exc:
                raise FirmwareError(exc.message, command=command) from exc
            except LinkError:  # no watchdog on the controller: the move must not go on unsupervised
                self._stopper.abort(self.console)
                raise
            error = connected(self.link).pop_error()
            self.console.record("received", f"error: {error}" if error is not None else "done")
            if error is not None:
                raise FirmwareError(f"LinuxCNC: {error}", command=command)
            if self.machine_state.estopped:
                raise MachineStateError("emergency stop during MDI", field="state", value="error")
            self._last_move = command if _OWN_MOVE.fullmatch(command) else None

    def _await_interpreter(self) -> None:
        """While the controller is in MDI mode and its interpreter runs (``get mode`` MDI,
        ``get program_status`` RUNNING: the MDI command), poll both every ``poll_s`` (at
        most ``motion_timeout_s``).  Only a head start for ``set wait done``, which stays
        the judge of done and failed: linuxcncrsh checks for done every 0.1 s, so a command
        that ends while it sleeps would be answered up to 0.1 s late; once the interpreter is
        idle its first check answers.  In any other mode (a program the controller still
        runs, which refuses the MDI command) nothing is waited here."""
        link, deadline = connected(self.link), time.monotonic() + self.motion_timeout_s
        watch = TaskWatch(link, "the MDI command")
        while (link.get("mode").upper() == "MDI" and link.get("program_status").upper() == "RUNNING"
               and time.monotonic() < deadline):
            watch.check()
            time.sleep(self.poll_s)

    def send(self, command: str) -> str:
        """One MDI command (blocking); returns the controller's operator message or ``ok``."""
        self.machine_state.claim("busy")
        try:
            self._mdi([command])
            return connected(self.link).get("operator_display")
        finally:
            self.machine_state.release(self.machine_state.fail_state())

    @property
    def home_command(self) -> str:
        """What homing is recorded as: the profile's command, else ``set home -1``."""
        return self.profile.home_command or "set home -1"

    def home(self) -> tuple[float, float, float]:
        """Home all joints (``set home -1``) and wait until every joint reports homed."""
        self.machine_state.claim("busy")
        try:
            self._mode("manual")
            connected(self.link).set("teleop_enable", "off")  # homing needs joint mode
            connected(self.link).set("home", "-1")
            deadline = time.monotonic() + self.motion_timeout_s
            joints, last, stable_since = self.address.joints, None, time.monotonic()
            watch = TaskWatch(connected(self.link), "homing")
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
                watch.check()
                time.sleep(self.poll_s)
            self.homed = True
            self._mdi(self.profile.safe_off)  # first chance after a connect to an un-homed machine
            return self._position()
        finally:
            self.machine_state.release(self.machine_state.fail_state())

    def move(self, x: float | None = None, y: float | None = None, z: float | None = None,
             feed_mm_min: float | None = None) -> tuple[float, float, float]:
        """Absolute straight move (G90 G1); returns once the motion is finished.  Not sent
        when it would change nothing (:meth:`_moves_nothing`): each MDI command costs
        linuxcncrsh's 0.1 s."""
        move = f"G90 {straight_move(self.profile, x, y, z, feed_mm_min)}"
        self.machine_state.claim("busy")
        try:
            if not self._moves_nothing(move, x, y, z):
                self._mdi([move])
            return self._position()
        finally:
            self.machine_state.release(self.machine_state.fail_state())

    def _moves_nothing(self, move: str, x: float | None, y: float | None, z: float | None) -> bool:
        """True when ``move`` (``G90 G1 .. F..``) would change nothing: the last command this
        machine ran was its own absolute ``G1`` move at the same feed (so the modal state
        is what ``move`` sets) and the tool is commanded at ``move``'s target already."""
        last = self._last_move
        return (last is not None and last.rpartition(" F")[2] == move.rpartition(" F")[2]
                and written_at(self._commanded(), x, y, z))

    def position(self) -> tuple[float, float, float]:
        """Actual X Y Z in absolute (machine) coordinates (``get abs_act_pos``)."""
        connected(self.link)
        return self._position()

    def _position(self) -> tuple[float, float, float]:
        values = [float(v) for v in connected(self.link).get("abs_act_pos").split()]
        return values[0], values[1], values[2]

    def _commanded(self) -> tuple[float, float, float]:
        """Commanded X Y Z in the coordinates a program's G90 words are in (``get
        rel_cmd_pos``: less the work, G92 and tool offsets): where the last move ended, as
        it was written."""
        values = [float(v) for v in connected(self.link).get("rel_cmd_pos").split()]
        return values[0], values[1], values[2]

    def joint_positions(self) -> list[float]:
        """Every joint's actual position (mm / deg), ``get joint_pos``."""
        return [float(v) for v in connected(self.link).get("joint_pos").split()]

    # ------------------------------------------------------------------ probing
    def probe(self, x: float, y: float, z_start: float | None = None, z_min: float | None = None,
              feed_mm_min: float | None = None) -> ProbeResult:
        """Travel to (x, y) at ``z_start`` (moves that would not move the tool are not
        sent), ``G38.2`` down to ``z_min``, read the trip point, retract to ``z_start``.
        ``ProbeFailed`` (retracted) when nothing is hit; a probe already tripped at the
        start is a ``FirmwareError``."""
        down = probe_down(self.profile, x, y, z_start, z_min, feed_mm_min)
        retract = f"G90 {down.retract}"
        self.machine_state.claim("busy")
        try:
            self._mdi([f"G90 {move}" for move in down.approach_moves(self._commanded())])
            try:
                self._mdi([f"G90 G38.2 Z{down.z_min:.4f} F{down.feed:.1f}"])
            except FirmwareError as exc:
                if _NO_CONTACT not in exc.message:
                    raise
                self._mdi([retract])
                raise probe_missed(down) from exc
            px, py, pz, tripped = self._probe_parameters()
            self._mdi([retract])
            if tripped != 1.0:
                raise ProbeFailed(f"probe at ({x:.3f}, {y:.3f}) did not trip", x=x, y=y,
                                  field="probe", value=[x, y])
            return ProbeResult(px, py, pz)
        finally:
            self.machine_state.release(self.machine_state.fail_state())

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
        check_tool(tool, MAX_TOOL)
        self.machine_state.claim("busy")
        try:
            try:
                self._mdi([f"T{tool} M6"])
            except FirmwareError as exc:
                raise InvalidConfig(f"LinuxCNC refused tool T{tool}: {exc.message}", field="tool",
                                    value=tool) from exc
        finally:
            self.machine_state.release(self.machine_state.fail_state())

    def probe_toward(self, start: tuple[float, float, float], target: tuple[float, float, float],
                     feed_mm_min: float | None = None) -> ProbeResult:
        """Travel to ``start`` (Z up first, then XY, then Z down; a move that would not move
        the tool is not sent: each MDI command costs linuxcncrsh's 0.1 s), ``G38.2`` toward
        ``target`` (any direction), read #5061-#5063, go straight back to ``start``.
        ``ProbeFailed`` when nothing is touched (the machine is back at ``start``)."""
        toward = probe_toward(self.profile, start, target, feed_mm_min)
        back = f"G90 {toward.back}"
        self.machine_state.claim("busy")
        try:
            self._mdi([f"G90 {move}" for move in toward.approach_moves(self._commanded())])
            try:
                self._mdi([f"G90 {toward.command}"])
            except FirmwareError as exc:
                if _NO_CONTACT not in exc.message:
                    raise
                self._mdi([back])
                raise probe_missed(toward) from exc
            px, py, pz, tripped = self._probe_parameters()
            self._mdi([back])
            if tripped != 1.0:
                raise ProbeFailed(f"probe toward {toward.where} did not trip", x=toward.target[0],
                                  y=toward.target[1], field="probe", value=toward.where)
            return ProbeResult(px, py, pz)
        finally:
            self.machine_state.release(self.machine_state.fail_state())

    # ------------------------------------------------------------------ programs
    def stream(self, lines: Iterable[str], on_progress: Callable[[int, int], None] | None = None,
               start_line: int = 0) -> StreamReport:
        """Run the program from command ``start_line`` on the controller (see the module
        docstring); returns when it ended or was cancelled (``set abort``)."""
        from .program_run import resume_preamble, run_program, write_program

        commands = program_commands(lines, start_line)
        total = len(commands)
        st = self.machine_state
        st.claim("printing")
        st.program_started(start_line, total)
        self.clock.start(start_line)
        started = time.monotonic()
        path: str | None = None
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
            # what the controller told before the loss: the commands before the line in
            # motion (program_line) are done; no line is numbered on the wire, nothing is in flight
            executed, _ = st.progress or (start_line, total)
            st.interrupted = InterruptedProgram(total, executed, None, [], reset=False, moved_index=executed,
                                                program_file=path)
            self._stopper.abort(self.console)
            st.release("error")
            exc.resume_line = executed
            raise
        except HardwareError:
            st.release(st.fail_state())
            raise
        st.release("idle")
        return StreamReport(executed, total, start_line, cancelled, time.monotonic() - started, {})

    # ------------------------------------------------------------------ interruption (the
    # same calls as hardware.machine.Machine: the service's interrupted/resume workflow)
    @property
    def acked_line_no(self) -> None:
        """LinuxCNC numbers no lines on the wire (progress is its ``program_line``)."""
        return None

    def adopt_interrupted(self, total: int, acked_index: int, acked_line_no: int | None) -> None:
        """A new process resumes a program an earlier one recorded (before connecting):
        ``InterruptedProgram.adopted``; LinuxCNC numbers no line on the wire, so
        ``acked_line_no`` (always None here) is not used."""
        self.machine_state.interrupted = InterruptedProgram.adopted(total, acked_index, None)

    def resume_line(self) -> int:
        """After reconnecting: the first command not known to be executed, as the record
        tells it (``InterruptedProgram.known_resume``: nothing was in flight).  A program
        the controller still runs is aborted first."""
        gap = self.machine_state.interrupted
        if gap is None:
            raise MachineStateError("no interrupted program to resume", field="state")
        link = self.link
        if link is None or not link.healthy:
            raise MachineStateError("connect before resuming", field="state", value="disconnected")
        if link.get("program_status").upper() != "IDLE":
            link.set("abort")
        start = gap.known_resume()
        assert start is not None  # nothing is ever in flight on LinuxCNC
        return start

    def program_status(self) -> dict[str, Any] | None:
        """The program on this machine, running or interrupted (``MachineState.program_status``)."""
        return self.machine_state.program_status()

    def pause(self) -> None:
        """Pause the running program (the controller decelerates and holds)."""
        st = self.machine_state
        st.require(("printing",), "cannot pause")
        st.live_link.set("pause")
        self.clock.pause()
        st.current = "paused"

    def resume(self) -> None:
        """Continue a paused program."""
        st = self.machine_state
        st.require(("paused",), "cannot resume")
        st.live_link.set("resume")
        self.clock.resume()
        st.current = "printing"

    def cancel(self) -> None:
        """Abort the running program (controlled stop, no emergency stop)."""
        self.machine_state.require(("printing", "paused"), "no program to cancel")
        self.machine_state.cancel_requested = True

    def stop(self) -> None:
        """The service's stop: emergency stop while something runs; ``MachineStateError``
        while idle or disconnected."""
        self.machine_state.require_stoppable()
        self.emergency_stop()

    def emergency_stop(self) -> None:
        """``set estop on`` over the stop session (reopened if it died), never queued behind
        the command session's operation (no claim), until the controller reports it (up to
        ``ESTOP_TRIES`` times, else ``LinkError``); machine -> error."""
        st = self.machine_state
        st.stopping()
        self.homed = False
        self._last_move = None
        try:
            self._stopper.estop(self.console)
        finally:
            st.current = "error"

    def status(self) -> dict[str, object]:
        """JSON-friendly snapshot for the API (state, identity, program progress)."""
        return {**base_status(self.machine_state, self.dialect, self.url, self.identity, self.program_status()),
                "link": None, "fallbacks": []}
