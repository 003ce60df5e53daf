"""Sample a running LinuxCNC's HAL pins (and its task state) from the controller's side.

Run with the *system* Python, which has LinuxCNC's ``hal`` and ``linuxcnc`` modules (the
project's venv does not): ``SimController.watch`` starts it in the simulator's
environment.  It imports nothing of Conforma.

    python3 hal_watch.py PERIOD_S MAX_S NAME [NAME ...]

NAME is a HAL pin / signal (read with ``hal.get_value``) or ``task_state`` (the
controller's reported task state, ``linuxcnc.stat().task_state``: 1 = ESTOP).  Every
PERIOD_S it reads them all and, when any value changed, prints one line
``<CLOCK_MONOTONIC ns> <value> ...`` (booleans as 0/1), flushed.  The clock is the one
``time.monotonic_ns()`` reads in any process on the host, so a test can compare these
times with the moment it issued a command.  It stops after MAX_S or on SIGTERM.

The pins are read one after another, and a busy host can pause this process between two
reads while the servo thread moves on: a line would pair one servo period's X with a later
period's Z.  So each line is a pass of reads repeated at once and printed only when both
passes agree (no pin changed between its two reads: every value held at the moment between
the passes).
"""

import os
import signal
import sys
import time
from typing import Any


def main(argv):
    period, limit, names = float(argv[1]), float(argv[2]), argv[3:]
    import hal  # LinuxCNC's, system Python only
    component = hal.component(f"conforma-watch-{os.getpid()}")  # get_value needs one
    component.ready()
    stat: Any = None  # linuxcnc.stat() when task_state is watched
    if "task_state" in names:
        import linuxcnc
        stat = linuxcnc.stat()
    running = [True]
    signal.signal(signal.SIGTERM, lambda *_: running.__setitem__(0, False))

    def read(name):
        if name == "task_state":
            stat.poll()
            return stat.task_state
        value = hal.get_value(name)
        return int(value) if isinstance(value, bool) else value

    out = sys.stdout
    last = None
    end = time.monotonic() + limit
    out.write("ready\n")
    out.flush()
    try:
        while running[0] and time.monotonic() < end:
            try:
                values = [read(name) for name in names]
                if [read(name) for name in names] != values:  # the servo thread ran between the reads
                    continue
            except SystemError:  # linuxcnc.stat.poll() now and then "returned NULL": read again
                time.sleep(period)
                continue
            now = time.monotonic_ns()
            if values != last:
                out.write(f"{now} " + " ".join(repr(v) for v in values) + "\n")
                out.flush()
                last = values
            time.sleep(period)
    finally:
        component.exit()


if __name__ == "__main__":
    main(sys.argv)
