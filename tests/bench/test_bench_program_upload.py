"""A 3M-line program uploaded to a real server: the API process's peak memory growth and
its CPU time (the server's own, so a loaded box does not inflate it).

Run: .venv/bin/python -m pytest tests/bench/test_bench_program_upload.py -s -o addopts="" -q
"""

from __future__ import annotations

import pytest

from tests.helpers.upload_memory import measure_program_upload, write_program

LINES = 3_000_000


@pytest.mark.timeout(1800)
def test_a_3m_line_program_uploads_within_100_mb_of_growth_and_60_s_of_cpu(tmp_path):
    path = tmp_path / "long.gcode"
    write_program(path, LINES)
    upload = measure_program_upload(path, tmp_path / "data")
    growth_mb = upload.growth_bytes / 2**20
    print(f"\n{LINES} lines, {path.stat().st_size / 2**20:.0f} MiB: server CPU {upload.cpu_s:.1f} s "
          f"({LINES / upload.cpu_s / 1000:.0f}k lines/s), wall {upload.wall_s:.1f} s, "
          f"API process peak growth {growth_mb:.0f} MiB")
    assert upload.program["lines"] == LINES
    assert upload.program["bounds"] == [[0.0, 0.5, 0.2], [99.6, 36.5, 0.2]]
    assert growth_mb <= 100
    assert upload.cpu_s <= 60
