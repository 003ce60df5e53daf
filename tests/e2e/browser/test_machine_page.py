"""The machines page as a technician uses it: homed state, buttons that follow the state,
home and keyboard jog checked against the mock firmware's position, the live console, the
running program's elapsed time and time left, renaming."""

from __future__ import annotations

from tests.e2e.browser.conftest import HeldRequests, screenshot

# long uniform moves on a real-time mock: a print that runs for ~20 s
PROGRAM = "G21\nG90\nG1 X1 Y1 Z5 F600\n" + "".join(f"G1 X{2 + i % 2 * 3} Y{1 + i // 2 % 2} F900\n" for i in range(60))


def _position(api, machine_id):  # type: ignore[no-untyped-def]
    return api.get(f"/api/v1/machines/{machine_id}").json()["position"]


def test_a_technician_homes_jogs_by_keyboard_reads_the_console_and_watches_a_print(page, served):
    api = served.api()
    made = api.post("/api/v1/machines", json={"name": "bench-a", "port": "mock://", "dialect": "marlin",
                                              "mock": {"time_scale": 1.0}}).json()
    sel = f'.machine-card[data-id="{made["id"]}"]'
    page.on("dialog", lambda dialog: dialog.accept("bench left") if dialog.type == "prompt" else dialog.accept())
    page.goto("/machines.html")
    page.wait_for_selector(sel)
    assert page.is_disabled(f"{sel} .act-disconnect") and page.is_disabled(f"{sel} .act-pause")
    page.click(f"{sel} .act-connect")
    page.wait_for_selector(f'{sel} [data-state="idle"]')
    assert page.inner_text(f"{sel} .badge.homed") == "not homed"
    assert page.is_disabled(f"{sel} .act-connect") and page.is_disabled(f"{sel} .act-resume")

    page.click(f"{sel} details.manual summary")
    page.click(f"{sel} .act-home")
    page.wait_for_selector(f'{sel} .badge.homed[data-homed="true"]')
    assert _position(api, made["id"]) == [0.0, 0.0, 0.0]

    # keyboard jog: nothing moves until it is ticked, then arrows move X/Y by the chosen step
    page.select_option(f"{sel} .jog-step", "10")
    page.focus(f"{sel} .jog-pad")
    page.keyboard.press("ArrowRight")
    page.wait_for_timeout(500)
    assert _position(api, made["id"]) == [0.0, 0.0, 0.0]
    page.check(f"{sel} .keyboard-jog")
    page.wait_for_selector(f"{sel} .jog-xp:enabled")
    page.focus(f"{sel} .jog-pad")
    page.keyboard.press("ArrowRight")
    page.wait_for_selector(f'{sel} .pos:has-text("X 10.000")')
    # the pad ignores keys while the card shows the machine busy (its jog buttons off)
    page.wait_for_selector(f"{sel} .jog-yp:enabled")
    page.keyboard.press("ArrowUp")
    page.wait_for_selector(f'{sel} .pos:has-text("Y 10.000")')
    assert _position(api, made["id"])[:2] == [10.0, 10.0]

    # the console: every line sent and received, the command line, the filter
    page.fill(f"{sel} .console-line", "M114")
    page.press(f"{sel} .console-line", "Enter")
    page.wait_for_selector(f'{sel} .console-log:has-text("< X:10.00 Y:10.00")')
    log = page.inner_text(f"{sel} .console-log")
    assert "G28" in log and "M114" in log and "< ok" in log
    page.fill(f"{sel} .console-filter", "m114")
    filtered = page.inner_text(f"{sel} .console-log").splitlines()
    assert filtered and all("M114" in line for line in filtered)

    # a print: elapsed and time left, motion buttons off, pause on
    program = api.post("/api/v1/programs", files={"file": ("slow.gcode", PROGRAM.encode())}).json()
    assert api.post(f"/api/v1/machines/{made['id']}/print", json={"program_id": program["id"]}).status_code == 202
    page.wait_for_selector(f'{sel} [data-state="printing"]', timeout=15_000)
    page.wait_for_selector(f'{sel} .program:has-text("left about")', timeout=15_000)
    assert "elapsed" in page.inner_text(f"{sel} .program")
    assert page.is_disabled(f"{sel} .act-home") and page.is_disabled(f"{sel} .jog-xp")
    assert page.is_enabled(f"{sel} .act-pause") and page.is_disabled(f"{sel} .act-resume")
    assert page.is_disabled(f"{sel} .act-delete")
    screenshot(page, "machine-page")
    page.click(f"{sel} .act-pause")
    page.wait_for_selector(f'{sel} [data-state="paused"]')
    assert page.is_enabled(f"{sel} .act-resume")
    page.click(f"{sel} .estop")
    page.wait_for_selector(f'{sel} [data-state="error"]')
    page.wait_for_selector(f'{sel} .badge.homed[data-homed="false"]')      # after a stop, home again

    page.click(f"{sel} .act-rename")
    page.wait_for_selector(f'{sel} .machine-name:has-text("bench left")')
    assert api.get(f"/api/v1/machines/{made['id']}").json()["name"] == "bench left"
    assert page.js_errors == []


