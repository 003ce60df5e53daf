"""A 3M-line program uploaded to a real server: the API process's peak memory growth.

Run: .venv/bin/python -m pytest tests/bench/test_bench_program_upload.py -s -o addopts="" -q
"""

from __future__ import annotations

import time
from pathlib import Path

import httpx
import pytest

from tests.processes import stop, wait_healthy
from tests.upload_memory import _status, start_upload_server

LINES = 3_000_000


@pytest.mark.timeout(1800)
def test_a_3m_line_program_uploads_within_100_mb_of_growth(tmp_path):
    path = tmp_path / "long.gcode"
    with path.open("w") as out:
        for k in range(0, LINES, 10_000):
            out.write("".join(f"G1 X{j % 100}.{j % 7} Y{j % 37}.5 Z0.2 F1200\n" for j in range(k, k + 10_000)))
    proc, base, headers = start_upload_server(tmp_path / "data")
    try:
        wait_healthy(base, proc)
        warm = httpx.post(f"{base}/api/v1/programs", files={"file": ("w.gcode", b"G1 X1\n")}, headers=headers,
                          timeout=120)
        assert warm.status_code == 201
        Path(f"/proc/{proc.pid}/clear_refs").write_text("5")
        before = _status(proc.pid, "VmRSS")
        started = time.perf_counter()
        with path.open("rb") as handle:
            response = httpx.post(f"{base}/api/v1/programs", files={"file": (path.name, handle)}, headers=headers,
                                  timeout=1200)
        seconds = time.perf_counter() - started
        assert response.status_code == 201, response.text
        growth_mb = (_status(proc.pid, "VmHWM") - before) / 2**20
        print(f"\n{LINES} lines, {path.stat().st_size / 2**20:.0f} MiB: {seconds:.1f} s, "
              f"API process peak growth {growth_mb:.0f} MiB")
        assert response.json()["lines"] == LINES
        assert growth_mb <= 100
    finally:
        stop(proc)
