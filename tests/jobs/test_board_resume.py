"""A board job whose worker died mid-batch redoes only the traces it had not finished.

The first attempt runs in the test's thread and "dies" (its worker is gone: no finish, no
heartbeat) while storing its second group of finished traces (checkpoints in groups of two
here), i.e. after the files of traces 3 and 4's artifacts were written to be listed in the
checkpoint's commit, before they were recorded as done; its lease then runs out, the reaper puts the job back and the
service's worker runs the second attempt.  That attempt reuses the first K traces (their artifacts untouched, their
computation not repeated), redoes the unrecorded ones and the rest, says how many it reused,
and its result is a clean run's.
"""

from __future__ import annotations

import json
import time

import pytest
from sqlalchemy import update
from sqlmodel import Session, select

from app.jobs import board_checkpoints
from app.jobs.board_checkpoints import TraceCheckpoints, checkpoint_name
from app.jobs.kinds import compensate as compensate_kind
from app.jobs.kinds import reconstruct as reconstruct_kind
from app.platform.models import Artifact, Job
from app.reconstruction.stored import stored_name
from app.reference.s1 import as_made, s1_mesh
from app.runtime.context import JobContext
from app.runtime.registry import get_kind
from app.runtime.store import Claim
from tests.conftest import auth
from tests.helpers.jobs import wait_for
from tests.jobs.test_field_probe_jobs import board, job

OP = auth("operator")
TRACES = (0, 2, 4, 6, 8)  # five S1 traces: lines, arcs and NURBS curves
PROCESS = {"deviation_amplitude_mm": 0.15, "deviation_wavelength_mm": 15.0}
K = 2  # traces the dying attempt finished and recorded


class WorkerDied(Exception):
    """Stands for the SIGKILL of the first attempt's worker."""


@pytest.fixture
def client(settings_factory):
    """The service with compute jobs in its threads (the test counts the second attempt's calls)."""
    from fastapi.testclient import TestClient

    from app.main import create_app

    with TestClient(create_app(settings_factory(compute_isolation="thread")), raise_server_exceptions=False) as c:
        yield c


@pytest.fixture(scope="module")
def meshes():
    truth = as_made(seed=11, amplitude_mm=0.15)
    return s1_mesh(grid_mm=0.6), truth.mesh(grid_mm=0.6).export(file_type="stl")


def probed_board(client, meshes) -> dict:
    """Part, traces, a mock machine holding the as-made part, a field plan and its probe run."""
    made = board(client, meshes, TRACES)
    ids, machine = made["trace_ids"], {"id": made["machine_id"]}
    plan = job(client, "probe_plan", {"trace_ids": ids, "count": 14, **PROCESS})
    run = job(client, "probe_run", {"plan_job_id": plan["id"], "machine_id": machine["id"]})
    return {"trace_ids": ids, "run": run["id"], "machine_id": machine["id"]}


@pytest.fixture
def groups_of_two(monkeypatch):
    """Checkpoints stored every two traces (never by time: the test decides where it dies)."""
    monkeypatch.setattr(board_checkpoints, "CHECKPOINT_TRACES", 2)
    monkeypatch.setattr(board_checkpoints, "CHECKPOINT_S", float("inf"))


