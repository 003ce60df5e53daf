"""A real viser server on a free port, bound to 127.0.0.1."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.helpers.processes import free_port

__all__ = ["free_port", "viser_server"]


@pytest.fixture
def viser_server() -> Iterator:  # type: ignore[no-untyped-def]
    import viser

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    server.scene.set_up_direction("+z")
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture
def viewer(viser_server):  # type: ignore[no-untyped-def]
    from app.viewer.server import Viewer

    return Viewer(viser_server, runtime=None)
