"""Resume support of ``hardware.machine.Machine`` (a mixin): the modal replay before a
resumed stream, the bound on what really moved when a controller reset (``ok`` means
planned), and draining the lines a controller still runs after it rejected one."""

from __future__ import annotations

from collections import deque

from .errors import FirmwareError, HardwareError
from .resume import executed_bound, modal_preamble, planner_blocks


class ResumeOperations:
    """Mixin of ``Machine`` (uses its link, profile, timeout_s and planner_blocks)."""

    def _replay_modes(self, commands: list[str], start_line: int) -> None:
        """Resuming mid-program: restore units, coordinate system, motion mode, feed, the
        start point, distance mode and the dispenser as the skipped commands left them."""
        self.last_preamble = []
        if start_line == 0:
            return
        p = self.profile
        preamble = modal_preamble(commands, start_line, dispense_on=p.dispense_on,
                                  dispense_off=p.dispense_off, clearance_z=p.clearance_z)
        for command in preamble:
            self.link.send(command, self.timeout_s * 10)
        self.last_preamble = preamble

    def _moved_bound(self, commands: list[str], acked: int, seqs: dict[int, int]) -> int:
        """First command not known to have *moved* (``ok`` = planned): from the planner's
        capacity, tightened by the last grbl status report (Idle: nothing planned; ``Bf:``
        free blocks) that came after some of the acknowledgements."""
        p = self.profile
        blocks = planner_blocks(commands, p.dispense_on, p.dispense_off)
        bound = executed_bound(blocks, acked, self.planner_blocks)
        marks = list(self.link.status_marks) if self.link is not None else []
        for status, completed, _ in reversed(marks):
            done = [i for i, seq in seqs.items() if seq is not None and seq <= completed]
            if not done:
                continue
            free = status.fields.get("Bf", "")
            if status.state.split(":")[0] in ("Idle", "Alarm", "Check"):
                pending = 0
            elif "," in free:
                pending = max(self.planner_blocks - int(free.split(",")[0]), 0)
            else:
                pending = self.planner_blocks
            return max(bound, executed_bound(blocks, max(done) + 1, pending))
        return bound

    def _drain_after_rejection(self, exc: FirmwareError, inflight: deque, executed: int) -> int:
        """A line was rejected: the controller still runs the lines it already holds
        (grbl: up to a buffer's worth).  Wait for each answer; return the index after the
        last one answered, and name the rejected line in ``exc.line_index``."""
        failed, _ = inflight.popleft()
        exc.line_index = failed
        executed = failed + 1
        rejected = [failed]
        while inflight:
            index, pending = inflight.popleft()
            try:
                outcome = pending.result(self.timeout_s * 10, check=False)
            except HardwareError:
                break
            if outcome.status == "error":
                rejected.append(index)
            executed = index + 1
        self.rejected_lines = rejected
        return executed
