"""The viser 3D view, started next to the API (bound to 127.0.0.1 by default).

viser has no authentication: nothing in it can move a machine.  Scenes for results are
pushed by the viewer modules (issue 9); here the server is started and its port read
back, since viser silently moves to the next port when the asked one is busy.
"""

from __future__ import annotations

import logging
from typing import Any

from app.config import Settings

log = logging.getLogger("conforma.viewer")


class Viewer:
    """A running viser server."""

    def __init__(self, server: Any) -> None:
        self.server = server

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    def stop(self) -> None:
        self.server.stop()


def start_viewer(settings: Settings, runtime: Any) -> Viewer:
    import viser

    server = viser.ViserServer(host=settings.viewer_host, port=settings.viewer_port, verbose=False)
    server.scene.set_up_direction("+z")
    server.scene.add_grid("/grid", width=200.0, height=200.0, cell_size=10.0)
    viewer = Viewer(server)
    log.info("viewer on http://%s:%d", settings.viewer_host, viewer.port)
    return viewer
