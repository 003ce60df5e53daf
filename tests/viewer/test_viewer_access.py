"""The 3D view behind the API's auth, tested with a real websocket client (``websockets``)
against the viser server that ``create_app`` starts: no token, a forged or expired token,
or a foreign Origin is refused at the handshake; a valid token connects; each view has
its own focus, drawn only into its own browsers' scenes."""

from __future__ import annotations

import asyncio
import time
from urllib.parse import parse_qs, urlsplit

import msgspec
import numpy as np
import pytest
import viser
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidStatus

from app.reference.s1 import s1_mesh
from app.viewer.access import TokenError, TokenSigner, load_secret
from tests.conftest import auth
from tests.helpers.async_run import run_async
from tests.viewer.conftest import free_port

OP, VIEWER = auth("operator"), auth("viewer")
SUBPROTOCOL = f"viser-v{viser.__version__}"


@pytest.fixture(scope="module")
def served(tmp_path_factory):  # type: ignore[no-untyped-def]
    from fastapi.testclient import TestClient

    from app.main import create_app
    from app.platform.config import load_settings
    from tests.conftest import KEYS

    settings = load_settings({}, data_dir=tmp_path_factory.mktemp("viewer-access"), viewer=True,
                             viewer_port=free_port(), api_keys=",".join(f"{k}:{r}" for r, k in KEYS.items()),
                             embedded_worker=False)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        yield client


def _port(client) -> int:  # type: ignore[no-untyped-def]
    return client.get("/api/v1/viewer", headers=VIEWER).json()["port"]


def _token(client, **body) -> dict:  # type: ignore[no-untyped-def]
    response = client.post("/api/v1/viewer/token", json=body, headers=VIEWER)
    assert response.status_code == 200, response.text
    return response.json()


def _handshake(port: int, token: str | None, origin: str | None) -> tuple[int, bytes]:
    """(HTTP status of the handshake, first bytes received); 101 = accepted."""
    async def attempt() -> tuple[int, bytes]:
        url = f"ws://127.0.0.1:{port}/" + (f"?token={token}" if token is not None else "")
        try:
            async with connect(url, origin=origin, subprotocols=[SUBPROTOCOL], open_timeout=5) as ws:
                first = await asyncio.wait_for(ws.recv(), 5)
                return 101, first if isinstance(first, bytes) else first.encode()
        except InvalidStatus as exc:
            return exc.response.status_code, exc.response.body or b""

    return run_async(attempt)


def test_no_token_forged_or_expired_token_and_foreign_origins_are_refused(served):  # type: ignore[no-untyped-def]
    port = _port(served)
    own = f"http://127.0.0.1:{port}"
    valid = _token(served)["token"]
    view, expiry, signature = valid.split(".")
    secret = load_secret(served.app.state.settings.data_dir)
    expired = TokenSigner(secret, 60, clock=lambda: time.time() - 3600).mint(view).token
    assert _handshake(port, None, own)[0] == 401
    assert _handshake(port, "", own)[0] == 401
    assert _handshake(port, f"{view}.{expiry}.{'0' * 64}", own)[0] == 401          # forged signature
    assert _handshake(port, f"other_view.{expiry}.{signature}", own)[0] == 401     # signature of another view
    assert _handshake(port, expired, own)[0] == 401
    assert _handshake(port, valid, "http://evil.example")[0] == 403
    assert _handshake(port, valid, f"http://127.0.0.1:{port + 1}")[0] == 403
    assert _handshake(port, valid, None)[0] == 403
    status, first = _handshake(port, valid, own)
    assert status == 101 and first                                                 # the scene starts to flow
    assert _handshake(port, valid, f"http://localhost:{port}")[0] == 101


def test_a_refused_handshake_carries_no_data(served):  # type: ignore[no-untyped-def]
    """The refusal is a bare HTTP status with its reason: no part names or ids."""
    part = served.post("/api/v1/parts",
                       files={"file": ("secret-name.stl", s1_mesh(grid_mm=4.0).export(file_type="stl"))},
                       headers=OP).json()
    port = _port(served)
    served.post("/api/v1/viewer/focus", json={"part_id": part["id"]}, headers=OP)
    status, body = _handshake(port, None, f"http://127.0.0.1:{port}")
    assert status == 401 and part["id"].encode() not in body and b"secret-name" not in body


def test_token_endpoint_needs_a_key_and_renews_a_view(served):  # type: ignore[no-untyped-def]
    assert served.post("/api/v1/viewer/token", json={}).status_code == 401
    first = _token(served)
    again = _token(served, view_id=first["view_id"])
    assert again["view_id"] == first["view_id"] and 0 < again["expires_in_s"] <= 120
    assert served.post("/api/v1/viewer/token", json={"view_id": "../x"}, headers=VIEWER).status_code == 422


def test_signer_round_trip_and_expiry():
    now = [1000.0]
    signer = TokenSigner(b"k" * 32, 30, clock=lambda: now[0])
    token = signer.mint("view_a")
    assert signer.verify(token.token) == "view_a" and token.expires_at == 1030
    now[0] = 1031
    with pytest.raises(TokenError, match="expired"):
        signer.verify(token.token)
    with pytest.raises(TokenError):
        TokenSigner(b"x" * 32, 30, clock=lambda: 1000.0).verify(token.token)


