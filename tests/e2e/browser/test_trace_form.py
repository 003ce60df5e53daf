"""The Traces page's form: a trace created while the page still lists its parts."""

from __future__ import annotations

from app.reference.s1 import s1_mesh, s1_traces

TRACE = s1_traces()[6].to_api()  # a cubic NURBS across the S1 part


def test_a_trace_created_while_the_parts_still_load_waits_for_them(page, served, tmp_path):
    """The form is on the page before the part list has arrived; a trace created then is
    created on the part once it has (not refused with "upload a part first")."""
    api = served.api()
    stl = tmp_path / "s1.stl"
    stl.write_bytes(s1_mesh(grid_mm=1.0).export(file_type="stl"))
    part = api.post("/api/v1/parts", files={"file": ("s1.stl", stl.read_bytes())}).json()
    held, released = [], []  # the page's part listing, answered only after the click

    def hold(route) -> None:  # type: ignore[no-untyped-def]
        if released:
            route.continue_()
        else:
            held.append(route)
    page.route("**/api/v1/parts?*", hold)
    page.goto(f"/traces.html?part={part['id']}", wait_until="commit")
    page.fill("#name", "created early")
    page.select_option("#type", "nurbs")
    page.fill("#points", "\n".join(f"{x}, {y}" for x, y in TRACE["geometry"]["control_points"]))
    page.fill("#degree", "3")
    page.click("#create-trace")
    while not held:
        page.wait_for_timeout(50)
    released.append(True)
    for route in held:
        route.continue_()
    row = page.wait_for_selector("#traces-body tr.selected")
    assert "created early" in row.inner_text()
    traces = api.get(f"/api/v1/parts/{part['id']}/traces").json()["items"]
    assert [t["name"] for t in traces] == ["created early"]
    assert page.js_errors == []
