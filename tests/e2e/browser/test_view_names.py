"""A part named like markup is shown as text in the 3-D view (Chromium): no frame, form or
script of the name's making exists in the view's document, and the name reads back."""

from __future__ import annotations

import pytest
import trimesh

HOSTILE = '<iframe srcdoc="<script>document.title=\'pwned\'</script>"></iframe><form><input placeholder="API key">'


@pytest.mark.timeout(600)
def test_a_hostile_part_name_is_text_in_the_3d_view(page, served):
    api = served.api()
    stl = trimesh.creation.box(extents=(20, 20, 5)).export(file_type="stl")
    part = api.post("/api/v1/parts", files={"file": ("box.stl", stl)}, data={"name": HOSTILE}).json()
    page.goto("/parts.html")
    page.click(f'tr[data-id="{part["id"]}"] button.open3d')
    page.wait_for_selector("#viewer-panel[data-generation]", state="attached")
    frame = page.frame_locator("#viewer-iframe")
    frame.get_by_text("iframe srcdoc", exact=False).first.wait_for(state="attached", timeout=60_000)
    assert frame.locator("iframe").count() == 0
    assert frame.locator("form input[placeholder='API key']").count() == 0
    shown = frame.get_by_text("iframe srcdoc", exact=False).first.inner_text()
    assert HOSTILE in " ".join(shown.split()) or "<iframe srcdoc=" in shown
    assert page.js_errors == []
