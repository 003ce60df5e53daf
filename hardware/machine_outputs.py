"""Process outputs and the interrupted program of ``hardware.machine.Machine`` (a mixin).

``connect`` (after identifying), a ``disconnect`` of an idle machine on a healthy link, and
every ``stream`` before its first command send the profile's ``safe_off`` (``dispense_off``
+ ``outputs_off``): a program starts with every output off unless it turns one on.  A
controller that kept running through a lost link gets it queued after what it had accepted;
a grbl locked in Alarm gets none (it refuses G-code; its reset switched spindle and coolant
off).  ``emergency_stop`` cannot send anything after the stop: what the firmware's own stop
leaves on is ``Dialect.estop_keeps`` (Marlin's ``kill()`` keeps fan and ``M42`` outputs
until the board resets, i.e. the reconnect).  ``outputs`` (``status()["outputs"]``) says
when ``safe_off`` was last sent, or why not.  ``program_status`` is what ``status()`` says
of the program: running, or interrupted and waiting for an operator."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .errors import FirmwareError, FirmwareReset

if TYPE_CHECKING:
    from .machine_host import SerialHost

DISCONNECT_SAFE_OFF_S = 5.0  # longest a disconnect waits for its safe_off to be answered


class OutputOperations:
    """Part of ``Machine`` (what it uses of it: ``hardware.machine_host.SerialHost``); sets
    ``outputs``."""

    outputs: dict[str, Any] | None

    def _outputs_off_on_connect(self: SerialHost, reset: bool) -> None:
        """Every process output off once connected (``safe_off``): whatever an earlier
        connection, another host or the board's own state left on goes off before anything
        else runs.

        A controller that kept running through a lost link (a Marlin board that does not
        reset on connect) still holds the interrupted program's outputs, dispensing while it
        waits.  Its queue must stay intact for the resume: settle where the program stands
        by line numbers first (``resume_line``, so the resume is unchanged by what follows),
        then send ``safe_off``: it is queued after the moves the controller accepted, and a
        resume's modal replay turns the dispenser back on where the program had it on.
        A controller that refuses G-code at connect (grbl booting in Alarm: every G-code
        line is ``error:9``) gets nothing: its reset already switched spindle and coolant
        off (see ``_send_safe_off``)."""
        gap = self._interrupted
        kept_running = gap is not None and not (reset or gap.reset or self.rules.resets_on_connect
                                                or not self.rules.line_numbers)
        if kept_running and gap is not None:
            try:
                settled = self.resume_line()
            except FirmwareReset:  # it restarted after all: its outputs are off, numbering starts again
                gap.reset = True
                self.live_link.reset_line_numbers(1)
            else:
                gap.acked_index, gap.inflight = settled, []
        self._send_safe_off("connect")

    def _send_safe_off(self: SerialHost, when: str, timeout_s: float | None = None) -> bool:
        """Send the profile's ``safe_off`` (``when``: connect, disconnect, program) and note
        it in ``outputs`` (for ``status()``); False when the controller refuses G-code in
        its current state and the commands were not sent.

        grbl refuses every G-code line in Alarm with ``error:9`` (protocol.c,
        ``protocol_main_loop``: "Everything else is gcode. Block if in alarm or jog mode."
        -> ``STATUS_SYSTEM_GC_LOCK``); it is only in Alarm after a reset, and every reset
        runs ``mc_reset()`` ("Kill spindle and coolant": ``spindle_stop(); coolant_stop();``,
        motion_control.c) and re-initialises with ``spindle_init(); coolant_init();``
        (main.c): its outputs are off already.  A command the firmware does not have
        (grbl ``error:20``, ``Dialect.unknown_error``: e.g. a Marlin fan command in a grbl
        profile) switches no output of it: noted in ``outputs["why"]``, the others still go."""
        known = self.controller
        if known is not None and known.locks_motion and self.rules.lock_error is not None:
            self.outputs = {"safe_off": when, "sent": False,
                            "why": f"the controller is in {known.name}: its reset switched its outputs off"}
            return False
        wait = self.timeout_s * 10 if timeout_s is None else timeout_s
        unknown: list[str] = []
        for command in self.profile.safe_off:
            try:
                self.live_link.send(command, wait)
            except FirmwareError as exc:
                if exc.code is not None and exc.code == self.rules.unknown_error:
                    unknown.append(command)  # no such output on this firmware: it cannot be on
                    continue
                if exc.code is None or exc.code != self.rules.lock_error:
                    raise
                self.outputs = {"safe_off": when, "sent": False,
                                "why": "the controller refused G-code (locked): its reset switched its outputs off"}
                return False
        self.outputs = {"safe_off": when, "sent": True, "why": None if not unknown else (
            f"the controller does not know {', '.join(unknown)} (error:{self.rules.unknown_error}): "
            "the profile names an output this firmware does not have")}
        return True

    def _note_estop_outputs(self: SerialHost) -> None:
        """After an emergency stop nothing more can be sent: note what the firmware's own
        stop leaves on (``Dialect.estop_keeps``) until the reconnect resets it."""
        kept = [c for c in (self.profile.dispense_on, *self.profile.safe_off) if self.rules.keeps_through_estop(c)]
        words = ", ".join(dict.fromkeys(c.split()[0] for c in kept))
        self.outputs = {"safe_off": "emergency stop", "sent": False, "why": (
            f"the firmware's stop leaves {words} outputs as they were until the controller resets: connect again"
            if kept else "the controller's emergency stop switched its outputs off")}

    def program_status(self: SerialHost) -> dict[str, Any] | None:
        """The program on this machine: while it runs ``{"state": "printing"|"paused",
        "line", "total"}`` (commands acknowledged so far, of the total); after it stopped on
        a lost link or a rejected line ``{"state": "interrupted", "line", "total",
        "resume_line"}``: commands known processed, and the first command a resume would
        send when that is known without asking the controller (a controller that reset: its
        planner bound or a located resume; a Marlin that kept running: once the reconnect
        settled it by line numbers), else None.  The interrupted program waits for an
        operator to resume (``stream(start_line=...)``) or abandon it; None when neither."""
        state = self.state
        if self.progress is not None and state in ("printing", "paused"):
            executed, total = self.progress
            return {"state": state, "line": executed, "total": total}
        gap = self._interrupted
        if gap is None:
            return None
        located = self.last_resume
        if located is not None:
            resume: int | None = located.start
        elif self.rules.resets_on_connect or gap.reset:
            resume = gap.moved_index if gap.moved_index is not None else gap.acked_index
        else:
            resume = None if gap.inflight else gap.acked_index
        return {"state": "interrupted", "line": gap.acked_index, "total": gap.total, "resume_line": resume}