def dies_after(client, monkeypatch, kind: str, params: dict, k: int) -> str:
    """Submit a board job, run its first attempt here until it dies storing the checkpoint
    that would record more than ``k`` traces (after the files of the group's outputs it
    stores with the checkpoint are written, before that commit), and let its lease run out;
    the job's id."""
    runtime = client.app.state.runtime
    with monkeypatch.context() as m:  # not handed to a worker: this test runs the first attempt
        m.setattr(runtime, "enqueue", lambda job_id, queue="default": runtime.store.mark_enqueued(job_id))
        submitted = runtime.submit(kind, params)
    claim = runtime.store.claim(submitted.id, "doomed-worker")
    assert isinstance(claim, Claim) and claim.attempt == 1
    real, recorded = TraceCheckpoints.flush, []

    def flush(self):  # type: ignore[no-untyped-def]
        if len(recorded) + len(self.pending) > k:  # dies storing the checkpoint: the files of the
            put_many, written = runtime.blobs.put_many, len(self.outputs)  # group's outputs are written first

            def dying(session, items):  # type: ignore[no-untyped-def]
                put_many(session, items[:written])  # their rows never committed
                raise WorkerDied([p["trace_id"] for p in self.pending])

            m.setattr(runtime.blobs, "put_many", dying)
        else:
            recorded.extend(p["trace_id"] for p in self.pending)
        real(self)

    spec = get_kind(kind)
    with monkeypatch.context() as m, pytest.raises(WorkerDied):
        m.setattr(TraceCheckpoints, "flush", flush)
        spec.run(JobContext(runtime, claim), spec.params.model_validate(claim.params))
    assert recorded == params["trace_ids"][:k]
    with runtime.engine.begin() as conn:  # the dead worker's lease runs out
        conn.execute(update(Job).where(Job.id == submitted.id).values(lease_until=time.time() - 1))
    return submitted.id


def artifacts(client, job_id: str) -> dict[str, tuple[int, str]]:
    """{name: (row id, sha256)} of the job's artifacts."""
    with Session(client.app.state.runtime.engine) as session:
        rows = session.exec(select(Artifact).where(Artifact.job_id == job_id)).all()
    return {a.name: (int(a.id or 0), a.sha256) for a in rows}


def counting(monkeypatch, module, name: str) -> list[int]:
    """Count the calls of ``module.name`` (a list that grows by one per call)."""
    calls: list[int] = []
    real = getattr(module, name)

    def counted(*args, **kwargs):  # type: ignore[no-untyped-def]
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, counted)
    return calls


def test_a_retried_board_compensate_redoes_only_the_unfinished_traces(client, meshes, monkeypatch, groups_of_two):
    setup = probed_board(client, meshes)
    ids, n = setup["trace_ids"], len(TRACES)
    rebuilt = job(client, "reconstruct", {"trace_ids": ids, "probe_run_job_id": setup["run"], "method": "field"})
    params = {"trace_ids": ids, "reconstruct_job_id": rebuilt["id"], "machine_id": setup["machine_id"]}
    job_id = dies_after(client, monkeypatch, "compensate", params, K)
    before = artifacts(client, job_id)
    for half in ids[K:K + 2]:  # their programs were written, but they commit with their checkpoint: not listed
        assert not {f"print.{half}.gcode", f"nominal.{half}.gcode"} & set(before)
    assert [n for n in before if n.startswith("checkpoint.")] == [checkpoint_name(ids[0])]
    calls = counting(monkeypatch, compensate_kind, "_program")
    done = wait_for(client, job_id, timeout=120)  # the reaper requeues it; the service's worker runs it
    assert done["status"] == "succeeded", done["error"]
    assert done["attempts"] == 2
    assert len(calls) == n - K  # the first K traces were not computed again
    assert done["message"] == f"{n}/{n} traces compensated ({K} reused from an earlier attempt)"
    after = artifacts(client, job_id)
    for trace_id in ids[:K]:  # the finished traces' artifacts: the same rows, the same bytes
        for name in (f"print.{trace_id}.gcode", f"nominal.{trace_id}.gcode"):
            assert after[name] == before[name], name
    assert after[checkpoint_name(ids[0])] == before[checkpoint_name(ids[0])]
    assert sorted(n for n in after if n.startswith("checkpoint.")) == sorted(checkpoint_name(t) for t in ids[0::2])
    # the result is a clean run's (its programs differ only by the job id in their header)
    clean = job(client, "compensate", params)
    assert [r["trace_id"] for r in done["result"]["traces"]] == ids
    assert done["result"] == clean["result"]

    def program(job_id: str, name: str) -> bytes:
        return client.get(f"/api/v1/jobs/{job_id}/artifacts/{name}", headers=OP).content

    for row in done["result"]["traces"]:
        for name in (row["print_artifact"], row["nominal_artifact"]):
            assert program(job_id, name) == program(clean["id"], name).replace(clean["id"].encode(), job_id.encode())


