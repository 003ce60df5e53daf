"""Concurrent job submitters against a real ``conforma serve``: 10, 100 and 1,000 at once
(plus 10 % simultaneous retries of the same Idempotency-Key).  Asserts 0 x 500, a clean
busy answer (503/429 + Retry-After) for anyone turned away, no duplicate for a retried key
and no job without its 202; prints throughput and p95 latency against the 10-client run."""

from __future__ import annotations

import numpy as np
import pytest

from tests.api.submitters import count_jobs, submit_all
from tests.e2e.test_serve import env_for, free_port, start, stop, wait_healthy

KEY = "bench-capacity-key"


@pytest.fixture(scope="module")
def server(tmp_path_factory):  # type: ignore[no-untyped-def]
    port = free_port()
    proc = start(["serve", "--port", str(port)],
                 env_for(tmp_path_factory.mktemp("bench-capacity") / "data", CONFORMA_API_KEYS=f"{KEY}:operator",
                         CONFORMA_LOG_LEVEL="warning", CONFORMA_EMBEDDED_WORKER="false"),
                 tmp_path_factory.mktemp("logs") / "serve.log")
    base = f"http://127.0.0.1:{port}"
    wait_healthy(base, proc)
    yield base
    stop(proc)


def test_submitters_scale_without_server_errors(server):  # type: ignore[no-untyped-def]
    reference = None
    accepted: set[str] = set()
    print("\nclients  retries  answers                      s     req/s   p95 s   per-request vs 10 clients")
    for clients in (10, 100, 1000):
        retries = clients // 10
        outcome = submit_all(server, KEY, clients=clients, retries=retries)
        assert outcome.codes[500] == 0 and set(outcome.codes) <= {202, 429, 503}, outcome.codes
        assert outcome.bad_busy == []
        assert all(len(ids) == 1 for ids in outcome.ids_by_key.values())
        accepted |= outcome.accepted_ids
        assert count_jobs(server, KEY) == len(accepted)
        per_request = outcome.seconds / (clients + retries)
        reference = reference or per_request
        print(f"{clients:7d}  {retries:7d}  {str(dict(outcome.codes)):26s} {outcome.seconds:6.2f}  "
              f"{(clients + retries) / outcome.seconds:7.0f}  {np.percentile(outcome.latencies_s, 95):6.2f}  "
              f"{per_request / reference:6.2f}x")
