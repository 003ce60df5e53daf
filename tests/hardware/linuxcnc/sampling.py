"""Joint positions sampled from a running program's dispensing lines (the print-path tests).

A thread polls the machine's own linuxcncrsh session (serialised with the machine's polling:
concurrent sessions sometimes receive each other's replies) for ``program_line`` and
``joint_pos`` while the stream runs, and keeps the joints read while the program was between
two file lines.  Until the stream opens its program, ``program_line`` still reads the last
line of the program the controller ran before (another test's, on a shared simulator) while
the joints rest at home: lines count only after this program's own start was seen (line 0
after ``set open``, or a line at or before the first sampled one).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class LineSampler:
    """``with LineSampler(link, after, before, joints) as s: machine.stream(program)``;
    ``s.samples``: (n, joints) joint positions (mm, degrees) read while the file line was
    strictly between ``after`` and ``before`` (the same line read before and after the joints).
    ``each(n)``: called after the n-th sample is kept (extra reads on the same session)."""

    POLL_S = 0.0005

    def __init__(self, link, after: int, before: int, joints: int,
                 each: Callable[[int], None] | None = None) -> None:
        self.link, self.after, self.before, self.joints, self.each = link, after, before, joints, each
        self.samples: list[list[float]] = []
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run)

    def line(self) -> int:
        return int(self.link.get("program_line"))

    def _run(self) -> None:
        started = False
        while not self._done.is_set():
            line = self.line()
            joints = [float(v) for v in self.link.get("joint_pos", words=self.joints).split()[:self.joints]]
            started = started or line <= self.after
            if started and self.after < line < self.before and self.line() == line:
                self.samples.append(joints)
                if self.each is not None:
                    self.each(len(self.samples))
            time.sleep(self.POLL_S)

    def __enter__(self) -> LineSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._done.set()
        self._thread.join(5)
