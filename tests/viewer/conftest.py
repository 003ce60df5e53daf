"""A real viser server on a free port, bound to 127.0.0.1."""

from __future__ import annotations

import socket
from collections.abc import Iterator

import pytest


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


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
