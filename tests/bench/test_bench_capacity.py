"""Concurrent job submitters against a real ``conforma serve``: 10, 100 and 1,000 at once
(plus 10 % simultaneous retries of the same Idempotency-Key).  Asserts 0 x 500, a clean
busy answer (503/429 + Retry-After) for anyone turned away, no duplicate for a retried key
and no job without its 202; prints throughput and p95 latency against the 10-client run."""

from __future__ import annotations

import numpy as np
import pytest

from tests.api.submitters import capacity_server, count_jobs, submit_all

KEY = "bench-capacity-key"


@pytest.fixture(scope="module")
def server(tmp_path_factory):  # type: ignore[no-untyped-def]
    with capacity_server(tmp_path_factory.mktemp("bench-capacity") / "data",
                         tmp_path_factory.mktemp("logs") / "serve.log", KEY) as base:
        yield base


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
