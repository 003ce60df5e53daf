"""Headless Chromium (the Debian ``chromium`` package) driven by playwright against a real
``conforma serve`` (API + worker + viser view).  Never downloads a browser: without
chromium or playwright the tests skip and say why, except under ``CI=true``, where they
fail (``tests/helpers/real_components.py``)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

from tests.helpers.processes import free_port, stop, wait_healthy
from tests.helpers.real_components import missing

ROOT = Path(__file__).resolve().parents[3]
# Test runs write screenshots as test artifacts; `make screenshots` copies them to
# web/screenshots/, the committed ones the manual names.
SCREENSHOTS = ROOT / "tests" / "artifacts" / "screenshots"
KEY = "browser-operator-key-1"
CHROMIUM_ARGS = ["--headless=new", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--no-first-run"]


def _missing() -> str | None:
    if shutil.which("chromium") is None:
        return "chromium is not installed (apt-get install -y chromium)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "playwright is not installed (pip install playwright; never `playwright install`)"
    return None


def is_view_eval_refusal(message: str) -> bool:
    """viser's bundle builds its (unused) Gaussian-splat sorter at load, and its WebAssembly
    glue compiles JavaScript from strings: the view's CSP refuses that eval (it allows
    WebAssembly, ``'wasm-unsafe-eval'``, but no ``'unsafe-eval'``).  Only the view's policy
    names ``'wasm-unsafe-eval'``, so this matches that refusal and no page's error."""
    return message.startswith("Evaluating a string as JavaScript violates the following Content Security "
                              "Policy directive") and "'wasm-unsafe-eval'" in message


@pytest.fixture(autouse=True)
def _chromium_present() -> None:
    """Every browser test needs Debian's Chromium and playwright: skip, or fail under CI."""
    reason = _missing()
    if reason:
        missing("Chromium (browser tests)", reason)


@dataclass(frozen=True)
class Served:
    base: str
    key: str
    viewer_port: int
    data_dir: Path

    def api(self) -> httpx.Client:
        return httpx.Client(base_url=self.base, headers={"Authorization": f"Bearer {self.key}"}, timeout=30)


@pytest.fixture(scope="session")
def served(tmp_path_factory) -> Iterator[Served]:  # type: ignore[no-untyped-def]
    data = tmp_path_factory.mktemp("browser-data")
    port, viewer_port = free_port(), free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("CONFORMA_")}
    env.update({"PYTHONPATH": str(ROOT), "CONFORMA_DATA_DIR": str(data), "CONFORMA_API_KEYS": f"{KEY}:admin",
                "CONFORMA_VIEWER": "true", "CONFORMA_LOG_LEVEL": "warning"})
    log = open(data / "serve.log", "w")  # noqa: SIM115 (closed below)
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "serve", "--port", str(port), "--viewer-port",
                             str(viewer_port)], env=env, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    try:
        wait_healthy(base, proc, timeout=180.0, log=data / "serve.log")  # a loaded 2-core host starts slowly
        info = httpx.get(f"{base}/api/v1/viewer", headers={"Authorization": f"Bearer {KEY}"}).json()
        yield Served(base, KEY, int(info["port"]), data)
    finally:
        stop(proc)
        log.close()


@pytest.fixture(scope="session")
def browser() -> Iterator:  # type: ignore[no-untyped-def]
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        chromium = pw.chromium.launch(executable_path=shutil.which("chromium"), args=CHROMIUM_ARGS)
        try:
            yield chromium
        finally:
            chromium.close()


@pytest.fixture
def page(browser, served):  # type: ignore[no-untyped-def]
    """A fresh page whose browser already holds the operator's key (localStorage)."""
    context = browser.new_context(viewport={"width": 1400, "height": 900}, base_url=served.base)
    context.add_init_script(f"localStorage.setItem('conforma.apiKey', {served.key!r});")
    page = context.new_page()
    page.set_default_timeout(30_000)  # the test machine may be heavily loaded
    errors: list[str] = []
    refused: list[str] = []
    page.on("pageerror", lambda exc: (refused if is_view_eval_refusal(str(exc)) else errors).append(str(exc)))
    page.js_errors = errors  # type: ignore[attr-defined]
    page.view_eval_refusals = refused  # type: ignore[attr-defined]
    yield page
    context.close()


def screenshot_path(name: str) -> Path:
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    return SCREENSHOTS / f"{name}.png"


def screenshot(page, name: str) -> Path:  # type: ignore[no-untyped-def]
    """Save the visible page as tests/artifacts/screenshots/<name>.png."""
    path = screenshot_path(name)
    page.screenshot(path=str(path), full_page=False)
    return path


class HeldRequests:
    """A ``page.route`` handler that holds the requests it gets (GETs only with
    ``gets_only``) until :meth:`release`; with ``read_now`` each one's answer is read from the
    server when it arrives and delivered on release (an answer about the moment it was
    asked), else the request goes to the server on release.  Later requests pass through."""

    def __init__(self, page, read_now: bool = False, gets_only: bool = False) -> None:  # type: ignore[no-untyped-def]
        self.page, self.read_now, self.gets_only = page, read_now, gets_only
        self.held: list = []
        self.released = False
        self.let_go = 0   # how many of the held requests have been released

    def __call__(self, route) -> None:  # type: ignore[no-untyped-def]
        if self.released or (self.gets_only and route.request.method != "GET"):
            route.continue_()
        else:
            self.held.append((route, route.fetch() if self.read_now else None))

    def wait(self) -> None:
        """Until one request is held."""
        while not self.held:
            self.page.wait_for_timeout(20)

    def release(self, count: int | None = None) -> list:
        """Let the next ``count`` (all) held requests go, in the order they came; requests that
        come after the first release pass; the read answers of those let go."""
        self.released = True
        first = self.let_go
        self.let_go = len(self.held) if count is None else min(len(self.held), first + count)
        answers = []
        for route, answer in self.held[first:self.let_go]:
            if answer is None:
                route.continue_()
            else:
                route.fulfill(response=answer)
                answers.append(answer)
        return answers
