"""What the machines page reads: the console log against what the mock firmware executed,
the homed state, the running program's elapsed time and time left, and editing a machine."""

from __future__ import annotations

import time

import pytest

from hardware.mock import get_world
from tests.api.test_machines import program_text, register, upload_program
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP, VIEWER = auth("operator"), auth("viewer")


def _connected(client, **mock):
    row = register(client, **mock).json()
    assert client.post(f"/api/v1/machines/{row['id']}/connect", headers=OP).status_code == 200
    return row, f"/api/v1/machines/{row['id']}"


def _sent_commands(entries):
    """The commands of sent lines, Marlin's line number and checksum taken off."""
    out = []
    for e in entries:
        text = e["text"]
        if text.startswith("N") and "*" in text:
            text = text.split(" ", 1)[1].rsplit("*", 1)[0]
        out.append(text)
    return out


def test_the_console_log_holds_every_command_the_firmware_executed_in_order(client):
    row, base = _connected(client)
    client.post(f"{base}/home", headers=OP)
    client.post(f"{base}/jog", json={"dx_mm": 2}, headers=OP)
    client.post(f"{base}/command", json={"command": "M114"}, headers=OP)
    page = client.get(f"{base}/console", headers=VIEWER).json()
    sent = _sent_commands([e for e in page["entries"] if e["direction"] == "sent"])
    executed = get_world(row["id"]).transcript.commands
    assert executed, "the firmware executed nothing"
    it = iter(sent)
    assert all(any(cmd == s for s in it) for cmd in executed), (executed, sent)  # a subsequence, in order
    received = [e["text"] for e in page["entries"] if e["direction"] == "received"]
    assert any(t.startswith("X:2.00") for t in received)                          # M114's answer after the jog
    seqs = [e["seq"] for e in page["entries"]]
    assert seqs == sorted(seqs) and page["last_seq"] == seqs[-1] and page["dropped"] == 0
    assert client.get(f"{base}/console", params={"after": page["last_seq"]}, headers=VIEWER).json()["entries"] == []
    only = client.get(f"{base}/console", params={"contains": "m114", "direction": "sent"}, headers=VIEWER).json()
    assert only["entries"] and all("M114" in e["text"] for e in only["entries"])
    bad = client.get(f"{base}/console", params={"direction": "both"}, headers=VIEWER)
    assert bad.status_code == 422 and bad.json()["errors"][0]["loc"][-1] == "direction"


def test_homed_is_known_only_after_homing_and_lost_on_an_emergency_stop(client):
    row = register(client).json()
    base = f"/api/v1/machines/{row['id']}"
    assert client.get(base, headers=OP).json()["homed"] is None                    # disconnected: unknown
    assert client.post(f"{base}/connect", headers=OP).json()["homed"] is False
    assert client.post(f"{base}/home", headers=OP).json()["homed"] is True
    client.post(f"{base}/stop", headers=OP)
    assert client.get(base, headers=OP).json()["homed"] is False
    assert client.post(f"{base}/connect", headers=OP).json()["homed"] is False
    homed = client.post(f"{base}/command", json={"command": "G28"}, headers=OP).json()["machine"]
    assert homed["homed"] is True                                                  # homed from the console


def test_a_print_shows_elapsed_time_and_a_time_left_that_comes_true(client):
    row, base = _connected(client, time_scale=1.0)
    program = upload_program(client, program_text(150)).json()
    job = client.post(f"{base}/print", json={"program_id": program["id"]}, headers=OP).json()
    wait_for(client, job["id"], states=("running",))
    seen = None
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        m = client.get(base, headers=OP).json()
        p = m["program"]
        if p and p["eta_s"] is not None and p["line"] < p["total"] * 0.6:
            seen = (time.monotonic(), p)
            break
        time.sleep(0.1)
    assert seen is not None, "no time left was shown while the program ran"
    at, p = seen
    assert p["elapsed_s"] > 0 and p["started_at"] is not None
    assert wait_for(client, job["id"], timeout=60)["status"] == "succeeded"
    actual_left = time.monotonic() - at
    assert p["eta_s"] == pytest.approx(actual_left, rel=0.5), (p, actual_left)  # uniform moves: the rate holds


def test_a_machine_is_renamed_any_time_and_its_profile_changed_only_disconnected(client):
    row, base = _connected(client)
    renamed = client.patch(base, json={"name": "bench left"}, headers=OP)
    assert renamed.status_code == 200 and renamed.json()["name"] == "bench left"
    profile = {**row["profile"], "travel_feed_mm_min": 1234.0, "dispense_on": None}
    refused = client.patch(base, json={"profile": profile}, headers=OP)
    assert refused.status_code == 409 and refused.json()["errors"][0]["loc"][-1] == "profile"
    client.post(f"{base}/disconnect", headers=OP)
    changed = client.patch(base, json={"profile": profile}, headers=OP).json()
    assert changed["profile"]["travel_feed_mm_min"] == 1234.0
    assert changed["profile"]["dispense_on"] == row["profile"]["dispense_on"]        # the dialect's default again
    client.post(f"{base}/connect", headers=OP)
    client.post(f"{base}/jog", json={"dx_mm": 1}, headers=OP)
    assert any("F1234.0" in c for c in get_world(row["id"]).transcript.commands)   # the new profile drives the jog
    assert client.patch(base, json={"port": "mock://other"}, headers=OP).status_code == 422
    assert client.patch(base, json={"name": ""}, headers=OP).status_code == 422
    assert client.patch(base, json={"name": "x"}, headers=VIEWER).status_code == 403
