"""Bad input and failures in the pages: a clear message, never a broken page."""

from __future__ import annotations

import json

from tests.e2e.browser.conftest import HeldRequests, screenshot


def last_error(page) -> str:  # type: ignore[no-untyped-def]
    return page.locator("#messages .msg.error").first.inner_text()


def test_wrong_file_type_and_unparsable_mesh_are_explained(page, served, tmp_path):
    page.goto("/parts.html")
    wrong = tmp_path / "notes.txt"
    wrong.write_text("not a mesh")
    page.set_input_files("#part-file", str(wrong))
    page.click("#upload-button")
    page.wait_for_selector("#messages .msg.error")
    assert 'wrong file type "notes.txt"' in last_error(page) and ".stl" in last_error(page)

    broken = tmp_path / "broken.stl"
    broken.write_bytes(b"solid x\nfacet normal 0 0 1\nthis is not STL\n")
    page.set_input_files("#part-file", str(broken))
    page.click("#upload-button")
    page.wait_for_selector("#messages .msg.error >> text=422")
    message = last_error(page)
    assert "broken.stl" in message and "Unprocessable input (422)" in message
    assert page.inner_text("#upload-status") == "upload failed"
    screenshot(page, "error-upload")
    assert page.js_errors == []


def test_job_parameter_errors_point_at_the_field(page, served):
    page.goto("/jobs.html?kind=probe_plan")
    page.wait_for_selector('#job-form-body[data-kind="probe_plan"]')
    page.fill("#param-trace_id", "trace_does_not_exist")
    page.fill("#param-chord_error_mm", "-1")
    page.click("#submit-job")
    page.wait_for_selector('.field.invalid[data-field="chord_error_mm"]')
    assert "params.chord_error_mm" in last_error(page)
    assert "greater than 0" in page.inner_text('.field[data-field="chord_error_mm"] .error-text')
    page.fill("#param-chord_error_mm", "0.005")
    page.click("#submit-job")
    page.wait_for_selector('.field.invalid[data-field="trace_id"]')
    assert "trace_does_not_exist" in last_error(page) and "does not exist" in last_error(page)


def test_server_error_is_a_readable_message(page, served):
    page.route("**/api/v1/parts?*", lambda route: route.fulfill(status=500, body="Internal Server Error",
                                                                 content_type="text/plain"))
    page.goto("/parts.html")
    page.wait_for_selector("#messages .msg.error")
    assert "The server failed (500" in last_error(page)
    assert page.locator("h1").inner_text() == "Parts"  # the page still works
    problem = {"type": "about:blank", "title": "Internal error", "status": 500,
               "detail": "the server failed; the error was logged"}
    page.unroute("**/api/v1/parts?*")
    page.route("**/api/v1/parts?*", lambda route: route.fulfill(status=500, body=json.dumps(problem),
                                                                 content_type="application/problem+json"))
    page.reload()
    page.wait_for_selector("#messages .msg.error >> text=the error was logged")
    assert "Internal error (500)" in last_error(page)


def test_lost_connection_is_shown_clearly(page, served):
    page.goto("/parts.html")
    page.wait_for_selector("#conn.online")
    page.route("**/api/v1/**", lambda route: route.abort("connectionrefused"))
    page.evaluate("document.dispatchEvent(new CustomEvent('conforma:key'))")  # triggers a reload of the list
    page.wait_for_selector("#offline-banner", state="visible")
    assert "Cannot reach the Conforma API" in last_error(page)
    assert page.inner_text("#conn") == "API unreachable"
    screenshot(page, "error-offline")
    page.unroute("**/api/v1/**")
    page.wait_for_selector("#conn.online", timeout=12_000)  # the health poll notices the return
    assert not page.locator("#offline-banner").is_visible()


def test_an_answer_to_a_request_sent_before_the_connection_failed_does_not_show_it_online(page, served):
    """A request in flight when a later one finds the API unreachable (a slow answer, a
    server going down) may still be answered; that answer says nothing about now.  The
    machines list is held on its way, every later request is refused, then the held one is
    let through and answered: the page stays 'API unreachable'."""
    page.goto("/parts.html")
    page.wait_for_selector("#conn.online")
    held = HeldRequests(page)
    page.route("**/api/v1/machines*", held)
    page.evaluate("document.dispatchEvent(new CustomEvent('conforma:key'))")  # lists the machines
    held.wait()
    page.route("**/api/v1/**", lambda route: route.abort("connectionrefused"))
    page.evaluate("document.dispatchEvent(new CustomEvent('conforma:key'))")  # these fail
    page.wait_for_selector("#conn.offline")
    with page.expect_response(lambda response: response.url.endswith("/api/v1/machines")) as answered:
        held.release(1)  # to the server, past the refusing route
    assert answered.value.ok
    page.evaluate("new Promise((done) => setTimeout(done, 100))")  # the answer's handlers have run
    assert page.inner_text("#conn") == "API unreachable"
    assert page.locator("#offline-banner").is_visible()
