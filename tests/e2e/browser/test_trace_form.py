"""The Traces page's forms: a trace created, or a circuit previewed, while the page still lists
its parts."""

from __future__ import annotations

from app.reference.s1 import s1_mesh, s1_traces
from tests.api.test_circuits import GERBER_MM

TRACE = s1_traces()[6].to_api()  # a cubic NURBS across the S1 part


class _HeldPartList:
    """The page's part listing held until ``release()`` (after the click under test)."""

    def __init__(self, page) -> None:  # type: ignore[no-untyped-def]
        self.page, self.held, self.released = page, [], False
        page.route("**/api/v1/parts?*", self._hold)

    def _hold(self, route) -> None:  # type: ignore[no-untyped-def]
        if self.released:
            route.continue_()
        else:
            self.held.append(route)

    def release(self) -> None:
        while not self.held:
            self.page.wait_for_timeout(50)
        self.released = True
        for route in self.held:
            route.continue_()


def _part(served, tmp_path) -> dict:  # type: ignore[no-untyped-def]
    stl = tmp_path / "s1.stl"
    stl.write_bytes(s1_mesh(grid_mm=1.0).export(file_type="stl"))
    return served.api().post("/api/v1/parts", files={"file": ("s1.stl", stl.read_bytes())}).json()


def test_a_trace_created_while_the_parts_still_load_waits_for_them(page, served, tmp_path):
    """The form is on the page before the part list has arrived; a trace created then is
    created on the part once it has (not refused with "upload a part first")."""
    api = served.api()
    part = _part(served, tmp_path)
    parts = _HeldPartList(page)
    page.goto(f"/traces.html?part={part['id']}", wait_until="commit")
    page.fill("#name", "created early")
    page.select_option("#type", "nurbs")
    page.fill("#points", "\n".join(f"{x}, {y}" for x, y in TRACE["geometry"]["control_points"]))
    page.fill("#degree", "3")
    page.click("#create-trace")
    parts.release()
    row = page.wait_for_selector("#traces-body tr.selected")
    assert "created early" in row.inner_text()
    traces = api.get(f"/api/v1/parts/{part['id']}/traces").json()["items"]
    assert [t["name"] for t in traces] == ["created early"]
    assert page.js_errors == []


def test_a_circuit_previewed_while_the_parts_still_load_waits_for_them(page, served, tmp_path):
    """The circuit import is on the page before the part list has arrived; a preview asked
    for then is drawn on the part once it has."""
    part = _part(served, tmp_path)
    gerber = tmp_path / "top.gbr"
    gerber.write_text(GERBER_MM)
    parts = _HeldPartList(page)
    page.goto(f"/traces.html?part={part['id']}", wait_until="commit")
    page.set_input_files("#circuit-file", str(gerber))
    page.click("#circuit-preview-button")
    parts.release()
    page.wait_for_selector("#circuit-preview polyline", state="attached")
    assert page.locator("#circuit-preview polyline").count() == 2
    assert served.api().get(f"/api/v1/parts/{part['id']}/traces").json()["items"] == []  # a preview stores nothing
    assert page.js_errors == []