def test_a_console_line_is_shown_once_when_two_polls_would_cross(page, served):
    """The console polls every second and once more after a command; both ask for what
    follows the same last line.  A slow poll (held here on its way) must not let the
    command's poll fetch the same lines again: each line is shown once."""
    api = served.api()
    made = api.post("/api/v1/machines", json={"name": "bench-b", "port": "mock://", "dialect": "marlin"}).json()
    sel = f'.machine-card[data-id="{made["id"]}"]'
    page.goto("/machines.html")
    page.click(f"{sel} .act-connect")
    page.wait_for_selector(f'{sel} [data-state="idle"]')
    page.click(f"{sel} details.manual summary")
    held = HeldRequests(page)
    page.route(f"**/api/v1/machines/{made['id']}/console*", held)
    held.wait()  # the next timed poll, held on its way
    with page.expect_response(lambda response: response.url.endswith("/command")):
        page.fill(f"{sel} .console-line", "M114")
        page.press(f"{sel} .console-line", "Enter")
    page.wait_for_timeout(300)  # the command's own poll, if it went out beside the held one
    held.release()
    page.wait_for_selector(f'{sel} .console-log:has-text("< X:")')
    page.wait_for_timeout(1500)  # the polls after
    lines = page.inner_text(f"{sel} .console-log").splitlines()
    assert sum(line.startswith(">") and "M114" in line for line in lines) == 1, lines
    assert sum(line.startswith("< X:") for line in lines) == 1, lines


def test_a_poll_answered_after_an_action_does_not_turn_the_card_back(page, served):
    """The machines list is polled every second; a poll read before an action (here:
    Connect) and answered after it would show the machine as it was before.  The poll's
    answer is read from the server, then held back until Connect's answer is shown.  (The
    page polls on a timer, so on a loaded host it may send more polls while Connect runs:
    they are read later, and let go after the first one's answer was judged.)"""
    api = served.api()
    made = api.post("/api/v1/machines", json={"name": "bench-c", "port": "mock://", "dialect": "marlin"}).json()
    sel = f'.machine-card[data-id="{made["id"]}"]'
    page.goto("/machines.html")
    page.wait_for_selector(f'{sel} [data-state="disconnected"]')
    held = HeldRequests(page, read_now=True, gets_only=True)  # the machine as it is now: disconnected
    page.route("**/api/v1/machines", held)
    held.wait()  # the next timed poll
    page.click(f"{sel} .act-connect")
    page.wait_for_selector(f'{sel} [data-state="idle"]')
    (before,) = held.release(1)   # the poll read before Connect
    assert {m["id"]: m["state"] for m in before.json()["items"]}[made["id"]] == "disconnected"
    page.evaluate("new Promise((done) => setTimeout(done, 100))")  # its handler has run
    assert page.get_attribute(f"{sel} h2 .badge[data-state]", "data-state") == "idle"
    held.release()   # polls sent while Connect ran, if any
