"""A part named like markup, with a trace named like markup, opened from the console in the
3-D view (Chromium, a real ``conforma serve``): the name reads back as text; no frame, image,
form or script of the name's making exists in the view's document; nothing ran; the view's
only CSP report is its refused eval (see ``is_view_eval_refusal``) and the console page
framed it (the view's ``frame-ancestors`` names the console)."""

from __future__ import annotations

import pytest
import trimesh

IFRAME = '<iframe srcdoc="<script>parent.pwned=1</script>">'
IMG = "<img src=x onerror=window.pwned=1>"
FORM = '<form><input placeholder="re-enter API key"></form>'
HOSTILE = f"{IFRAME}{IMG}{FORM}"

VIOLATIONS = """
window.__violations = [];
document.addEventListener('securitypolicyviolation', e => window.__violations.push(
    {directive: e.effectiveDirective, blocked: e.blockedURI}));
"""


@pytest.mark.timeout(600)
def test_a_hostile_part_name_is_text_in_the_3d_view(page, served):  # type: ignore[no-untyped-def]
    api = served.api()
    stl = trimesh.creation.box(extents=(20, 20, 5)).export(file_type="stl")
    part = api.post("/api/v1/parts", files={"file": ("box.stl", stl)}, data={"name": HOSTILE}).json()
    trace = api.post(f"/api/v1/parts/{part['id']}/traces",
                     json={"name": IMG, "geometry": {"type": "line", "start": [-5, 0], "end": [5, 0]}})
    assert trace.status_code == 201, trace.text
    page.context.add_init_script(VIOLATIONS)
    page.goto("/parts.html")
    page.click(f'tr[data-id="{part["id"]}"] button.open3d')
    page.wait_for_selector("#viewer-panel[data-generation]", state="attached")
    frame = page.frame_locator("#viewer-iframe")
    frame.get_by_text("iframe srcdoc", exact=False).first.wait_for(state="attached", timeout=60_000)
    shown = " ".join(frame.locator("body").inner_text().split())
    assert f"part {HOSTILE}" in shown
    assert frame.locator("iframe").count() == 0
    assert frame.locator("form").count() == 0 and frame.locator("input[placeholder='re-enter API key']").count() == 0
    assert frame.locator("img[src='x']").count() == 0
    view = next(f for f in page.frames if f.url.startswith(f"http://127.0.0.1:{served.viewer_port}/"))
    assert view.evaluate("typeof window.pwned") == "undefined" and page.evaluate("typeof window.pwned") == "undefined"
    assert [v for v in view.evaluate("window.__violations") if v["blocked"] != "eval"] == []
    assert page.evaluate("window.__violations") == []
    assert page.js_errors == []