def test_a_retried_board_reconstruct_redoes_only_the_unfinished_traces(client, meshes, monkeypatch, groups_of_two):
    setup = probed_board(client, meshes)
    ids, n = setup["trace_ids"], len(TRACES)
    params = {"trace_ids": ids, "probe_run_job_id": setup["run"], "method": "field", "sigma_mm": 0.001}
    job_id = dies_after(client, monkeypatch, "reconstruct", params, K)
    before = artifacts(client, job_id)
    calls = counting(monkeypatch, reconstruct_kind, "_field_trace")
    done = wait_for(client, job_id, timeout=120)
    assert done["status"] == "succeeded", done["error"]
    assert done["attempts"] == 2 and len(calls) == n - K
    assert done["message"] == f"{n}/{n} traces rebuilt ({K} reused from an earlier attempt)"
    after = artifacts(client, job_id)
    for trace_id in ids[:K]:
        assert after[stored_name(trace_id)] == before[stored_name(trace_id)]
    assert after[checkpoint_name(ids[0])] == before[checkpoint_name(ids[0])]
    clean = job(client, "reconstruct", params)
    assert done["result"] == clean["result"]
    for trace_id in ids:  # the stored reconstructions are a clean run's, bit for bit
        assert after[stored_name(trace_id)][1] == artifacts(client, clean["id"])[stored_name(trace_id)][1]


def test_a_checkpoint_is_reused_only_over_whole_artifacts_from_the_same_inputs(client, meshes, groups_of_two):
    setup = probed_board(client, meshes)
    ids = setup["trace_ids"][:2]
    done = job(client, "reconstruct", {"trace_ids": ids, "probe_run_job_id": setup["run"], "method": "field"})
    runtime = client.app.state.runtime
    ctx = JobContext(runtime, Claim(done["id"], "reconstruct", "reader", 1, done["params"]))
    stored = TraceCheckpoints(ctx)
    first, second = json.loads(ctx.artifact_bytes(done["id"], checkpoint_name(ids[0])))["traces"]
    record = first  # one group: both traces
    assert record["row"] == done["result"]["traces"][0] and record["trace_id"] == ids[0]
    assert second["row"] == done["result"]["traces"][1] and second["trace_id"] == ids[1]
    inputs = record["inputs_sha256"]
    assert stored.reusable(ids[0], inputs) == record["row"] and stored.reused == 1
    assert stored.reusable(ids[0], "0" * 64) is None  # other inputs: done again
    assert stored.reusable("trc_never_done", inputs) is None
    # an artifact rewritten after its checkpoint (an attempt killed before it stored the new one)
    other_sha = artifacts(client, done["id"])[stored_name(ids[1])][1]
    with Session(runtime.engine) as session:
        row = session.exec(select(Artifact).where(Artifact.job_id == done["id"],
                                                  Artifact.name == stored_name(ids[0]))).one()
        row.sha256 = other_sha
        session.add(row)
        session.commit()
    assert TraceCheckpoints(ctx).reusable(ids[0], inputs) is None
    # a blob whose bytes do not hash to its name (a damaged file) is never reused
    assert TraceCheckpoints(ctx).reusable(ids[1], second["inputs_sha256"]) == second["row"]
    blob = runtime.blobs.path(other_sha)
    blob.write_bytes(blob.read_bytes()[:-7])
    assert TraceCheckpoints(ctx).reusable(ids[1], second["inputs_sha256"]) is None
    # a damaged checkpoint is read as no checkpoint at all
    group = runtime.blobs.path(artifacts(client, done["id"])[checkpoint_name(ids[0])][1])
    group.write_bytes(group.read_bytes().replace(b'"traces"', b'"tracez"'))
    assert TraceCheckpoints(ctx).earlier == {}
