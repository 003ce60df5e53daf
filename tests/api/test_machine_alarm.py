"""A controller alarm through the API: the machine record shows the firmware's state and why,
motion it forbids is a 409 naming the state and how to clear it (never a 502), and the
operator's confirmed unlock clears it (grbl mock)."""

from __future__ import annotations

from tests.api.test_machines import register
from tests.conftest import auth

OP = auth("operator")


def test_an_alarm_shows_refuses_motion_with_409_and_clears_on_a_confirmed_unlock(client):
    row = register(client, dialect="grbl").json()
    base = f"/api/v1/machines/{row['id']}"
    connected = client.post(f"{base}/connect", headers=OP).json()
    assert connected["controller"]["state"] == "Idle" and connected["controller"]["clear"] is None
    assert client.post(f"{base}/jog", json={"dz_mm": 5}, headers=OP).status_code == 200
    miss = client.post(f"{base}/command", json={"command": "G38.2 Z4 F100"}, headers=OP)  # nothing in reach
    assert miss.status_code == 502 and "Probe fail" in miss.text  # the firmware's own answer to that line
    shown = client.get(f"{base}", headers=OP).json()["controller"]
    assert shown["state"] == "Alarm" and shown["reason"].startswith("ALARM:5") and "$X" in shown["clear"]
    for path, body in (("command", {"command": "G1 X1 F100"}), ("jog", {"dx_mm": 1})):
        refused = client.post(f"{base}/{path}", json=body, headers=OP)
        assert refused.status_code == 409, refused.text
        problem = refused.json()
        assert ("Alarm" in problem["detail"] and "$X" in problem["detail"]
                and problem["errors"][0]["loc"][-1] == "controller")
    assert client.post(f"{base}/unlock", json={}, headers=OP).status_code == 422  # the operator must confirm
    assert client.post(f"{base}/unlock", json={"confirm": False}, headers=OP).status_code == 422
    unlocked = client.post(f"{base}/unlock", json={"confirm": True}, headers=OP)
    assert unlocked.status_code == 200 and unlocked.json()["controller"]["state"] == "Idle", unlocked.text
    assert client.post(f"{base}/command", json={"command": "G1 X1 F100"}, headers=OP).status_code == 200


def test_marlin_has_no_unlock(client):
    row = register(client).json()
    base = f"/api/v1/machines/{row['id']}"
    client.post(f"{base}/connect", headers=OP)
    assert client.get(base, headers=OP).json()["controller"] is None
    assert client.post(f"{base}/unlock", json={"confirm": True}, headers=OP).status_code == 409
