"""The viser 3D view, started next to the API (bound to 127.0.0.1 by default).

viser has no authentication: nothing in it can move a machine (the panel only changes
what is shown).  The web pages tell the view what to show through the API
(``POST /api/v1/viewer/focus``); the view reads job records and artifacts through the
runtime.  The server's port is read back, since viser silently moves to the next port
when the asked one is busy.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

import numpy as np
from sqlmodel import Session, select

from app.config import Settings
from app.models import Job, Part
from app.viewer.gui import ViewerPanel
from app.viewer.loaders import load_focus
from app.viewer.offload import ParsePool
from app.viewer.registry import SceneRegistry
from app.viewer.scene_data import FocusScene
from app.viewer.scenes import SceneBuilder

log = logging.getLogger("conforma.viewer")
JOB_LIST_LIMIT = 50


class Viewer:
    """A running viser server with the Conforma scenes and panel."""

    def __init__(self, server: Any, runtime: Any = None, host: str = "127.0.0.1") -> None:
        self.server = server
        self.runtime = runtime
        self.host = host
        self.registry = SceneRegistry()
        self.builder = SceneBuilder(server, self.registry)
        self._lock = threading.Lock()
        self.parser = ParsePool()
        self.panel = ViewerPanel(server, self.builder, self.registry, self._select_from_panel, self._recent)
        if runtime is not None:
            self.panel.refresh_jobs()

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    def stop(self) -> None:
        self.parser.close()
        self.server.stop()

    # focus -----------------------------------------------------------------------------
    def focus(self, part_id: str | None = None, job_id: str | None = None) -> dict[str, Any]:
        """Show a part or a job (read from the runtime); returns the registry snapshot.
        Raises NotFound for an unknown id (nothing changes then)."""
        scene = load_focus(self.runtime, part_id=part_id, job_id=job_id, parser=self.parser)
        self.show(scene)
        self.panel.refresh_jobs(current=job_id or part_id)
        return self.registry.snapshot()

    def show(self, scene: FocusScene) -> dict[str, Any]:
        """Draw an already loaded scene (also used by tests and benchmarks)."""
        with self._lock:
            self.registry.reset(scene.focus)
            for note in scene.notes:
                self.registry.note(note)
            self.builder.draw(scene)
            self.panel.show(scene)
            self._aim_camera(scene)
        return self.registry.snapshot()

    def snapshot(self) -> dict[str, Any]:
        return self.registry.snapshot()

    def _aim_camera(self, scene: FocusScene) -> None:
        bounds = scene.bounds()
        if bounds is None:
            return
        centre = bounds.mean(axis=0)
        size = float(max(np.linalg.norm(bounds[1] - bounds[0]), 1.0))
        eye = centre + size * np.array([0.6, -0.9, 0.8])
        camera = self.server.initial_camera
        camera.far = max(10.0 * size, 1000.0)
        camera.near = max(size * 1e-3, 0.01)
        camera.look_at = centre
        camera.position = eye
        for client in self.server.get_clients().values():
            try:
                client.camera.far = camera.far
                client.camera.near = camera.near
                client.camera.look_at = centre
                client.camera.position = eye
            except Exception:  # a client disconnecting meanwhile
                log.debug("could not move a client's camera", exc_info=True)

    def _select_from_panel(self, part_id: str | None, job_id: str | None) -> None:
        try:
            self.focus(part_id=part_id, job_id=job_id)
        except Exception:
            log.exception("viewer could not show %s", job_id or part_id)

    def _recent(self) -> list[tuple[str, str]]:
        """(label, id) of recent parts and jobs for the panel's selector."""
        if self.runtime is None:
            return []
        with Session(self.runtime.engine) as session:
            parts = session.exec(select(Part).order_by(Part.created_at.desc()).limit(JOB_LIST_LIMIT)).all()
            jobs = session.exec(select(Job).order_by(Job.created_at.desc()).limit(JOB_LIST_LIMIT)).all()
        return [(f"part {p.name} ({p.id})", p.id) for p in parts] + \
               [(f"{j.kind} {j.status} ({j.id})", j.id) for j in jobs]


def start_viewer(settings: Settings, runtime: Any) -> Viewer:
    import viser

    server = viser.ViserServer(host=settings.viewer_host, port=settings.viewer_port, verbose=False)
    server.scene.set_up_direction("+z")
    server.scene.add_grid("/grid", width=200.0, height=200.0, cell_size=10.0)
    viewer = Viewer(server, runtime, host=settings.viewer_host)
    log.info("viewer on http://%s:%d", settings.viewer_host, viewer.port)
    return viewer
