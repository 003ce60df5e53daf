"""Hostile names in the 3-D view, in Chromium, under the view's own CSP.

A view (viser started as the API starts it: handshake check and CSP) shows a scene whose
part, trace, job and machine names and messages are markup: an ``<iframe srcdoc>`` with a
script, an ``<img onerror>``, a fake "re-enter API key" form.  They reach every element the
panel fills (markdown title and notes, slider label and caption, plot title, colour-scale
HTML, dropdown option).  The page must show each as its literal text, hold no iframe, img
or form of their making, run none of their script, report no CSP violation but the refused
eval of viser's own WebAssembly glue, and still draw the part on the canvas.  Raw HTML sent
past the escaping (``gui.add_html``) is then confined by the CSP alone.
"""

from __future__ import annotations

import io
import time
from collections.abc import Iterator
from urllib.parse import quote

import numpy as np
import pytest
import trimesh
from PIL import Image

from app.viewer.scene_data import DeviationPlot, FocusScene, LayerStack, Polyline, ScalarSurface
from tests.e2e.browser.pixels import PANEL_SELECTORS, slate_mask
from tests.helpers.processes import free_port

IFRAME = '<iframe srcdoc="<script>parent.pwned=1</script>">'
IMG = "<img src=x onerror=window.pwned=1>"
FORM = '<form><input placeholder="re-enter API key"></form>'
PART, TRACE, JOB_MESSAGE, MACHINE = f"part {IFRAME}", IMG, f"job is failed: {FORM}", f"machine {IMG}{FORM}"
OPTION = f"part {FORM} (part_hostile)"

VIOLATIONS = """
window.__violations = [];
document.addEventListener('securitypolicyviolation', e => window.__violations.push(
    {directive: e.effectiveDirective, blocked: e.blockedURI, line: e.lineNumber}));
"""


def _hostile_scene() -> FocusScene:
    box = trimesh.creation.box(extents=(40, 40, 8))
    s = np.linspace(0, 30, 40)
    trace = np.column_stack([s - 15, np.zeros_like(s), np.full_like(s, 4.2)])
    ribbon_v = np.array([[-15, -1, 4.1], [15, -1, 4.1], [15, 1, 4.1], [-15, 1, 4.1]], float)
    layer = np.array([[[-15, -5, 4.5], [15, -5, 4.5]]], float)
    return FocusScene(
        {"part_id": "part_hostile"}, PART, np.asarray(box.vertices), np.asarray(box.faces),
        polylines=(Polyline(TRACE, trace),),
        plots=(DeviationPlot(TRACE, f"{TRACE}: measured - nominal", s, 0.01 * np.sin(s)),),
        layers=(LayerStack(MACHINE, (IFRAME, FORM), (layer, layer + 0.5)),),
        scalar_surfaces=(ScalarSurface(f"{TRACE} sd", ribbon_v, np.array([[0, 1, 2], [0, 2, 3]]),
                                       np.array([0.0, 0.01, 0.02, 0.01]), 0.0, 0.02),),
        notes=(JOB_MESSAGE, MACHINE))


@pytest.fixture(scope="module")
def hostile_view(tmp_path_factory) -> Iterator:  # type: ignore[no-untyped-def]
    from app.platform.config import load_settings
    from app.viewer.server import start_viewer

    settings = load_settings({}, data_dir=tmp_path_factory.mktemp("hostile-view"), viewer=True,
                             viewer_port=free_port(), embedded_worker=False)
    viewer = start_viewer(settings, None)
    viewer._recent = lambda: [(OPTION, "part_hostile")]  # type: ignore[method-assign]  (the dropdown's entries)
    try:
        viewer.show(_hostile_scene())
        yield viewer
    finally:
        viewer.stop()


def _open(browser, viewer):  # type: ignore[no-untyped-def]
    port = viewer.port
    token = viewer.guard.signer.mint("default").token
    websocket = f"ws://127.0.0.1:{port}/?token={quote(token)}"
    context = browser.new_context(viewport={"width": 960, "height": 640})
    context.add_init_script(VIOLATIONS)
    page = context.new_page()
    page.set_default_timeout(30_000)
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.goto(f"http://127.0.0.1:{port}/?websocket={quote(websocket)}")
    return context, page, errors


def _text(page) -> str:  # type: ignore[no-untyped-def]
    return " ".join(page.evaluate("document.body.innerText").split())


def _wait_for_text(page, needles: list[str], timeout_s: float = 30.0) -> str:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while True:
        text = _text(page)
        if all(n in text for n in needles) or time.monotonic() > deadline:
            return text
        page.wait_for_timeout(200)


