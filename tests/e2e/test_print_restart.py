"""Resume on the real processes: `conforma serve` SIGKILLed mid-print and started
again.  The printer (the mock firmware behind a TCP-serial bridge in its own process, see
tests/helpers/mock_tcp_printer.py) outlives the server, as a real one does.  The job comes back
``interrupted``, the printer executes nothing until an operator resumes, and the resumed
job continues from the right command: the firmware executed the program exactly once."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import httpx

from hardware.protocol import normalized_commands
from tests.e2e.test_serve import ROOT, env_for, start
from tests.helpers.mock_tcp_printer import status
from tests.helpers.processes import free_port, stop, wait_healthy

ADMIN = "e2e-admin-key-1"
# ~30 ms per move in real time (1 mm at 2000 mm/min): long enough to kill it midway
PROGRAM = "G21\nG90\n" + "".join(f"G1 X{(i % 20) + 1}.0 Y{(i // 20) % 2}.0 F2000\n" for i in range(100))


def _printer(log) -> tuple[subprocess.Popen, int, int]:  # type: ignore[no-untyped-def]
    port, status_port = free_port(), free_port()
    proc = subprocess.Popen([sys.executable, "-m", "tests.helpers.mock_tcp_printer", "--port", str(port),
                             "--status-port", str(status_port), "--time-scale", "1"],
                            cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    deadline = time.monotonic() + 20
    while True:
        try:
            status(status_port, timeout=0.5)
            return proc, port, status_port
        except OSError:
            assert time.monotonic() < deadline and proc.poll() is None, "mock printer did not start"
            time.sleep(0.05)


def _settled(status_port: int, quiet_s: float = 0.6, timeout: float = 30.0) -> int:
    """The executed count once it stopped moving for ``quiet_s`` (buffered moves drained)."""
    deadline = time.monotonic() + timeout
    last, since = -1, time.monotonic()
    while time.monotonic() < deadline:
        now_count = status(status_port)["executed"]
        if now_count != last:
            last, since = now_count, time.monotonic()
        elif time.monotonic() - since >= quiet_s:
            return last
        time.sleep(0.05)
    raise AssertionError("the printer never settled")


def test_server_killed_mid_print_waits_for_the_operator_and_resumes_exactly_once(tmp_path):
    log = open(tmp_path / "processes.log", "a")  # noqa: SIM115 (closed below)
    printer, printer_port, status_port = _printer(log)
    data = tmp_path / "data"
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    headers = {"Authorization": f"Bearer {ADMIN}"}
    env = env_for(data, CONFORMA_API_KEYS=f"{ADMIN}:admin", CONFORMA_LEASE_S="2", CONFORMA_REAPER_INTERVAL_S="0.2",
                  CONFORMA_SOCKET_HOSTS="127.0.0.1", CONFORMA_COMPUTE_WARM_UP="false")  # a print: no compute job
    server = start(["serve", "--port", str(port)], env, tmp_path / "processes.log")
    try:
        wait_healthy(base, server, log=tmp_path / "processes.log")
        machine = httpx.post(f"{base}/api/v1/machines", json={"name": "tcp", "port": f"socket://127.0.0.1:{printer_port}"},
                             headers=headers).json()
        connected = httpx.post(f"{base}/api/v1/machines/{machine['id']}/connect", headers=headers, timeout=30)
        assert connected.status_code == 200, connected.text
        program = httpx.post(f"{base}/api/v1/programs", files={"file": ("p.gcode", PROGRAM.encode())},
                             headers=headers).json()
        job = httpx.post(f"{base}/api/v1/machines/{machine['id']}/print", json={"program_id": program["id"]},
                         headers=headers).json()
        deadline = time.monotonic() + 30
        while status(status_port)["executed"] < 25:
            assert time.monotonic() < deadline, "the print never got going"
            time.sleep(0.02)
        stop(server, signal.SIGKILL)  # mid-print, no goodbye
        drained = _settled(status_port)
        # the connect's and the program's safe_off ran first, then the program's commands
        safe = normalized_commands([machine["profile"]["dispense_off"], *machine["profile"].get("outputs_off", [])])
        drained -= 2 * len(safe)
        assert 25 - 2 * len(safe) <= drained < 102  # the printer finished what it had buffered, then stopped

        server = start(["serve", "--port", str(port)], env, tmp_path / "processes.log")
        wait_healthy(base, server, log=tmp_path / "processes.log")
        record = httpx.get(f"{base}/api/v1/jobs/{job['id']}", headers=headers).json()
        assert record["status"] == "interrupted", record
        state = record["program_state"]
        assert state["total"] == 102 and 0 < state["executed"] <= drained and state["acked_line_no"]
        time.sleep(1.0)  # restarted, reaped, nobody asked: nothing moves
        assert status(status_port)["executed"] == drained + 2 * len(safe)
        assert httpx.get(f"{base}/api/v1/jobs/{job['id']}", headers=headers).json()["status"] == "interrupted"

        resumed = httpx.post(f"{base}/api/v1/jobs/{job['id']}/resume", json={"confirm": True}, headers=headers)
        assert resumed.status_code == 202, resumed.text
        deadline = time.monotonic() + 60
        while (done := httpx.get(f"{base}/api/v1/jobs/{job['id']}", headers=headers).json())["status"] != "succeeded":
            assert done["status"] in ("queued", "running"), done
            assert time.monotonic() < deadline, "the resumed print did not finish"
            time.sleep(0.1)
        start_line, preamble = done["result"]["start_line"], done["result"]["resume_preamble"]
        print(f"persisted executed {state['executed']}, drained {drained}, resumed from {start_line}")
        assert start_line == drained  # the firmware's line number says exactly where it stopped
        assert done["result"]["resume_location"]["basis"] == "line numbers"  # the evidence, in the record
        assert done["result"]["resume_location"]["start"] == start_line
        commands = normalized_commands(PROGRAM.splitlines())
        # the connect's and the program's safe_off, the program up to the lost link; the Marlin kept
        # running through it: the reconnect sent its safe_off after what it had accepted, then the
        # resume's re-homing and replay (from safe_off)
        assert preamble[1:1 + len(safe)] == safe
        assert status(status_port)["commands"] == \
            safe + safe + commands[:start_line] + safe + preamble + commands[start_line:]
    finally:
        stop(server)
        stop(printer)
        log.close()
