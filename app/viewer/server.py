"""The viser 3D view, started next to the API (bound to 127.0.0.1 by default).

Access: every websocket needs a short-lived signed token from the API and an allowed
Origin (``app.viewer.access``); without them the handshake is refused and nothing —
no names, ids or meshes — is sent.  Each token names a *view*; each view has its own
focus, drawn into the per-client scenes of the browsers opened with that view's tokens
(never into the shared scene), so one operator's focus never changes what another sees.
Nothing in the view can move a machine (the panel only changes what is shown).  The
server's port is read back, since viser silently moves to the next port when the asked
one is busy.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from sqlmodel import Session, col, select

from app.domain.errors import Conflict
from app.platform.config import Settings
from app.platform.models import Job, Part
from app.viewer.access import HandshakeGuard, TokenSigner, allowed_origins, guarded_viser_serve, load_secret
from app.viewer.csp import ViewPolicy
from app.viewer.gui import ViewerPanel
from app.viewer.headless import HeadlessTarget
from app.viewer.loaders import load_focus
from app.viewer.offload import ParsePool
from app.viewer.registry import SceneRegistry
from app.viewer.scene_data import FocusScene
from app.viewer.scenes import SceneBuilder
from app.viewer.text import user_text

log = logging.getLogger("conforma.viewer")
JOB_LIST_LIMIT = 50
DEFAULT_VIEW = "default"
MAX_VIEWS = 256


class ViewerStartError(RuntimeError):
    """The view could not be started with its access check in place."""


@dataclass
class _Drawer:
    """One drawing target (a browser's client handle, or the headless recorder)."""

    target: Any
    builder: SceneBuilder
    panel: ViewerPanel


@dataclass
class View:
    """One view's focus: its registry (what it shows), last scene and drawers."""

    registry: SceneRegistry
    headless: _Drawer
    scene: FocusScene | None = None
    camera: tuple[np.ndarray, np.ndarray, float, float] | None = None  # look_at, position, near, far
    clients: dict[int, _Drawer] = field(default_factory=dict)


class Viewer:
    """A running viser server with per-view Conforma scenes and panels."""

    def __init__(self, server: Any, runtime: Any = None, host: str = "127.0.0.1",
                 guard: HandshakeGuard | None = None) -> None:
        self.server = server
        self.runtime = runtime
        self.host = host
        self.guard = guard
        self._lock = threading.RLock()
        self.parser = ParsePool()
        self._views: dict[str, View] = {}
        self._client_views: dict[int, str] = {}
        self._pending: dict[int, Any] = {}  # clients ready before their view was known
        if guard is not None:
            server._websock_server.on_client_connect(self._on_socket)
        server.on_client_connect(self._on_client)
        server.on_client_disconnect(self._on_client_gone)

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    def stop(self) -> None:
        self.parser.close()
        self.server.stop()

    # views -----------------------------------------------------------------------------
    def view(self, view_id: str = DEFAULT_VIEW) -> View:
        with self._lock:
            view = self._views.get(view_id)
            if view is None:
                if len(self._views) >= MAX_VIEWS:  # forget the oldest view without browsers
                    idle = next((k for k, v in self._views.items() if not v.clients and k != DEFAULT_VIEW), None)
                    if idle is not None:
                        del self._views[idle]
                registry = SceneRegistry()
                view = View(registry, self._drawer(HeadlessTarget(), registry, view_id))
                self._views[view_id] = view
            return view

    def _drawer(self, target: Any, registry: SceneRegistry, view_id: str) -> _Drawer:
        builder = SceneBuilder(target, registry)

        def select(part_id: str | None, job_id: str | None) -> None:
            self._select_from_panel(view_id, part_id, job_id)

        return _Drawer(target, builder, ViewerPanel(target, builder, registry, select, self._recent))

    @property
    def builder(self) -> SceneBuilder:
        """The default view's recording builder (tests read its nodes)."""
        return self.view().headless.builder

    @property
    def registry(self) -> SceneRegistry:
        return self.view().registry

    # connections -------------------------------------------------------------------------
    def _on_socket(self, conn: Any) -> None:
        """A websocket passed the handshake: note which view its token named."""
        raw = getattr(self.server._websock_server, "_live_connections", {}).get(conn.client_id)
        view_id = self.guard.view_of(raw) if (self.guard is not None and raw is not None) else None
        if view_id is None:
            log.error("viewer: no view for client %s; it will show nothing", conn.client_id)
            return
        with self._lock:
            self._client_views[conn.client_id] = view_id
            waiting = self._pending.pop(conn.client_id, None)
        if waiting is not None:  # the browser was ready before its handshake was noted: draw now
            self._on_client(waiting)

    def _on_client(self, client: Any) -> None:
        """A browser is ready: give it its own panel and draw its view's focus."""
        with self._lock:
            view_id = self._client_views.get(client.client_id, None if self.guard is not None else DEFAULT_VIEW)
            if view_id is None:  # viser may report the client before the handshake callback ran
                self._pending[client.client_id] = client
                return
            view = self.view(view_id)
            drawer = self._drawer(client, view.registry, view_id)
            view.clients[client.client_id] = drawer
            scene = view.scene
        drawer.panel.refresh_jobs()
        if scene is not None:
            self._draw(view, drawer, scene)

    def _on_client_gone(self, client: Any) -> None:
        with self._lock:
            self._pending.pop(client.client_id, None)
            view_id = self._client_views.pop(client.client_id, DEFAULT_VIEW)
            view = self._views.get(view_id)
            if view is not None:
                view.clients.pop(client.client_id, None)

    # focus -----------------------------------------------------------------------------
    def focus(self, part_id: str | None = None, job_id: str | None = None,
              view_id: str = DEFAULT_VIEW) -> dict[str, Any]:
        """Show a part or a job (read from the runtime) in one view; returns its snapshot.
        Raises NotFound for an unknown id (nothing changes then)."""
        scene = load_focus(self.runtime, part_id=part_id, job_id=job_id, parser=self.parser)
        snapshot = self.show(scene, view_id)
        for drawer in list(self.view(view_id).clients.values()):
            drawer.panel.refresh_jobs(current=job_id or part_id)
        return snapshot

    def show(self, scene: FocusScene, view_id: str = DEFAULT_VIEW) -> dict[str, Any]:
        """Draw an already loaded scene in one view (also used by tests and benchmarks)."""
        view = self.view(view_id)
        with self._lock:
            view.scene = scene
            view.registry.reset(scene.focus)
            for note in scene.notes:
                view.registry.note(note)
            view.camera = _camera_for(scene)
            drawers = [view.headless, *view.clients.values()]
        for drawer in drawers:
            self._draw(view, drawer, scene)
        return view.registry.snapshot()

    def snapshot(self, view_id: str = DEFAULT_VIEW) -> dict[str, Any]:
        """What a view shows (an empty scene for a view nobody has focused or opened)."""
        with self._lock:
            view = self._views.get(view_id)
        return (view.registry if view is not None else SceneRegistry()).snapshot()

    def set_layer(self, view_id: str, index: int, name: str | None = None) -> dict[str, Any]:
        """Show a view's program preview (``name``, default its first) up to layer position
        ``index`` (clipped), nothing above, in every browser of the view; returns the snapshot.
        Conflict when the view shows no program preview."""
        view = self.view(view_id)
        with self._lock:
            drawers = [view.headless, *view.clients.values()]
        names = list(view.headless.builder.previews)
        if not names or (name is not None and name not in names):
            raise Conflict("the view shows no program preview (focus a toolpath, circuit program or print job)",
                           field="name" if name else "view_id", value=name or view_id)
        for drawer in drawers:
            try:
                shown = drawer.builder.show_preview_layer(name or names[0], index)
                drawer.panel.set_slider(name or names[0], shown)
            except Exception:
                if drawer is view.headless:
                    raise
                log.debug("could not draw the layer for a client", exc_info=True)
        return view.registry.snapshot()

    def show_head(self, view_id: str, position_mm: Any, line: int | None) -> dict[str, Any]:
        """Draw a machine's head at ``position_mm`` (the program's frame) in every browser of a view."""
        view = self.view(view_id)
        with self._lock:
            drawers = [view.headless, *view.clients.values()]
        for drawer in drawers:
            try:
                drawer.builder.show_head(position_mm, line)
            except Exception:
                if drawer is view.headless:
                    raise
                log.debug("could not draw the head for a client", exc_info=True)
        return view.registry.snapshot()

    def _draw(self, view: View, drawer: _Drawer, scene: FocusScene) -> None:
        try:
            drawer.builder.draw(scene)
            drawer.panel.show(scene)
            if view.camera is not None and drawer is not view.headless:
                look_at, position, near, far = view.camera
                camera = drawer.target.camera
                camera.far, camera.near = far, near
                # position FIRST: viser's position setter moves look_at along with the
                # camera (keeping its orientation), so a look_at set before it is shifted
                # away and the camera stares past the part at an empty canvas
                camera.position = position
                camera.look_at = look_at
        except Exception:  # a browser disconnecting meanwhile
            if drawer is view.headless:
                raise
            log.debug("could not draw for a client", exc_info=True)

    def _select_from_panel(self, view_id: str, part_id: str | None, job_id: str | None) -> None:
        try:
            self.focus(part_id=part_id, job_id=job_id, view_id=view_id)
        except Exception:
            log.exception("viewer could not show %s", job_id or part_id)

    def _recent(self) -> list[tuple[str, str]]:
        """(label, id) of recent parts and jobs for the panel's selector."""
        if self.runtime is None:
            return []
        with Session(self.runtime.engine) as session:
            parts = session.exec(select(Part).order_by(col(Part.created_at).desc()).limit(JOB_LIST_LIMIT)).all()
            jobs = session.exec(select(Job).order_by(col(Job.created_at).desc()).limit(JOB_LIST_LIMIT)).all()
        return [(f"part {user_text(p.name, 'label', 80)} ({p.id})", p.id) for p in parts] + \
               [(f"{j.kind} {j.status} ({j.id})", j.id) for j in jobs]


def _camera_for(scene: FocusScene) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """(look_at, position, near, far) framing the scene, or None without bounds: what is shown
    on the part (a trace, a program, a circuit) with at least 40 % of the whole scene's extent
    around it for context; the whole part when nothing else is shown."""
    bounds = scene.bounds()
    if bounds is None:
        return None
    shown = scene.bounds(include_part=False)
    if shown is not None:
        half = np.maximum((shown[1] - shown[0]) / 2, 0.2 * (bounds[1] - bounds[0]))
        bounds = np.stack([shown.mean(axis=0) - half, shown.mean(axis=0) + half])
    centre = bounds.mean(axis=0)
    size = max(float(np.linalg.norm(bounds[1] - bounds[0])), 1.0)
    # near at 1 % of the framed size: depth steps stay ~1 um at the framed distance, so a deviation
    # ribbon 10 um above the part does not z-fight with it
    return centre, centre + size * np.array([0.6, -0.9, 0.8]), max(size * 1e-2, 0.01), max(20.0 * size, 500.0)


class OriginPolicy:
    """The Origins allowed to open the view's websocket; none until the port is known."""

    def __init__(self, host: str, extra: list[str]) -> None:
        self.host = host
        self.extra = extra
        self._allowed: frozenset[str] = frozenset()

    def set_port(self, port: int) -> None:
        self._allowed = allowed_origins(self.host, port, self.extra)

    def __call__(self) -> frozenset[str]:
        return self._allowed


def make_guard(settings: Settings) -> tuple[HandshakeGuard, OriginPolicy]:
    """The handshake check for ``settings`` and its origin policy (port set after start)."""
    signer = TokenSigner(load_secret(settings.data_dir, settings.viewer_secret), settings.viewer_token_ttl_s)
    policy = OriginPolicy(settings.viewer_host, [o.strip() for o in settings.viewer_origins.split(",") if o.strip()])
    return HandshakeGuard(signer, policy), policy


def check_page_policy(host: str, port: int, timeout_s: float = 30.0) -> str:
    """GET the view's page from the running server and return its CSP; ViewerStartError
    unless it carries one that allows the page's scripts by hash and nothing inline."""
    import http.client

    address = "127.0.0.1" if host in ("0.0.0.0", "", "::") else host.strip("[]")
    connection = http.client.HTTPConnection(address, port, timeout=timeout_s)
    try:
        connection.request("GET", "/", headers={"Accept-Encoding": "identity"})
        response = connection.getresponse()
        response.read()
        policy = response.getheader("Content-Security-Policy") or ""
    except OSError as exc:
        raise ViewerStartError(f"could not read the view's page to check its CSP: {exc}") from exc
    finally:
        connection.close()
    script = next((d for d in policy.split(";") if d.strip().startswith("script-src ")), "")
    if response.status != 200 or "'sha256-" not in script or "'unsafe-inline'" in script:
        raise ViewerStartError(f"the view's page is served without its script hashes (HTTP {response.status}, "
                               f"CSP {policy[:200]!r}): the view is not served")
    return policy


def start_viewer(settings: Settings, runtime: Any) -> Viewer:
    import viser

    guard, origins = make_guard(settings)
    policy = ViewPolicy(origins, settings.port)
    with guarded_viser_serve(guard, policy) as installed:
        server = viser.ViserServer(host=settings.viewer_host, port=settings.viewer_port, verbose=False)
    if not installed.is_set():
        server.stop()
        raise ViewerStartError("viser did not start through websockets.asyncio.server.serve: the view's "
                               "access check could not be installed, so the view is not served")
    origins.set_port(int(server.get_port()))
    try:
        check_page_policy(settings.viewer_host, int(server.get_port()))
    except ViewerStartError:
        server.stop()
        raise
    server.scene.set_up_direction("+z")
    server.scene.configure_environment_map(None)
    server.scene.configure_default_lights(True, cast_shadow=False)
    server.scene.add_light_ambient("/ambient", intensity=1.0)
    server.scene.add_grid("/grid", width=200.0, height=200.0, cell_size=10.0)
    viewer = Viewer(server, runtime, host=settings.viewer_host, guard=guard)
    log.info("viewer on http://%s:%d (tokens required)", settings.viewer_host, viewer.port)
    return viewer
