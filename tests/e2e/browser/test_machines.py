"""The machines page: register a mock machine, connect, watch a print, press the
emergency stop and see the state change; an interrupted print shows on its card with the
job that waits and what to do."""

from __future__ import annotations

import time

from tests.e2e.browser.conftest import screenshot

# A slow program on a real-time mock: long enough to still be printing when stopped.
SLOW_PROGRAM = "G21\nG90\nG1 X1 Y0 Z5 F600\n" + "".join(f"G1 X{10 + i} Y{i % 7} F30\n" for i in range(40))


def test_emergency_stop_changes_the_machine_state(page, served):
    api = served.api()
    assert api.get("/api/v1/machines").status_code == 200
    page.goto("/machines.html")
    page.fill("#m-name", "browser-mock")
    page.fill("#m-time-scale", "1")
    page.click("#register-machine")
    card = page.wait_for_selector('.machine-card:has-text("browser-mock")')
    machine_id = card.get_attribute("data-id")
    sel = f'.machine-card[data-id="{machine_id}"]'
    page.click(f"{sel} .act-connect")
    page.wait_for_selector(f'{sel} [data-state="idle"]')

    # the stop is sent even to an idle machine (the firmware decides): Marlin halts until reconnected
    page.click(f"{sel} .estop")
    page.wait_for_selector(f'{sel} [data-state="error"]')
    page.click(f"{sel} .act-connect")
    page.wait_for_selector(f'{sel} [data-state="idle"]')

    program = api.post("/api/v1/programs", files={"file": ("slow.gcode", SLOW_PROGRAM.encode())}).json()
    started = api.post(f"/api/v1/machines/{machine_id}/print", json={"program_id": program["id"]})
    assert started.status_code == 202, started.text
    page.wait_for_selector(f'{sel} [data-state="printing"]', timeout=15_000)
    assert "line" in page.inner_text(f"{sel} .program")
    screenshot(page, "machines")
    page.click(f"{sel} .estop")
    page.wait_for_selector(f'{sel} [data-state="error"]')
    # Marlin's kill() leaves a fan output (the default dispenser, M106) as it was until the board resets
    page.wait_for_selector(f'{sel} .outputs:has-text("M106")')
    assert "connect again" in page.inner_text(f"{sel} .outputs")
    t0 = time.monotonic()
    status = api.get(f"/api/v1/machines/{machine_id}").json()
    assert status["state"] == "error" and time.monotonic() - t0 < 5
    assert page.js_errors == []


def test_an_interrupted_print_shows_on_the_card(page, served):
    api = served.api()
    made = api.post("/api/v1/machines", json={"name": "cut-link", "port": "mock://", "dialect": "marlin",
                                              "mock": {"faults": {"disconnect_at_line": 20}}})
    assert made.status_code == 201, made.text
    machine_id = made.json()["id"]
    program = api.post("/api/v1/programs", files={"file": ("cut.gcode", (
        "G21\nG90\n" + "".join(f"G1 X{i % 9} Y{i // 9} F3000\n" for i in range(60))).encode())}).json()
    job = api.post(f"/api/v1/machines/{machine_id}/print", json={"program_id": program["id"]}).json()
    deadline = time.monotonic() + 60
    while (record := api.get(f"/api/v1/jobs/{job['id']}").json())["status"] != "interrupted":
        assert record["status"] in ("queued", "running") and time.monotonic() < deadline, record
        time.sleep(0.1)
    state = record["program_state"]
    page.goto("/machines.html")
    sel = f'.machine-card[data-id="{machine_id}"]'
    page.wait_for_selector(f'{sel} .program[data-state="interrupted"]', timeout=15_000)
    text = page.inner_text(f"{sel} .program")
    assert text.startswith(f"interrupted at line {state['executed']} of {state['total']}"), text
    assert "its print job waits: resume or abandon" in text and job["id"] not in text, text
    assert f"(job {job['id']})" in page.get_attribute(f"{sel} .program", "title")  # the id on hover
    assert page.js_errors == []