def _camera_message() -> bytes:
    return msgspec.msgpack.encode({"type": "ViewerCameraMessage", "wxyz": [1, 0, 0, 0], "position": [0, 0, 100],
                                   "fov": 1.0, "near": 0.1, "far": 1000.0, "image_height": 480, "image_width": 640,
                                   "look_at": [0, 0, 0], "up_direction": [0, 0, 1]})


def test_each_view_has_its_own_focus_drawn_only_into_its_own_browsers(served):  # type: ignore[no-untyped-def]
    viewer = served.app.state.viewer
    port = _port(served)
    stl = s1_mesh(grid_mm=4.0).export(file_type="stl")
    part = served.post("/api/v1/parts", files={"file": ("p.stl", stl)}, headers=OP).json()
    a, b = _token(served), _token(served)

    async def two_browsers() -> None:
        origin = f"http://127.0.0.1:{port}"
        async with connect(f"ws://127.0.0.1:{port}/?token={a['token']}", origin=origin,
                           subprotocols=[SUBPROTOCOL]) as wa, \
                connect(f"ws://127.0.0.1:{port}/?token={b['token']}", origin=origin, subprotocols=[SUBPROTOCOL]) as wb:
            await wa.send(_camera_message())
            await wb.send(_camera_message())
            for _ in range(100):  # both browsers registered with their views
                if viewer.view(a["view_id"]).clients and viewer.view(b["view_id"]).clients:
                    break
                await asyncio.sleep(0.05)
            shown = await asyncio.to_thread(served.post, "/api/v1/viewer/focus",
                                            json={"part_id": part["id"], "view_id": a["view_id"]}, headers=OP)
            assert shown.status_code == 200 and "/focus/part" in shown.json()["nodes"]
            (drawer_a,) = viewer.view(a["view_id"]).clients.values()
            (drawer_b,) = viewer.view(b["view_id"]).clients.values()
            assert "/focus/part" in drawer_a.builder._handles       # drawn into A's own client scene
            assert drawer_b.builder._handles == {}                  # B's browser got nothing
            assert drawer_a.target.client_id != drawer_b.target.client_id

    run_async(two_browsers)
    scene_b = served.get("/api/v1/viewer/scene", params={"view_id": b["view_id"]}, headers=VIEWER).json()
    scene_a = served.get("/api/v1/viewer/scene", params={"view_id": a["view_id"]}, headers=VIEWER).json()
    assert scene_b["nodes"] == {} and scene_a["focus"] == {"part_id": part["id"]}


def test_token_travels_in_the_websocket_url_the_page_builds():
    """The page opens viser with ?websocket=<ws url with ?token=>; the server reads it back."""
    from app.viewer.access import token_from_path

    src = "/?websocket=" + "ws%3A%2F%2F127.0.0.1%3A8080%2F%3Ftoken%3Dv.1.abc"
    ws_url = parse_qs(urlsplit(src).query)["websocket"][0]
    assert token_from_path(urlsplit(ws_url).path + "?" + urlsplit(ws_url).query) == "v.1.abc"


def test_a_browser_camera_is_aimed_at_what_the_view_shows(served):  # type: ignore[no-untyped-def]
    """The camera a connected browser gets looks from the framing position at the scene: viser's
    position setter drags look_at along (orientation kept), so setting look_at first left every
    browser staring past the part at an empty canvas (issues 17 and 19)."""
    viewer = served.app.state.viewer
    port = _port(served)
    part = served.post("/api/v1/parts", files={"file": ("cam.stl", s1_mesh(grid_mm=4.0).export(file_type="stl"))},
                       headers=OP).json()
    grant = _token(served)

    async def browser() -> None:
        origin = f"http://127.0.0.1:{port}"
        async with connect(f"ws://127.0.0.1:{port}/?token={grant['token']}", origin=origin,
                           subprotocols=[SUBPROTOCOL]) as ws:
            await ws.send(_camera_message())   # a browser's camera at (0, 0, 100) looking at the origin
            for _ in range(100):
                if viewer.view(grant["view_id"]).clients:
                    break
                await asyncio.sleep(0.05)
            shown = await asyncio.to_thread(served.post, "/api/v1/viewer/focus",
                                            json={"part_id": part["id"], "view_id": grant["view_id"]}, headers=OP)
            assert shown.status_code == 200
            look_at, position, _near, _far = viewer.view(grant["view_id"]).camera
            (drawer,) = viewer.view(grant["view_id"]).clients.values()
            camera = drawer.target.camera
            assert np.allclose(camera.position, position) and np.allclose(camera.look_at, look_at)
            lo, hi = np.asarray(part["bounds"], float)
            assert np.all(camera.look_at >= lo - 1e-9) and np.all(camera.look_at <= hi + 1e-9)   # at the part
            assert np.linalg.norm(camera.position - camera.look_at) > np.linalg.norm(hi - lo) / 2  # from outside it

    run_async(browser)


def test_the_view_loads_no_environment_map(served):  # type: ignore[no-untyped-def]
    """viser fades its canvas in from 5 % opacity only once its HDR environment map is decoded
    and pre-filtered, which takes tens of seconds under software GL (a lab PC without a GPU,
    headless Chromium): what every browser is sent switches the map off and lights the scene."""
    buffer = served.app.state.viewer.server._websock_server._broadcast_buffer
    sent = list(buffer.message_from_id.values())
    maps = [m for m in sent if type(m).__name__ == "EnvironmentMapMessage"]
    assert maps and all(m.hdri_data is None for m in maps)
    assert any(type(m).__name__ == "AmbientLightMessage" for m in sent)
