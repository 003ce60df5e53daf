"""The 3D view under load: 100,000 toolpath segments pushed to viser while the API keeps
answering, and how fast the pages load.

Goal: 100k toolpath segments reach the view without blocking the API; the pages
load in < 1 s on localhost.  Measured against a real ``conforma serve`` process (API,
worker and viewer in one process, as operators run it).  The reference run is the same
API latency probe with the viewer idle, in the same process and minute (noisy machine).

Run: .venv/bin/python -m pytest tests/bench/test_bench_viewer.py -s -o addopts="" -q
"""

from __future__ import annotations

import shutil
import statistics
import threading
import time

import httpx
import numpy as np
import pytest

from app.runtime.registry import JobParams, job_kind
from tests.e2e.test_serve import env_for, free_port, start, stop, wait_healthy

KEY = "bench-viewer-key-1"
SEGMENTS = 100_000
PROBE_PERIOD_S = 0.02


def toolpath_gcode(n: int, seed: int = 0) -> str:
    """A raster-like program of n moves, every 20th a travel move."""
    rng = np.random.default_rng(seed)
    xy = np.cumsum(rng.uniform(-1, 1, size=(n, 2)), axis=0) % 100
    z = np.repeat(np.arange(n // 1000 + 1) * 0.2, 1000)[:n]
    lines = ["G21", "G90", "M83"]
    for i, (x, y) in enumerate(xy):
        if i % 20 == 0:
            lines.append(f"G0 X{x:.3f} Y{y:.3f} Z{z[i]:.3f}")
        else:
            lines.append(f"G1 X{x:.3f} Y{y:.3f} E0.01")
    return "\n".join(lines) + "\n"


class BenchToolpathParams(JobParams):
    segments: int
    seed: int = 0


@job_kind("bench_toolpath", BenchToolpathParams)
def store_bench_toolpath(ctx, params: BenchToolpathParams) -> dict:  # type: ignore[no-untyped-def]
    """Store a synthetic toolpath program as print.gcode (this module is the server's job plugin)."""
    ctx.artifact("print.gcode", toolpath_gcode(params.segments, params.seed).encode(), "text/x-gcode")
    return {"segments": params.segments}


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    data = tmp_path_factory.mktemp("bench-viewer") / "data"
    port, vport = free_port(), free_port()
    proc = start(["serve", "--port", str(port), "--viewer-port", str(vport)],
                 env_for(data, CONFORMA_API_KEYS=f"{KEY}:operator", CONFORMA_LOG_LEVEL="warning",
                         CONFORMA_VIEWER="true",
                         CONFORMA_JOB_PLUGINS="tests.jobs.sample_kinds,tests.bench.test_bench_viewer"),
                 tmp_path_factory.mktemp("logs") / "serve.log")
    base = f"http://127.0.0.1:{port}"
    wait_healthy(base, proc)
    yield base
    stop(proc)


def latency_probe(url: str, headers: dict, stop_event: threading.Event, out: list[float]) -> None:
    with httpx.Client(headers=headers, timeout=60) as client:
        while not stop_event.is_set():
            t0 = time.perf_counter()
            client.get(url).raise_for_status()
            out.append(1000 * (time.perf_counter() - t0))
            time.sleep(PROBE_PERIOD_S)


def listen_to_viewer(api: httpx.Client, frames: list[tuple[float, int]]) -> None:
    """A bare websocket client of the viser server: records (arrival time, bytes) per frame."""
    import viser
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    port = api.get("/api/v1/viewer").json()["port"]
    with connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"], max_size=None,
                 open_timeout=30) as ws:
        while True:
            try:
                message = ws.recv(timeout=120)
            except (TimeoutError, ConnectionClosed):
                return
            frames.append((time.perf_counter(), len(message)))


def wait_for_big_frame(frames: list[tuple[float, int]], after: float, min_bytes: int = 2_000_000,
                       timeout: float = 60.0) -> float:
    """Arrival time of the first frame of at least min_bytes (100k segments: 2.4 MB of float32)."""
    deadline = time.perf_counter() + timeout
    while time.perf_counter() < deadline:
        for t, size in list(frames):
            if t >= after and size >= min_bytes:
                return t
        time.sleep(0.01)
    return float("inf")


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def test_100k_segments_reach_the_view_without_blocking_the_api(served):
    headers = {"Authorization": f"Bearer {KEY}"}
    api = httpx.Client(base_url=served, headers=headers, timeout=120)
    job = api.post("/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": 0}}).json()
    probe_url = f"{served}/api/v1/jobs/{job['id']}"

    def measure(action) -> tuple[list[float], float]:  # type: ignore[no-untyped-def]
        samples: list[float] = []
        stop_event = threading.Event()
        probe = threading.Thread(target=latency_probe, args=(probe_url, headers, stop_event, samples))
        probe.start()
        time.sleep(0.3)
        t0 = time.perf_counter()
        action()
        elapsed = time.perf_counter() - t0
        time.sleep(0.3)
        stop_event.set()
        probe.join()
        return samples, elapsed

    def idle() -> None:
        time.sleep(3.0)

    # push the 100k-segment scene through the viewer object of the server process: the
    # API's focus endpoint reads the artifact (via the runtime), parses and pushes it
    from app.viewer.gcode_paths import parse_toolpath

    text = toolpath_gcode(SEGMENTS)
    t0 = time.perf_counter()
    parsed = parse_toolpath(text)
    parse_s = time.perf_counter() - t0
    assert parsed.count == SEGMENTS

    ref, _ = measure(idle)

    pushes: list[tuple[str, float, float]] = []
    jobs = [_job_with_artifact(api, seed) for seed in (1, 2)]
    frames: list[tuple[float, int]] = []
    listener = threading.Thread(target=listen_to_viewer, args=(api, frames), daemon=True)
    listener.start()
    time.sleep(1.0)

    def push() -> None:
        for label, job_id in (("cold, program 1", jobs[0]), ("cold, program 2", jobs[1]), ("warm, program 1", jobs[0])):
            t = time.perf_counter()
            response = api.post("/api/v1/viewer/focus", json={"job_id": job_id})
            response.raise_for_status()
            done = time.perf_counter()
            arrived = wait_for_big_frame(frames, after=t)
            pushes.append((label, done - t, arrived - t))

    loaded, _elapsed = measure(push)
    scene = api.get("/api/v1/viewer/scene").json()
    counts = {k: v["count"] for k, v in scene["nodes"].items() if "/toolpaths/" in k}
    print(f"\n100k-segment toolpath -> viser, API latency probe every {PROBE_PERIOD_S * 1000:.0f} ms "
          f"(GET /api/v1/jobs/{{id}}):")
    print(f"  {'run':<34}{'n':>6}{'p50 ms':>9}{'p95 ms':>9}{'max ms':>9}")
    for label, s in (("viewer idle (reference)", ref), ("while pushing 3 x 100k segments", loaded)):
        print(f"  {label:<34}{len(s):6d}{pct(s, 50):9.1f}{pct(s, 95):9.1f}{max(s):9.1f}")
    print(f"  p95 ratio loaded/idle: {pct(loaded, 95) / pct(ref, 95):.2f}")
    for label, request_s, arrived_s in pushes:
        print(f"  focus {label}: request {request_s:.2f} s, 100k segments received by a viewer client after "
              f"{arrived_s:.2f} s")
    print(f"  G-code parse alone (this process): {parse_s:.2f} s; nodes: {counts}")
    assert sum(counts.values()) >= 0.999 * SEGMENTS and len(counts) <= 4  # zero-length moves are dropped
    assert pct(loaded, 95) < 250, f"API p95 while pushing: {pct(loaded, 95):.0f} ms"
    assert all(arrived < 30 for _, _, arrived in pushes)


