"""Accessibility (axe-core, shipped inside the axe-playwright-python package: nothing is
downloaded) on every page, and the API documentation working offline."""

from __future__ import annotations

import pytest

PAGES = ["index.html", "parts.html", "traces.html", "jobs.html", "machines.html"]


@pytest.mark.parametrize("name", PAGES)
def test_no_serious_accessibility_violations(page, name):
    from axe_playwright_python.sync_playwright import Axe

    page.goto(f"/{name}")
    page.wait_for_selector('body[data-ready="1"]')
    violations = Axe().run(page).response["violations"]
    serious = [(v["id"], v["impact"], [n["target"] for n in v["nodes"]][:3]) for v in violations
               if v["impact"] in ("serious", "critical")]
    assert serious == [], serious


def test_api_docs_render_without_the_internet(page):
    page.goto("/docs")
    page.wait_for_selector(".swagger-ui .info .title", timeout=30_000)
    assert "Conforma" in page.inner_text(".swagger-ui .info .title")
    assert page.query_selector_all(".opblock")                      # the operations are listed
