"""Machine safety through the API on the mock firmware: no motion without an operator,
a port is one machine, one program per machine, one thread per machine."""

from __future__ import annotations

import threading
import time

import pytest
from sqlalchemy import update

from app.platform.models import Job
from hardware.mock import get_world
from hardware.protocol import normalized_commands
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")


def program(n: int, x0: float = 0.0) -> str:
    return "G21\nG90\n" + "".join(f"G1 X{x0 + (i % 40) * 0.5:.2f} Y{(i // 40) * 0.5:.2f} F3000\n" for i in range(n))


def make_machine(client, **mock) -> dict:
    response = client.post("/api/v1/machines", json={"name": "m", "port": "mock://", "dialect": "marlin",
                                                     "mock": mock}, headers=OP)
    assert response.status_code == 201, response.text
    return response.json()


def upload(client, text: str) -> dict:
    return client.post("/api/v1/programs", files={"file": ("p.gcode", text.encode())}, headers=OP).json()


def start_print(client, machine: dict, prog: dict):
    return client.post(f"/api/v1/machines/{machine['id']}/print", json={"program_id": prog["id"]}, headers=OP)


def safe_off(client, machine: dict) -> list[str]:
    """The machine profile's ``safe_off`` commands as the firmware's transcript records them."""
    profile = client.get(f"/api/v1/machines/{machine['id']}", headers=OP).json()["profile"]
    return normalized_commands([profile["dispense_off"], *profile.get("outputs_off", [])])


def executed(client, machine: dict) -> int:
    """Commands the mock firmware executed; 0 before the print job has connected it (a job is
    ``running`` from its claim, the mock's world exists from the connect)."""
    return client.get(f"/api/v1/machines/{machine['id']}", headers=OP).json()["mock"].get("executed_commands", 0)


def test_row1_a_dropped_link_interrupts_the_print_and_only_the_operator_resumes_it(client):
    machine = make_machine(client, faults={"disconnect_at_line": 150})
    text = program(300)
    prog = upload(client, text)
    job = start_print(client, machine, prog).json()
    interrupted = wait_for(client, job["id"], states=("interrupted", "succeeded", "failed"), timeout=60)
    assert interrupted["status"] == "interrupted", interrupted
    state = interrupted["program_state"]
    assert state["total"] == 302 and 0 < state["executed"] <= 150 and state["reason"].startswith("LinkError")
    assert state["position"] is not None and state["acked_line_no"] is not None
    frozen = executed(client, machine)
    time.sleep(0.6)  # longer than a reaper pass and a lease third: nothing moves, nothing requeues
    assert executed(client, machine) == frozen
    assert client.get(f"/api/v1/jobs/{job['id']}", headers=OP).json()["status"] == "interrupted"
    # the interrupted job holds the machine: no other program may start meanwhile
    other = start_print(client, machine, prog)
    assert other.status_code == 409 and other.json()["errors"][0]["loc"] == ["params", "machine_id"]
    assert client.post(f"/api/v1/jobs/{job['id']}/resume", json={}, headers=OP).status_code == 422
    assert client.post(f"/api/v1/jobs/{job['id']}/resume", json={"confirm": True}, headers=OP).status_code == 202
    done = wait_for(client, job["id"], timeout=60)
    assert done["status"] == "succeeded", done["error"]
    start, preamble = done["result"]["start_line"], done["result"]["resume_preamble"]
    # re-homed, then the modal state the skipped commands left replayed (units, modes, start point, feed)
    assert preamble[0] == "G28" and "G21" in preamble and start == done["program_state"]["resumed_from"]
    commands = normalized_commands(text.splitlines())
    # the program started with its outputs off; the Marlin kept running through the dropped link:
    # the reconnect sent its safe_off after what it had accepted (it would dispense while it
    # waited otherwise); the resume starts from safe_off again, then the modal replay
    safe = safe_off(client, machine)
    assert preamble[1:1 + len(safe)] == safe
    # what the firmware executed: the connect's safe_off, the program exactly once, with the
    # re-homing before the resume point
    assert get_world(machine["id"]).transcript.commands == \
        safe + safe + commands[:start] + safe + preamble + commands[start:]