@pytest.mark.timeout(120)
def test_hostile_names_are_text_and_run_nothing_in_the_3d_view(browser, hostile_view):  # type: ignore[no-untyped-def]
    from tests.e2e.browser.conftest import is_view_eval_refusal

    context, page, errors = _open(browser, hostile_view)
    try:
        page.get_by_text("Connected").first.wait_for(state="visible")
        shown = [PART, JOB_MESSAGE, MACHINE, f"{TRACE}: measured - nominal", FORM]
        text = _wait_for_text(page, shown)
        for literal in shown:   # title, notes, plot title, slider caption (the last layer's label)
            assert literal in text, literal
        legends = page.evaluate("""[...document.querySelectorAll('.conforma-legend')].map(
            e => [e.dataset.name, e.querySelector('b').textContent])""")
        assert legends == [[f"map:{TRACE} sd", f"{TRACE} sd"]]  # the colour scale, in viser's HTML element
        slider_label = page.evaluate("[...document.querySelectorAll('label')]"
                                     ".map(l => l.innerText.replace(/\\s+/g, ''))")
        assert MACHINE.replace(" ", "") in slider_label
        for drawer in hostile_view.view().clients.values():  # the selector names the shown part
            drawer.panel.refresh_jobs(current="part_hostile")
        page.wait_for_function("v => [...document.querySelectorAll('input')].some(i => i.value === v)", arg=OPTION)
        made = page.evaluate("""() => ({
            iframes: document.querySelectorAll('iframe').length,
            forms: document.querySelectorAll('form').length,
            fake_inputs: document.querySelectorAll('input[placeholder="re-enter API key"]').length,
            handlers: [...document.querySelectorAll('*')].filter(e => [...e.attributes].some(
                a => a.name.startsWith('on'))).length,
            images: [...document.querySelectorAll('img')].map(i => i.getAttribute('src'))
                .filter(src => !src.startsWith('data:image/svg+xml')),  // viser's own logo
            pwned: typeof window.pwned})""")
        assert made == {"iframes": 0, "forms": 0, "fake_inputs": 0, "handlers": 0, "images": [], "pwned": "undefined"}
        violations = page.evaluate("window.__violations")
        assert [v for v in violations if v["blocked"] != "eval"] == [], violations
        assert [e for e in errors if not is_view_eval_refusal(e)] == []

        # the canvas still draws the part (its lit slate), viser's panel masked out
        png = page.screenshot(mask=[page.locator(s) for s in PANEL_SELECTORS], mask_color="#FFFFFF")
        img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
        slate = int(slate_mask(img).sum())
        assert slate > 0.01 * img.shape[0] * img.shape[1], f"{slate} px of the part drawn"
    finally:
        context.close()


@pytest.mark.timeout(120)
def test_markup_sent_past_the_escaping_is_confined_by_the_csp(browser, hostile_view):  # type: ignore[no-untyped-def]
    """Raw HTML with an ``onerror`` handler and a ``<script>`` (as ``gui.add_html`` would carry a
    forgotten escape): the elements exist, but the CSP refuses to run either."""
    context, page, _errors = _open(browser, hostile_view)
    try:
        page.get_by_text("Connected").first.wait_for(state="visible")
        # the page may show "Connected" before the server lists its client: send until it arrives
        handles: list = []
        deadline = time.monotonic() + 60
        while page.locator("#raw-img").count() == 0:
            assert time.monotonic() < deadline, "the view never received the raw markup"
            handles += [client.gui.add_html('<img id="raw-img" src="x" onerror="window.pwned=1">'
                                            '<iframe id="raw-frame" srcdoc="<script>parent.pwned=2</script>">'
                                            '</iframe>')
                        for client in hostile_view.server.get_clients().values()]
            page.wait_for_timeout(1000)
        page.wait_for_function("window.__violations.some(v => v.blocked === 'inline') || window.pwned !== undefined")
        page.wait_for_timeout(500)
        assert page.evaluate("typeof window.pwned") == "undefined"
        refused = {v["directive"] for v in page.evaluate("window.__violations") if v["blocked"] == "inline"}
        assert refused <= {"script-src-attr", "script-src-elem"} and "script-src-attr" in refused
        for handle in handles:
            handle.remove()
    finally:
        context.close()


@pytest.mark.timeout(120)
def test_a_foreign_page_cannot_frame_the_view(browser, hostile_view):  # type: ignore[no-untyped-def]
    context = browser.new_context()
    page = context.new_page()
    try:
        page.set_content(f'<iframe id="v" src="http://127.0.0.1:{hostile_view.port}/" width=400 height=300></iframe>')
        page.wait_for_timeout(1500)
        frame = page.frame_locator("#v")
        assert frame.locator("#root").count() == 0  # viser's page never loaded into the frame
    finally:
        context.close()
