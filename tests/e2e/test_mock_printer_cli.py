"""`conforma mock-printer --pty` as a process: Printrun's printcore streams a program to the
printed pty path; on SIGTERM the command prints what the firmware executed, which must be
the program's digest."""

from __future__ import annotations

import signal
import subprocess
import sys

from hardware.protocol import commands_sha256
from tests.hardware.mock.printrun_host import load_printcore, program, stream_with_printcore
from tests.helpers.processes import stop


def test_printcore_streams_to_the_mock_printer_command():
    load_printcore()
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "mock-printer", "--pty",
                             "--set", "checksum_rate=0.01", "--set", "seed=4", "--seconds", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        first = proc.stdout.readline().split()
        assert first[0] == "pty" and first[1].startswith("/dev/"), first
        lines = program(300)
        stream_with_printcore(first[1], lines)
    finally:
        stop(proc, signal.SIGTERM)
    out = proc.stdout.read()
    digest = commands_sha256(lines)
    assert f"executed {digest.count} commands sha256 {digest.sha256}" in out, out


def test_mock_printer_refuses_a_bad_option():
    done = subprocess.run([sys.executable, "-m", "app.cli", "mock-printer", "--pty",
                           "--set", "checksum_rate=2"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "checksum_rate" in done.stderr


def test_mock_printer_listens_on_loopback_unless_told_and_warns_when_told():
    for host, warned in ((None, False), ("0.0.0.0", True)):
        args = [sys.executable, "-m", "app.cli", "mock-printer", "--pty", "--tcp", "0", "--seconds", "0.2"]
        done = subprocess.run(args + (["--host", host] if host else []), capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stderr
        address = next(line for line in done.stdout.splitlines() if line.startswith("tcp ")).split()[1]
        assert address.startswith("0.0.0.0:" if host else "127.0.0.1:")
        assert ("warning: listening on 0.0.0.0" in done.stderr) is warned, done.stderr
