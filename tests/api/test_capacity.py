"""200 concurrent job submitters against a real ``conforma serve`` (without admission, an
exhausted pool answers 500s and creates jobs behind them): every answer is a 202 or a
clean 429/503 problem with Retry-After, never a 500; a retried key never duplicates; the
jobs that exist are exactly the ones whose 202 was sent."""

from __future__ import annotations

import pytest

from tests.api.submitters import capacity_server, count_jobs, submit_all

KEY = "capacity-operator-key"


@pytest.fixture(scope="module")
def server(tmp_path_factory):  # type: ignore[no-untyped-def]
    with capacity_server(tmp_path_factory.mktemp("capacity") / "data", tmp_path_factory.mktemp("logs") / "serve.log",
                         KEY) as base:
        yield base


def test_200_concurrent_submitters_get_202_or_a_clean_busy_answer(server):  # type: ignore[no-untyped-def]
    outcome = submit_all(server, KEY, clients=200, retries=50)
    print(f"\n200 submitters + 50 simultaneous retries: {dict(outcome.codes)} in {outcome.seconds:.1f} s")
    assert outcome.codes[500] == 0 and set(outcome.codes) <= {202, 429, 503}, outcome.codes
    assert outcome.bad_busy == []
    assert all(len(ids) == 1 for ids in outcome.ids_by_key.values())  # a retried key: the same job
    assert count_jobs(server, KEY) == len(outcome.accepted_ids)          # no job behind a non-202
    assert outcome.codes[202] >= 200  # with the default queue bound nobody is turned away here
