"""The application factory.  Nothing is built at import time: ``create_app(settings)``."""

from __future__ import annotations

import logging
import os
import shutil
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline

import app as app_package
from app.api.admission import AdmissionMiddleware
from app.api.errors import install_error_handlers
from app.api.headers import SecurityHeadersMiddleware
from app.api.limits import BodyLimitMiddleware
from app.api.openapi_errors import document_error_responses
from app.api.routes import (
    circuits,
    files,
    jobs,
    loop_actions,
    machine_console,
    machines,
    parts,
    programs,
    reports,
    system,
    traces,
)
from app.api.routes import viewer as viewer_api
from app.platform.auth import KeyRing, LoginThrottle
from app.platform.config import Settings
from app.platform.db import migrate
from app.runtime.engine import QUEUES, Runtime
from app.runtime.heap import LARGE_BLOCK_BYTES, SERVER_ARENAS, limit_arenas, map_large_blocks

# The API's routers, in the order their routes are matched
ROUTERS = (system.router, parts.router, traces.router, jobs.router, loop_actions.router, programs.router,
           machines.router, machine_console.router,
           files.router, viewer_api.router, reports.router, circuits.router)
WEB_DIR = Path(__file__).resolve().parent.parent / "web"
log = logging.getLogger("conforma")


class ConsoleFiles(StaticFiles):
    """``web/`` as the console: its pages, scripts and styles, not the lint tooling kept
    beside them (``node_modules/``, the npm manifest and the ESLint config): a 404."""

    TOOLING = frozenset({"node_modules", "package.json", "package-lock.json", "eslint.config.js"})

    def lookup_path(self, path: str) -> tuple[str, os.stat_result | None]:
        if Path(path).parts[:1] and Path(path).parts[0] in self.TOOLING:
            return "", None
        return super().lookup_path(path)


def _sweep(runtime: Runtime) -> None:
    """Files a crash left behind: old ``.tmp-*`` and blob files without a row (logged)."""
    from sqlmodel import Session

    from app.platform.blobs import SWEEP_GRACE_S, sweep_blobs

    with Session(runtime.engine) as session:
        counts = sweep_blobs(runtime.blobs, session)
    for spool in runtime.settings.data_dir.glob("import-*"):  # a circuit import's uploads
        if spool.is_dir() and time.time() - spool.stat().st_mtime > SWEEP_GRACE_S:
            shutil.rmtree(spool, ignore_errors=True)
            counts["temporary"] += 1
    if any(counts.values()):
        logging.getLogger("conforma").warning("swept %(temporary)d temporary and %(orphans)d row-less blob "
                                              "files left by a crash", counts)


def create_app(settings: Settings, *, start_workers: bool | None = None) -> FastAPI:
    """Build the API for ``settings``.  On start-up: migrate, open the runtime, start the
    embedded worker (unless disabled) and the viewer (if enabled)."""
    limit_arenas(SERVER_ARENAS)  # before the server's threads start (app.runtime.heap)
    map_large_blocks(LARGE_BLOCK_BYTES)  # a request's or a workflow's freed buffers leave at once

    @asynccontextmanager
    async def lifespan(api: FastAPI) -> AsyncIterator[None]:
        migrate(settings)
        runtime = Runtime(settings)
        api.state.runtime = runtime
        _sweep(runtime)
        api.state.keyring = KeyRing(runtime.engine, settings.static_keys())
        api.state.login_throttle = LoginThrottle()
        # This process owns the serial ports: it always consumes the machine queue (and the
        # workflows that drive machines).
        embedded = settings.embedded_worker if start_workers is None else start_workers
        runtime.start_workers(QUEUES if embedded else ("machine", "workflow"))
        viewer = None
        if settings.viewer:
            from app.viewer.server import start_viewer

            viewer = start_viewer(settings, runtime)
            api.state.viewer = viewer
        try:
            yield
        finally:
            if viewer is not None:
                viewer.stop()
            runtime.stop()

    document_error_responses(ROUTERS)
    api = FastAPIOffline(  # /docs served from the package: no CDN, works offline
        title="Conforma",
        version=app_package.__version__,
        description="Plan, measure and compensate toolpaths for printing electronics onto curved parts.",
        lifespan=lifespan,
        # the routers' own routes, built once when their modules were imported: an included
        # router (``include_router``) is built again for every app, at its first request
        routes=[route for router in ROUTERS for route in router.routes],
    )
    api.state.settings = settings
    install_error_handlers(api)
    # Outermost last: security headers -> admission -> authentication and size limits.
    api.add_middleware(BodyLimitMiddleware, upload_bytes=int(settings.max_upload_mb * 2**20),
                       json_bytes=int(settings.max_json_mb * 2**20))
    # Each admitted request holds at most two pooled connections: never admit more than the
    # pool (pool_size + overflow = 2 x db_pool_size) can serve next to the workers.
    api.add_middleware(AdmissionMiddleware, max_active=min(settings.max_active_requests, settings.db_pool_size),
                       max_waiting=settings.max_waiting_requests, wait_s=settings.request_wait_s)
    api.add_middleware(SecurityHeadersMiddleware)
    if WEB_DIR.is_dir():
        api.mount("/", ConsoleFiles(directory=WEB_DIR, html=True), name="web")
    return api
