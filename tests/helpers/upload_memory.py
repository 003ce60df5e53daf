"""Peak memory of one upload, measured on a real `conforma serve` process (Linux /proc).

The server's peak resident set (VmHWM) is reset to its current RSS through
``/proc/<pid>/clear_refs`` just before the upload (root, or the process's owner), so
``VmHWM`` after the upload minus ``VmRSS`` before is the upload's peak growth.  The file
is streamed from disk by the client, which is another process.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
import trimesh

from tests.helpers.processes import free_port, stop, wait_healthy

ROOT = Path(__file__).resolve().parents[2]
KEY = "upload-memory-key-1"


@dataclass(frozen=True)
class UploadPeak:
    """``growth_bytes``: peak RSS growth of the server during the upload; ``file_bytes``;
    ``part``: the API's response."""

    growth_bytes: int
    file_bytes: int
    part: dict

    @property
    def ratio(self) -> float:
        return self.growth_bytes / self.file_bytes


def _status(pid: int, field: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    raise AssertionError(f"{field} not in /proc/{pid}/status")


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of process ``pid`` so far (every thread), s."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@dataclass(frozen=True)
class ProgramUpload:
    """One ``POST /programs`` on a real server: ``growth_bytes`` of its peak RSS, ``cpu_s``
    the server's CPU time for it (load on the box does not inflate it), ``wall_s``, the body."""

    growth_bytes: int
    cpu_s: float
    wall_s: float
    program: dict


def write_program(path: Path, lines: int) -> None:
    """A program of ``lines`` G1 moves (x 0..99.6, y 0.5..36.5, z 0.2 mm), ~26 bytes a line."""
    with path.open("w") as out:
        for k in range(0, lines, 10_000):
            out.write("".join(f"G1 X{j % 100}.{j % 7} Y{j % 37}.5 Z0.2 F1200\n"
                              for j in range(k, min(k + 10_000, lines))))


def measure_program_upload(path: Path, data_dir: Path) -> ProgramUpload:
    """Start a server on ``data_dir``, warm it up, upload the program at ``path`` and measure."""
    proc, base, headers = start_upload_server(data_dir)
    try:
        wait_healthy(base, proc)
        warm = httpx.post(f"{base}/api/v1/programs", files={"file": ("w.gcode", b"G1 X1\n")}, headers=headers,
                          timeout=120)
        assert warm.status_code == 201, warm.text
        Path(f"/proc/{proc.pid}/clear_refs").write_text("5")
        before, cpu = _status(proc.pid, "VmRSS"), cpu_seconds(proc.pid)
        started = time.perf_counter()
        with path.open("rb") as handle:
            response = httpx.post(f"{base}/api/v1/programs", files={"file": (path.name, handle)}, headers=headers,
                                  timeout=1800)
        wall = time.perf_counter() - started
        assert response.status_code == 201, response.text
        return ProgramUpload(_status(proc.pid, "VmHWM") - before, cpu_seconds(proc.pid) - cpu, wall, response.json())
    finally:
        stop(proc)


def start_upload_server(data_dir: Path) -> tuple[subprocess.Popen, str, dict[str, str]]:
    """A ``conforma serve`` of its own on ``data_dir`` (no viewer, no embedded worker, 1000 MB
    uploads, one operator key): (the process, its base URL, the key's headers)."""
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("CONFORMA_")}
    env.update({"PYTHONPATH": str(ROOT), "CONFORMA_DATA_DIR": str(data_dir), "CONFORMA_VIEWER": "false",
                "CONFORMA_EMBEDDED_WORKER": "false", "CONFORMA_API_KEYS": f"{KEY}:operator",
                "CONFORMA_MAX_UPLOAD_MB": "1000"})
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "serve", "--port", str(port)], env=env, cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    return proc, f"http://127.0.0.1:{port}", {"Authorization": f"Bearer {KEY}"}


def measure_upload(stl: Path, data_dir: Path) -> UploadPeak:
    """Start a server on ``data_dir``, warm it up, upload ``stl`` and measure."""
    proc, base, headers = start_upload_server(data_dir)
    try:
        wait_healthy(base, proc)
        warm = trimesh.creation.icosphere(subdivisions=3).export(file_type="stl")
        for _ in range(2):
            assert httpx.post(f"{base}/api/v1/parts", files={"file": ("warm.stl", warm)}, headers=headers,
                              timeout=60).status_code == 201
        Path(f"/proc/{proc.pid}/clear_refs").write_text("5")
        before = _status(proc.pid, "VmRSS")
        assert _status(proc.pid, "VmHWM") <= before + (1 << 20), "clear_refs did not reset VmHWM"
        with open(stl, "rb") as handle:
            response = httpx.post(f"{base}/api/v1/parts", files={"file": (stl.name, handle)}, headers=headers,
                                  timeout=600)
        assert response.status_code == 201, response.text
        peak = _status(proc.pid, "VmHWM")
        return UploadPeak(peak - before, stl.stat().st_size, response.json())
    finally:
        stop(proc)
