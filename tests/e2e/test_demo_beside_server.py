"""`conforma demo` beside a running `conforma serve` on the same data directory (the first
thing a newcomer tries after `make run`): the server runs the demo's jobs and shows them;
a second server on the same data directory is refused with a readable reason."""

from __future__ import annotations

import subprocess

import httpx

from tests.e2e.test_serve import CONFORMA, ROOT, env_for, start
from tests.helpers.processes import free_port, stop, wait_healthy

ADMIN = "demo-admin-key-1"


def test_demo_runs_through_the_server_that_owns_the_data_dir(tmp_path):
    data = tmp_path / "data"
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    env = env_for(data, CONFORMA_API_KEYS=f"{ADMIN}:admin")
    log = tmp_path / "serve.log"
    server = start(["serve", "--port", str(port)], env, log)
    try:
        wait_healthy(base, server, log=log)
        second = subprocess.run(CONFORMA + ["serve", "--port", str(free_port())], env=env, cwd=ROOT,
                                capture_output=True, text=True, timeout=60)
        assert second.returncode == 1 and "already runs on" in second.stderr
        # the part's meshes as coarse as tests/test_demo.py's run: the same loop, a third of the faces
        demo = subprocess.run(CONFORMA + ["demo", "--traces", "1-2", "--grid-mm", "0.5"], env=env, cwd=ROOT,
                              capture_output=True, text=True, timeout=300)
        assert demo.returncode == 0, demo.stdout[-2000:] + demo.stderr[-2000:] + log.read_text()[-2000:]
        assert "the demo's jobs run there" in demo.stdout and "err max after" in demo.stdout
        headers = {"Authorization": f"Bearer {ADMIN}"}
        loops = httpx.get(f"{base}/api/v1/jobs?kind=closed_loop", headers=headers).json()["items"]
        assert [j["status"] for j in loops] == ["succeeded"]
        assert loops[0]["id"] in demo.stdout  # run by the server: the demo started no worker
        for row in loops[0]["result"]["table"]:
            assert row["standoff_max_after_um"] <= 10.0
    finally:
        stop(server)
