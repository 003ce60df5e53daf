"""A program's numbers stay within what its schema says: a coordinate beyond a double is a
422 naming the line, never a stored program with bounds ``null``."""

from __future__ import annotations

from app.api.routes.programs import CHUNK_BYTES
from tests.conftest import auth

OP = auth("operator")


def test_a_400_digit_coordinate_is_a_422_naming_its_line(client):
    text = "G21\nG1 X1 Y1\nG1 X" + "9" * 400 + " Y2\n"
    response = client.post("/api/v1/programs", files={"file": ("big.gcode", text.encode())}, headers=OP)
    assert response.status_code == 422, response.text
    error = response.json()["errors"][0]
    assert error["loc"] == ["file"] and error["value"]["line"] == 3
    assert client.get("/api/v1/programs", headers=OP).json()["total"] == 0


def test_a_program_streamed_in_pieces_keeps_its_facts(client):
    """A program read in three ``CHUNK_BYTES`` pieces, both boundaries inside a line: its line
    and command counts, its bounds and its stored bytes are the ones of the whole text (more
    pieces cross no other kind of boundary)."""
    text = "".join(f"G1 X{k % 50} Y{k % 13} Z0.{k % 9}\n" for k in range(160_000))
    assert 2 * CHUNK_BYTES < len(text) <= 3 * CHUNK_BYTES
    assert text[CHUNK_BYTES - 1] != "\n" and text[2 * CHUNK_BYTES - 1] != "\n"   # pieces end mid-line
    response = client.post("/api/v1/programs", files={"file": ("long.gcode", text.encode())}, headers=OP)
    assert response.status_code == 201, response.text
    body = response.json()
    assert (body["lines"], body["commands"]) == (160_000, 160_000)
    assert body["bounds"] == [[0.0, 0.0, 0.0], [49.0, 12.0, 0.8]]
    stored = client.get(f"/api/v1/programs/{body['id']}/file", headers=OP)
    assert stored.content == text.encode()


def test_the_firmware_s_502_is_documented_on_the_routes_that_talk_to_it(client):
    paths = client.get("/openapi.json").json()["paths"]
    assert "502" in paths["/api/v1/machines/{machine_id}/command"]["post"]["responses"]
    assert "502" not in paths["/api/v1/programs"]["post"]["responses"]
