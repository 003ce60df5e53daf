"""Jobs through a test app's API: submit one, wait for its status."""

from __future__ import annotations

import time
from typing import Any

from tests.conftest import auth

OP = auth("operator")
POLL_MIN_S, POLL_MAX_S = 0.02, 0.2
WHOLE = {"include": ["result", "artifacts", "params", "input_hashes"]}  # a job's record whole
# how soon a cancel must end a job, request to recorded outcome: within a second on an idle box
# (the watcher polls every 0.1 s); 1.30-1.35 s seen with the whole suite on the two cores. The
# waits it guards against are a job's minutes, or a process start's 3 s
CANCEL_BOUND_S = 2.0


def submit(client: Any, kind: str, params: dict[str, Any]) -> Any:
    """POST a job of ``kind`` with ``params`` as the operator; the response, unchecked."""
    return client.post("/api/v1/jobs", json={"kind": kind, "params": params}, headers=OP)


def wait_for(client: Any, job_id: str,
             states: tuple[str, ...] = ("succeeded", "needs_attention", "failed", "cancelled"),
             timeout: float = 20.0) -> dict[str, Any]:
    """The job once its status is one of ``states``, whole (``?include=result&include=artifacts``
    ``&include=params&include=input_hashes``: what a test reads).  Polled (the small record) every 20 ms at first, then
    ever less often (every 5 % of the time waited so far, at most every 0.2 s): each poll is a request through
    the whole app (~5 ms of CPU), which a 20 ms poll took from the job it waits for for as
    long as the job ran."""
    start = time.monotonic()
    deadline = start + timeout
    while time.monotonic() < deadline:
        job: dict[str, Any] = client.get(f"/api/v1/jobs/{job_id}", headers=OP).json()
        if job["status"] in states:
            whole: dict[str, Any] = client.get(f"/api/v1/jobs/{job_id}", params=WHOLE, headers=OP).json()
            return whole if whole["status"] in states else job
        time.sleep(min(POLL_MAX_S, max(POLL_MIN_S, (time.monotonic() - start) / 20)))
    raise AssertionError(f"job {job_id} still {job['status']}")
