"""The machines page: register a mock machine, connect, watch a print, press the
emergency stop and see the state change."""

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
    t0 = time.monotonic()
    status = api.get(f"/api/v1/machines/{machine_id}").json()
    assert status["state"] == "error" and time.monotonic() - t0 < 5
    assert page.js_errors == []
