"""Every app serves the routes its routers built once, at import: building an app for new
settings (a server start, every test app) does not build its routes again."""

from __future__ import annotations

from fastapi.routing import APIRoute
from fastapi.testclient import TestClient

from app.main import ROUTERS, create_app
from tests.conftest import auth


def test_every_app_serves_the_routers_own_routes(settings_factory, tmp_path):  # type: ignore[no-untyped-def]
    built = [route for router in ROUTERS for route in router.routes]
    assert built and all(isinstance(route, APIRoute) for route in built)
    apps = [create_app(settings_factory(data_dir=tmp_path / name)) for name in ("a", "b")]
    for api in apps:
        served = [route for route in api.routes if getattr(route, "path", "").startswith("/api/")]
        # the same objects, in the routers' order: nothing rebuilt or wrapped per app
        assert len(served) == len(built) and all(s is b for s, b in zip(served, built))
        with TestClient(api) as client:
            assert client.get("/api/v1/health", headers=auth("viewer")).status_code == 200
            assert client.get("/api/v1/parts", headers=auth("viewer")).json() is not None
            assert client.get("/api/v1/parts/nope", headers=auth("viewer")).status_code == 404


def test_the_console_serves_its_pages_not_the_lint_tooling_beside_them(client):  # type: ignore[no-untyped-def]
    """``web/`` holds the console and, once ``make lint`` ran, npm's ``node_modules`` and the
    ESLint set-up: only the console is served."""
    assert client.get("/js/api.js").status_code == 200
    assert client.get("/index.html").status_code == 200
    for path in ("/package.json", "/package-lock.json", "/eslint.config.js",
                 "/node_modules/eslint/package.json", "/node_modules/.package-lock.json"):
        assert client.get(path).status_code == 404, path
