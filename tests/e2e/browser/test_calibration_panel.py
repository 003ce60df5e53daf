"""The machines page's calibration panel: an uncalibrated machine says so and holds the
nozzle button back; "Calibrate probe" asks for confirmation, submits the job, and the panel
then shows the measured ball radius with its uncertainty, and flags it once it is stale."""

from __future__ import annotations

import re
import time

from tests.e2e.browser.conftest import screenshot
from tests.jobs.test_calibration_jobs import PHYSICS, PROFILE


def test_the_calibration_panel_runs_and_shows_a_probe_calibration(page, served):
    api = served.api()
    machine = api.post("/api/v1/machines", json={"name": "calib-browser", "port": f"mock://?{PHYSICS}",
                                                 # stale after 1.8 s
                                                 "profile": {**PROFILE, "calibration_max_age_h": 0.0005},
                                                 "mock": {"probe_noise_mm": 0.001}}).json()
    page.goto("/machines.html")
    panel = f'.calibration-panel[data-id="{machine["id"]}"]'
    page.wait_for_selector(f"{panel} .calib-missing")
    assert page.is_disabled(f'{panel} .calibrate-nozzle[data-tool="1"]')
    assert "T1 silver" in page.inner_text(f"{panel} .calib-nozzles") and "not calibrated" in page.inner_text(panel)

    messages: list[str] = []
    page.on("dialog", lambda dialog: (messages.append(dialog.message), dialog.accept()))
    page.click(f"{panel} .calibrate-probe")
    page.wait_for_selector('.msg.info:has-text("Calibrate probe: job")')
    assert messages and "moves" in messages[0]
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        mine = api.get("/api/v1/jobs", params={"kind": "calibrate_probe", "machine_id": machine["id"]}).json()["items"]
        if mine and mine[0]["status"] in ("succeeded", "failed"):
            break
        time.sleep(0.5)
    assert mine and mine[0]["status"] == "succeeded", mine
    page.wait_for_selector(f"{panel} .calib-probe", timeout=20_000)
    text = page.inner_text(f"{panel} .calib-probe")
    radius = re.search(r"ball radius\s+([0-9.]+) mm ± ([0-9.]+) µm", text)
    assert radius and abs(float(radius.group(1)) - 0.5) <= 0.003 and float(radius.group(2)) > 0, text
    assert page.is_enabled(f'{panel} .calibrate-nozzle[data-tool="1"]')
    page.wait_for_selector(f"{panel} .calib-stale", timeout=20_000)  # a stale calibration is shown as such
    assert re.search(r"probe calibration is \d+ s old \(max 0.0005 h\)", page.inner_text(f"{panel} .calib-flags"))
    page.locator(panel).scroll_into_view_if_needed()
    screenshot(page, "calibration")
    assert page.js_errors == []
