"""Drive the mock firmware with Printrun's ``printcore`` (a host Conforma did not write).

Used by tests/hardware/mock/test_printrun.py and tests/bench/test_bench_printrun.py.
Under ``CI=true`` a missing Printrun is a failure, never a skip."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from tests.helpers.real_components import missing


def load_printcore():  # type: ignore[no-untyped-def]
    """(printcore class, gcoder module), or fail (CI) / skip (elsewhere) when missing."""
    try:
        from printrun import gcoder
        from printrun.printcore import printcore
    except ImportError as exc:
        missing("Printrun's printcore", f"not installed ({exc}); make install adds it")
    return printcore, gcoder


def program(n: int) -> list[str]:
    """``n`` commands of a dispensing program: moves with F words, dispenser on/off, dwells."""
    lines = ["G21", "G90", "G1 Z1.0000 F600.0"]
    i = 0
    while len(lines) < n:
        if i % 50 == 0:
            lines.append("M106 S255")
        elif i % 50 == 49:
            lines.append("M107")
        elif i % 97 == 0:
            lines.append("G4 P0")
        else:
            lines.append(f"G1 X{(i * 0.37) % 80:.4f} Y{(i * 0.61) % 60:.4f} F{1200 + i % 7 * 100}")
        i += 1
    return lines[:n]


@dataclass
class HostRun:
    """What printcore saw: temperature lines, position lines, errors it logged, seconds."""

    temperatures: list[str] = field(default_factory=list)
    positions: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    elapsed_s: float = 0.0


def stream_with_printcore(port: str, lines: list[str], *, query_every_s: float = 0.5,
                          timeout_s: float = 120.0) -> HostRun:
    """Connect printcore to ``port`` (a pty path or ``host:port``), stream ``lines`` with
    its own line numbers, checksums and resend handling, and ask for temperatures
    (``M105``) and positions (``M114``) while it prints, as a host UI does."""
    printcore, gcoder = load_printcore()
    run = HostRun()
    host = printcore()
    host.tempcb = run.temperatures.append
    host.recvcb = lambda line: run.positions.append(line) if line.startswith("X:") else None
    host.errorcb = run.errors.append
    host.connect(port, 115200)
    try:
        deadline = time.monotonic() + 10.0
        while not host.online:
            assert time.monotonic() < deadline, "printcore never saw the printer come online"
            time.sleep(0.01)
        started = time.monotonic()
        assert host.startprint(gcoder.LightGCode(lines))
        next_query = started
        while host.printing:
            now = time.monotonic()
            assert now - started < timeout_s, "printcore did not finish in time"
            if now >= next_query:
                host.send_now("M105")
                host.send_now("M114")
                next_query = now + query_every_s
            time.sleep(0.005)
        run.elapsed_s = time.monotonic() - started
        seen = (len(run.temperatures), len(run.positions))
        host.send_now("M105")
        host.send_now("M114")
        deadline = time.monotonic() + 5.0
        while (len(run.temperatures) <= seen[0] or len(run.positions) <= seen[1]) \
                and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        host.disconnect()
    return run