def test_row1_the_reaper_interrupts_a_machine_job_whose_process_died(client):
    machine = make_machine(client)
    prog = upload(client, program(5))
    runtime = client.app.state.runtime
    job = runtime.submit("print", {"machine_id": machine["id"], "program_id": prog["id"]})
    done = wait_for(client, job.id)
    assert done["status"] == "succeeded"
    # pretend it is running in a process that died: expired lease, someone else's worker
    with runtime.engine.begin() as conn:
        conn.execute(update(Job).where(Job.id == job.id).values(status="running", worker="gone:1:2", attempts=1,
                                                                lease_until=time.time() - 1, finished_at=None))
    assert job.id not in runtime.reap_once()
    after = client.get(f"/api/v1/jobs/{job.id}", headers=OP).json()
    assert after["status"] == "interrupted" and after["attempts"] == 1 and after["error"] is None
    assert client.post(f"/api/v1/jobs/{job.id}/abandon", headers=OP).json()["status"] == "cancelled"
    assert client.post(f"/api/v1/jobs/{job.id}/abandon", headers=OP).status_code == 409
    with runtime.engine.begin() as conn:  # and at start-up of the process that owns the machines
        conn.execute(update(Job).where(Job.id == job.id).values(status="running", worker="gone:1:2"))
    assert runtime.store.interrupt_orphans(f"{runtime.worker_id}:") == [job.id]


@pytest.mark.parametrize("device", ["/dev/null", "/dev/zero", "/dev/mem", "/dev/watchdog", "/dev/ttyCONFORMA_NONE",
                                    "/dev/shm"])
def test_only_what_the_kernel_calls_a_terminal_is_a_machine_port(client, device):
    response = client.post("/api/v1/machines", json={"name": "x", "port": device}, headers=OP)
    assert response.status_code == 422 and response.json()["errors"][0]["loc"] == ["port"], response.text


def test_row2_one_record_per_physical_port(client, tmp_path):
    first = client.post("/api/v1/machines", json={"name": "a", "port": "/dev/tty"}, headers=OP)
    assert first.status_code == 201
    for alias in ("/dev/./tty", "/dev/../dev/tty"):
        again = client.post("/api/v1/machines", json={"name": "b", "port": alias}, headers=OP)
        assert again.status_code == 409 and again.json()["errors"][0]["loc"] == ["port"], again.text
    for bad in ("/dev/../etc/passwd", "/dev/../tmp/ttyUSB0"):  # real path outside /dev
        response = client.post("/api/v1/machines", json={"name": "c", "port": bad}, headers=OP)
        assert response.status_code == 422 and response.json()["errors"][0]["loc"] == ["port"], response.text
    foreign = client.post("/api/v1/machines", json={"name": "d", "port": "socket://192.0.2.7:23"}, headers=OP)
    assert foreign.status_code == 422 and "allow-list" in foreign.json()["detail"]
    local = client.post("/api/v1/machines", json={"name": "e", "port": "socket://LOCALHOST:2323"}, headers=OP)
    assert local.status_code == 201
    same = client.post("/api/v1/machines", json={"name": "f", "port": "socket://localhost:2323"}, headers=OP)
    assert same.status_code == 409 and same.json()["errors"][0]["loc"] == ["port"]
    assert len({make_machine(client)["id"] for _ in range(2)}) == 2  # each mock record is its own machine


def test_row3_an_operator_disconnect_cancels_the_print_and_it_stays_stopped(client):
    machine = make_machine(client, time_scale=1.0)
    prog = upload(client, program(60))
    job = start_print(client, machine, prog).json()
    wait_for(client, job["id"], states=("running",))
    while executed(client, machine) < 3:
        time.sleep(0.02)
    assert client.post(f"/api/v1/machines/{machine['id']}/disconnect", headers=OP).status_code == 200
    done = wait_for(client, job["id"], timeout=20)
    assert done["status"] == "cancelled" and "disconnected" in done["error"]["detail"]
    frozen = executed(client, machine)
    time.sleep(0.8)  # what the firmware had buffered may finish; the job never reconnects
    settled = executed(client, machine)
    time.sleep(0.8)
    assert executed(client, machine) == settled < 62 and frozen <= settled
    assert client.get(f"/api/v1/machines/{machine['id']}", headers=OP).json()["state"] == "disconnected"


