"""An emergency stop is never refused or misdirected: a valid key is never throttled by
someone else's wrong keys, and one physical port is one machine whatever spelling names it."""

from __future__ import annotations

import socket

import pytest

from tests.conftest import auth

OP = auth("operator")


def _mock_machine(client, headers: dict) -> str:
    response = client.post("/api/v1/machines", json={"name": "bench", "port": "mock://bench", "dialect": "grbl"},
                           headers=headers)
    assert response.status_code == 201, response.text
    machine_id = response.json()["id"]
    assert client.post(f"/api/v1/machines/{machine_id}/connect", headers=headers).json()["state"] == "idle"
    return machine_id


def test_stop_with_a_stored_key_is_delivered_after_a_thousand_wrong_keys(client):
    """1,000 wrong keys from the operator's address, then STOP (and STOP ALL's machine list)
    with a stored key (as ``conforma keys create`` and the first start make): delivered to the
    firmware (the mock's own count of stops), not a 429."""
    _record, stored = client.app.state.keyring.create("operator", "operator at the machine")
    mine = {"Authorization": f"Bearer {stored}"}
    machine_id = _mock_machine(client, mine)
    world = client.app.state.runtime.machines.world_by_id(machine_id)
    codes = [client.post(f"/api/v1/machines/{machine_id}/stop",
                         headers={"Authorization": f"Bearer wrong-{i}"}).status_code
             for i in range(1000)]
    assert codes.count(401) == 20 and codes.count(429) == 980          # the guessing is throttled
    assert world.stats.stops == 0
    listed = client.get("/api/v1/machines", headers=mine)                 # STOP ALL lists the machines first
    assert listed.status_code == 200 and [m["id"] for m in listed.json()["items"]] == [machine_id]
    stop = client.post(f"/api/v1/machines/{machine_id}/stop", headers=mine)
    assert stop.status_code == 200, stop.text
    assert stop.json()["stop_sent"] is True and world.stats.stops == 1   # the firmware took it
    wrong = client.post(f"/api/v1/machines/{machine_id}/stop", headers={"Authorization": "Bearer wrong-again"})
    assert wrong.status_code == 429                                       # still throttled for wrong keys
    client.app.state.keyring.revoke(_record.id)
    revoked = client.post(f"/api/v1/machines/{machine_id}/stop", headers=mine)
    assert revoked.status_code == 429 and world.stats.stops == 1          # a revoked key is a wrong key again


def _listening_port() -> socket.socket:
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen()
    return server


@pytest.mark.parametrize(("first", "second"), [
    ("socket://127.0.0.1:{p}", "socket://localhost:{p}"),
    ("socket://LOCALHOST:{p}", "socket://127.0.0.1:{p}"),
    ("linuxcnc://127.0.0.1:{p}", "linuxcnc://localhost:{p}?joints=3"),
    ("linuxcnc://localhost:{p}?joints=5", "socket://127.0.0.1:{p}"),
    ("linuxcnc://LocalHost:{p}?joints=3", "linuxcnc://127.0.0.1:{p}?joints=5"),
])
def test_two_spellings_of_one_port_are_refused_as_a_second_machine(client, first, second):
    with _listening_port() as server:
        port = server.getsockname()[1]
        a = client.post("/api/v1/machines", json={"name": "a", "port": first.format(p=port),
                                                  "dialect": "linuxcnc" if first.startswith("linuxcnc") else "grbl"},
                        headers=OP)
        assert a.status_code == 201, a.text
        b = client.post("/api/v1/machines", json={"name": "b", "port": second.format(p=port),
                                                  "dialect": "linuxcnc" if second.startswith("linuxcnc") else "grbl"},
                        headers=OP)
        assert b.status_code == 409, b.text
        assert a.json()["id"] in b.json()["detail"] and b.json()["errors"][0]["loc"][-1] == "port"
        other = client.post("/api/v1/machines", json={"name": "c", "port": f"socket://127.0.0.1:{port + 1}",
                                                      "dialect": "grbl"}, headers=OP)
        assert other.status_code == 201, other.text                   # another port is another machine


def test_two_names_of_one_device_are_refused_as_a_second_machine(client):
    assert client.post("/api/v1/machines", json={"name": "a", "port": "/dev/tty", "dialect": "grbl"},
                       headers=OP).status_code == 201
    again = client.post("/api/v1/machines", json={"name": "b", "port": "/dev/../dev/tty", "dialect": "grbl"},
                        headers=OP)
    assert again.status_code == 409, again.text


def test_a_second_record_of_a_connected_port_cannot_connect():
    """Records stored before their spellings were normalised: while one is connected, the
    other cannot connect (so its STOP cannot answer ``stop_sent`` for a link that is not the
    moving machine's)."""
    from types import SimpleNamespace

    from app.domain.errors import Conflict
    from app.machines.live import MachineManager
    from app.platform.models import Machine

    manager = MachineManager(lambda _part_id: None)
    manager._machines["mach_a"] = SimpleNamespace(url="socket://localhost:5999", state="printing")
    duplicate = Machine(id="mach_b", name="b", port="socket://127.0.0.1:5999", dialect="grbl")
    with pytest.raises(Conflict) as info:
        manager.connect(duplicate)
    assert "mach_a" in str(info.value) and info.value.field == "port"
