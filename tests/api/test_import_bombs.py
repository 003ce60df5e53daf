"""Circuit imports are read in a bounded child process: every bomb is a 422 in under a
second with little memory in the API process, while a print on the mock streams on to
its last line; the import's answer is unchanged."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

from app.circuits.budget import MAX_SHAPES
from app.reference.s1 import s1_mesh
from tests.api.test_machines import program_text, register, upload_program
from tests.circuits import bombs
from tests.conftest import auth
from tests.jobs.test_jobs_api import wait_for

OP = auth("operator")
UPLOAD_LIMIT_MB = 200.0


def _seconds_allowed() -> float:
    """1 s on an idle box; on a box running more processes than it has cores, 1 s scaled by
    the queue (the shared CI box runs several suites at once)."""
    return max(1.0, os.getloadavg()[0] / (os.cpu_count() or 1))


def _rss_peak_reset() -> int:
    Path("/proc/self/clear_refs").write_text("5")
    return _status("VmRSS")


def _status(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    raise AssertionError(field)


def _import(client, part_id: str, name: str, data: bytes, **options):
    return client.post(f"/api/v1/parts/{part_id}/circuits:import", headers=OP,
                       files=[("files", (name, data))], data={"options": json.dumps(options)})


BOMBS = [
    ("block-bomb.dxf", lambda: bombs.dxf_block_bomb()),
    ("recursive.dxf", bombs.dxf_recursive_block),
    ("use-bomb.svg", lambda: bombs.svg_use_bomb()),
    ("long-path.svg", lambda: bombs.svg_long_path()),
    ("flashes.gbr", lambda: bombs.gerber_flashes()),
    ("region.gbr", lambda: bombs.gerber_region()),
    ("hits.drl", lambda: bombs.excellon_hits()),
    ("huge.dxf", lambda: bombs.dxf_line(1e308)),
    ("scale.svg", lambda: bombs.svg_scaled("1e300")),
    ("aperture.gbr", lambda: bombs.gerber_flashes(3, "1e20")),
    ("tool.drl", lambda: bombs.excellon_hits(3, "1e20")),
    ("pads-count.gbr", lambda: bombs.gerber_traces_and_pads(MAX_SHAPES // 2 + 1, MAX_SHAPES // 2 + 1)),
]


@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="needs Linux /proc")
def test_every_bomb_is_refused_fast_and_small_while_a_print_streams_on(client):
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_mesh(grid_mm=2.0).export(file_type="stl"))},
                       headers=OP).json()
    warm = _import(client, part["id"], "ok.gbr", bombs.gerber_traces_and_pads(3, 2).encode(), dry_run=True)
    assert warm.status_code == 201, warm.text           # starts the fork server
    machine = register(client, time_scale=1.0).json()
    assert client.post(f"/api/v1/machines/{machine['id']}/connect", headers=OP).json()["state"] == "idle"
    program = upload_program(client, program_text(1500)).json()
    printing = client.post(f"/api/v1/machines/{machine['id']}/print", json={"program_id": program["id"]},
                           headers=OP).json()
    wait_for(client, printing["id"], states=("running",))
    figures = []
    for name, make in BOMBS:
        data = make().encode()
        before = _rss_peak_reset()
        started = time.perf_counter()
        response = _import(client, part["id"], name, data)
        seconds = time.perf_counter() - started
        growth = _status("VmHWM") - before - len(data)  # the test's own copy of the file is not the server's
        figures.append((name, len(data), response.status_code, round(seconds, 3), growth // 2**20))
        assert response.status_code == 422, (name, response.text)
        assert response.json()["errors"][0]["loc"][0] in ("files", "file", "coordinate", "width_mm"), response.text
        assert seconds < _seconds_allowed(), figures[-1]
        assert growth < 2 * UPLOAD_LIMIT_MB * 2**20, figures[-1]
    print(figures)
    still = client.get(f"/api/v1/jobs/{printing['id']}", headers=OP).json()
    assert still["status"] == "running", "the print must outlast the bombs (it is ~16 s of motion)"
    done = wait_for(client, printing["id"], timeout=60)
    assert done["status"] == "succeeded", done["error"]
    status = client.get(f"/api/v1/machines/{machine['id']}", headers=OP).json()
    # the connect's and the program's safe_off (every program starts with its outputs off), then the program
    safe = [status["profile"]["dispense_off"], *status["profile"]["outputs_off"]]
    assert status["mock"]["executed_commands"] == 2 * len(safe) + program["commands"]


@pytest.mark.parametrize("options", ['{"layers": ["\\ud800"]}', '{"\\udfff": 1}'])
def test_a_lone_surrogate_in_the_options_is_a_422_naming_it(client, options):
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_mesh(grid_mm=4.0).export(file_type="stl"))},
                       headers=OP).json()
    response = client.post(f"/api/v1/parts/{part['id']}/circuits:import", headers=OP,
                           files=[("files", ("a.gbr", bombs.gerber_traces_and_pads(1, 0).encode()))],
                           data={"options": options})
    assert response.status_code == 422, response.text
    assert response.json()["errors"][0]["loc"][0] == "options"