@pytest.mark.parametrize("early_check", [True, False])
def test_row4_eight_simultaneous_prints_on_one_machine_exactly_one_accepted(client, monkeypatch, early_check):
    if not early_check:  # the friendly check-before-insert off: the unique index alone decides
        monkeypatch.setattr("app.jobs.kinds.print_program.refuse_if_machine_busy", lambda *_: None)
    machine = make_machine(client, time_scale=1.0)
    prog = upload(client, program(20))
    barrier = threading.Barrier(8)
    codes: list[int] = []
    bodies: list[dict] = []

    def submit() -> None:
        barrier.wait()
        response = start_print(client, machine, prog)
        codes.append(response.status_code)
        bodies.append(response.json())

    threads = [threading.Thread(target=submit) for _ in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(30)
    assert sorted(codes) == [202] + [409] * 7, codes
    assert all(b["errors"][0]["loc"] == ["params", "machine_id"] for b in bodies if b.get("status") == 409)
    jobs = client.get("/api/v1/jobs?kind=print", headers=OP).json()
    assert jobs["total"] == 1
    client.post(f"/api/v1/jobs/{jobs['items'][0]['id']}/cancel", headers=OP)


def test_row5_a_print_on_machine_b_does_not_wait_for_machine_a(client):
    slow = make_machine(client, time_scale=1.0)
    fast = make_machine(client)
    long_job = start_print(client, slow, upload(client, program(400))).json()
    wait_for(client, long_job["id"], states=("running",))
    started = time.monotonic()
    quick = start_print(client, fast, upload(client, program(50, x0=1.0))).json()
    done = wait_for(client, quick["id"], timeout=20)
    assert done["status"] == "succeeded" and time.monotonic() - started < 5
    assert client.get(f"/api/v1/jobs/{long_job['id']}", headers=OP).json()["status"] == "running"
    assert client.post(f"/api/v1/jobs/{long_job['id']}/cancel", headers=OP).status_code == 202
    assert wait_for(client, long_job["id"])["status"] == "cancelled"


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_emergency_stop_through_the_api_ends_the_print_at_the_stop(client, dialect):
    response = client.post("/api/v1/machines", json={"name": "m", "port": "mock://", "dialect": dialect,
                                                     "mock": {"time_scale": 1.0}}, headers=OP)
    machine = response.json()
    job = start_print(client, machine, upload(client, program(80))).json()
    wait_for(client, job["id"], states=("running",))
    while executed(client, machine) < 3:
        time.sleep(0.02)
    stop = client.post(f"/api/v1/machines/{machine['id']}/stop", headers=OP)
    assert stop.status_code == 200 and stop.json()["stop_sent"] and stop.json()["state"] == "error"
    at_stop = executed(client, machine)
    done = wait_for(client, job["id"], timeout=20)
    assert done["status"] == "cancelled" and "emergency stop" in done["error"]["detail"]
    time.sleep(0.5)
    assert executed(client, machine) == at_stop  # nothing ran after the stop
    assert client.get(f"/api/v1/machines/{machine['id']}", headers=OP).json()["state"] == "error"


def test_row1_a_print_queued_before_a_restart_waits_for_the_operator(client):
    machine = make_machine(client)
    prog = upload(client, program(5))
    runtime = client.app.state.runtime
    job = runtime.submit("print", {"machine_id": machine["id"], "program_id": prog["id"]})
    wait_for(client, job.id)
    with runtime.engine.begin() as conn:  # as if the server died before the job started
        conn.execute(update(Job).where(Job.id == job.id).values(status="queued", worker=None, finished_at=None,
                                                                result=None, program_state=None))
    before = executed(client, machine)
    assert runtime.store.interrupt_orphans(f"{runtime.worker_id}:") == [job.id]
    runtime.enqueue(job.id, "machine")  # a stale queue message must not start it either
    time.sleep(0.3)
    assert client.get(f"/api/v1/jobs/{job.id}", headers=OP).json()["status"] == "interrupted"
    assert executed(client, machine) == before
    assert client.post(f"/api/v1/jobs/{job.id}/resume", json={"confirm": True}, headers=OP).status_code == 202
    done = wait_for(client, job.id)
    assert done["status"] == "succeeded" and done["result"]["start_line"] == 0 and done["result"]["resumes"] == 0
    assert executed(client, machine) == before + len(safe_off(client, machine)) + 7  # safe_off, then the program
