"""Manual machine control through the API: home, jog, console, removal — against what the
mock firmware knows, and refused while a program holds the machine."""

from __future__ import annotations

import pytest

from hardware.mock import get_world
from tests.api.test_machines import program_text, register, upload_program
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP, ADMIN = auth("operator"), auth("admin")


@pytest.fixture
def machine(client):  # type: ignore[no-untyped-def]
    row = register(client).json()
    assert client.post(f"/api/v1/machines/{row['id']}/connect", headers=OP).status_code == 200
    return row


def test_home_jog_and_console_move_the_firmware_as_asked(client, machine):
    base = f"/api/v1/machines/{machine['id']}"
    assert client.post(f"{base}/home", headers=OP).status_code == 200
    world = get_world(machine["id"])
    assert world.position == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    jogged = client.post(f"{base}/jog", json={"dx_mm": 5, "dy_mm": -2.5, "dz_mm": 10, "feed_mm_min": 1200}, headers=OP)
    assert jogged.status_code == 200, jogged.text
    assert world.position == pytest.approx((5.0, -2.5, 10.0), abs=1e-6)
    assert jogged.json()["position"] == pytest.approx([5.0, -2.5, 10.0], abs=1e-3)
    again = client.post(f"{base}/jog", json={"dz_mm": -4}, headers=OP)           # relative to where it is
    assert again.status_code == 200 and world.position == pytest.approx((5.0, -2.5, 6.0), abs=1e-6)
    console = client.post(f"{base}/command", json={"command": "M114"}, headers=OP)
    assert console.status_code == 200, console.text
    assert console.json()["command"] == "M114" and any("X:5" in line for line in console.json()["reply"])
    unknown = client.post(f"{base}/command", json={"command": "M9999"}, headers=OP)  # Marlin's own answer
    assert unknown.status_code == 200 and any("Unknown command" in line
                                              for line in unknown.json()["reply"]), unknown.text


@pytest.mark.parametrize("body", ['{}', '{"dx_mm": 0}', '{"dx_mm": 500}', '{"dy_mm": NaN}', '{"dq_mm": 1}'])
def test_bad_jogs_are_422_naming_the_field(client, machine, body):
    response = client.post(f"/api/v1/machines/{machine['id']}/jog", content=body,
                           headers={**OP, "content-type": "application/json"})
    assert response.status_code == 422, response.text
    assert response.json()["errors"][0]["loc"][-1] in ("dx_mm", "dy_mm", "dq_mm")


@pytest.mark.parametrize("command", ["", "G28\nG1 X5", "x" * 97, "M117 ключ"])
def test_bad_console_lines_are_422(client, machine, command):
    response = client.post(f"/api/v1/machines/{machine['id']}/command", json={"command": command}, headers=OP)
    assert response.status_code == 422 and response.json()["errors"][0]["loc"][-1] == "command"


def test_manual_control_waits_while_a_program_holds_the_machine(client):
    row = register(client, time_scale=1.0).json()
    base = f"/api/v1/machines/{row['id']}"
    client.post(f"{base}/connect", headers=OP)
    program = upload_program(client, program_text(400)).json()
    job = client.post(f"{base}/print", json={"program_id": program["id"]}, headers=OP).json()
    wait_for(client, job["id"], states=("running",))
    executed = get_world(row["id"]).executed_count
    for path, body in (("home", None), ("jog", {"dx_mm": 1}), ("command", {"command": "G28"})):
        response = client.post(f"{base}/{path}", json=body, headers=OP)
        assert response.status_code == 409 and response.json()["errors"][0]["loc"][-1] == "machine_id", path
    assert client.delete(base, headers=ADMIN).status_code == 409                  # not even forced
    assert get_world(row["id"]).executed_count >= executed                        # the print goes on
    client.post(f"{base}/stop", headers=OP)


def test_a_used_machine_is_removed_once_its_jobs_ended(client, machine):
    spare = register(client, port="mock://").json()
    assert client.delete(f"/api/v1/machines/{spare['id']}", headers=OP).status_code == 204
    assert client.get(f"/api/v1/machines/{spare['id']}", headers=OP).status_code == 404
    assert client.delete(f"/api/v1/machines/{spare['id']}", headers=OP).status_code == 404
    base = f"/api/v1/machines/{machine['id']}"
    program = upload_program(client, program_text(5)).json()
    done = client.post(f"{base}/print", json={"program_id": program["id"]}, headers=OP).json()
    assert wait_for(client, done["id"])["status"] == "succeeded"
    # an unfinished job: a print connects the machine itself, so it is a long one (400 moves at
    # 10 mm/s) that the cancel below reaches while it runs
    client.post(f"{base}/disconnect", headers=OP)
    long_program = upload_program(client, program_text(400)).json()
    queued = client.post(f"{base}/print", json={"program_id": long_program["id"]}, headers=OP).json()
    refused = client.delete(base, headers=OP)
    assert refused.status_code == 409 and queued["id"] in refused.json()["detail"], refused.text
    assert client.delete(f"{base}?force=true", headers=OP).status_code == 403
    client.post(f"/api/v1/jobs/{queued['id']}/cancel", headers=OP)
    assert wait_for(client, queued["id"])["status"] in ("cancelled", "failed")
    assert client.delete(base, headers=OP).status_code == 204    # finished jobs keep their records
    assert client.get(base, headers=OP).status_code == 404
    assert client.get(f"/api/v1/jobs/{done['id']}", headers=OP).json()["status"] == "succeeded"


def test_reading_a_machine_never_fails_on_the_controller_s_answer(client, machine, monkeypatch):
    """A real controller (no mock world) whose position query fails: the record is read with
    ``position`` null, never a 502 on a GET."""
    from hardware.errors import FirmwareError

    machines = client.app.state.runtime.machines
    live = machines.get(machine["id"])

    def fails() -> tuple[float, float, float]:
        raise FirmwareError("M114 returned no position", command="M114")

    monkeypatch.setattr(machines, "world", lambda row: None)  # as for a serial port
    monkeypatch.setattr(live, "position", fails)
    for url in (f"/api/v1/machines/{machine['id']}", "/api/v1/machines"):
        response = client.get(url, headers=OP)
        assert response.status_code == 200, response.text
    assert response.json()["items"][0]["position"] is None and response.json()["items"][0]["state"] == "idle"


@pytest.mark.parametrize(("command", "words"), [("G99999", "Unsupported command"), ("XYZ", "Bad number format")])
def test_a_console_command_the_firmware_refuses_is_a_422_naming_it(client, command, words):
    """grbl's ``error:N`` about the command itself is the sender's mistake: 422 naming the
    command and the firmware's words; the machine stays ready."""
    row = register(client, dialect="grbl").json()
    base = f"/api/v1/machines/{row['id']}"
    assert client.post(f"{base}/connect", headers=OP).status_code == 200
    refused = client.post(f"{base}/command", json={"command": command}, headers=OP)
    assert refused.status_code == 422, refused.text
    problem = refused.json()
    assert words in problem["detail"] and problem["errors"][0]["loc"][-1] == "command"
    assert problem["errors"][0]["value"] == command
    assert client.get(base, headers=OP).json()["state"] == "idle"
    assert client.post(f"{base}/command", json={"command": "G1 X1 F100"}, headers=OP).status_code == 200