def _job_with_artifact(api: httpx.Client, seed: int) -> str:
    """A succeeded job whose print.gcode holds SEGMENTS moves (a different program per seed)."""
    job_id = api.post("/api/v1/jobs", json={"kind": "bench_toolpath", "params": {"segments": SEGMENTS, "seed": seed}}
                      ).json()["id"]
    for _ in range(1200):
        job = api.get(f"/api/v1/jobs/{job_id}?include=result&include=artifacts").json()
        if job["status"] in ("succeeded", "failed"):
            assert job["status"] == "succeeded", job["error"]
            return job_id
        time.sleep(0.1)
    raise AssertionError("the artifact job did not finish")


def test_pages_load_under_one_second(served):
    if shutil.which("chromium") is None:
        pytest.skip("chromium is not installed")
    pytest.importorskip("playwright.sync_api")
    from playwright.sync_api import sync_playwright

    from tests.e2e.browser.conftest import CHROMIUM_ARGS

    rows = []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=shutil.which("chromium"), args=CHROMIUM_ARGS)
        context = browser.new_context(base_url=served)
        context.add_init_script(f"localStorage.setItem('conforma.apiKey', {KEY!r});")
        page = context.new_page()
        for name in ("index", "parts", "traces", "jobs", "machines"):
            times = []
            for _ in range(5):
                t0 = time.perf_counter()
                page.goto(f"/{name}.html", wait_until="load")
                page.wait_for_selector("body[data-ready]")  # the page's first data is shown
                times.append(time.perf_counter() - t0)
            rows.append((name, statistics.median(times), max(times)))
        browser.close()
    print("\npage load on localhost (headless chromium; navigation to first data shown, 5 runs):")
    print(f"  {'page':<10}{'median s':>10}{'max s':>8}")
    for name, med, worst in rows:
        print(f"  {name:<10}{med:10.3f}{worst:8.3f}")
    assert all(med < 1.0 for _, med, _ in rows)
