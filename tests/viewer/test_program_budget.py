"""A job's program whose arcs would make millions of chords (a warped upload holding a
full circle of radius 1e9 mm): its summary and its 3-D view answer in well under a second
of CPU with a refusal naming the artifact and the line; programs within their budget get
their exact summary, read in the request when small and in a bounded child when not."""

from __future__ import annotations

import math
import resource
import time

import pytest
from sqlmodel import Session

from app.gcode.reader import ArcBudgetError, arc_chord_budget
from app.platform.artifacts import add_artifact
from app.platform.models import Job, new_id, utcnow
from app.viewer.gcode_paths import parse_toolpath
from app.viewer.offload import ParsePool
from app.viewer.program_profile import program_summary
from tests.conftest import auth
from tests.viewer.conftest import free_port

OP = auth("operator")
HUGE_CIRCLE = "G21 G90\nG0 X1000000000 Y0 Z1\nM106\nG2 X1000000000 Y0 I-1000000000 J0 F600\nM107\n"
CIRCLE = "G2 X10 Y0 I-10 J0\n"   # 158 chords at the reader's 0.002 mm


def _cpu_s() -> float:
    """CPU seconds of this process (every thread: the app runs in the test client's) and its
    finished children (a summary's bounded child)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


@pytest.fixture
def vclient(settings_factory):  # type: ignore[no-untyped-def]
    from fastapi.testclient import TestClient

    from app.main import create_app

    with TestClient(create_app(settings_factory(viewer=True, viewer_port=free_port())),
                    raise_server_exceptions=False) as test_client:
        yield test_client


def _job_with_program(client, text: str, name: str = "warped.gcode") -> str:  # type: ignore[no-untyped-def]
    """A succeeded warp job record holding ``text`` as its G-code artifact ``name``."""
    runtime = client.app.state.runtime
    with Session(runtime.engine) as session:
        job = Job(id=new_id("job"), kind="warp_program", status="succeeded", progress=1.0, params={}, result={},
                  created_at=utcnow())
        session.add(job)
        session.flush()
        add_artifact(session, runtime.blobs, job.id, name, text.encode(), "text/x-gcode")
        session.commit()
        return job.id


def test_summary_and_view_of_a_1e9_radius_circle_refuse_naming_the_line_in_milliseconds(vclient):
    # the first summary and view of a process pay for their modules' imports: not what is measured
    warm = _job_with_program(vclient, "G21 G90\nG1 X10 Y0 F600\n" + CIRCLE)
    assert vclient.get(f"/api/v1/jobs/{warm}/artifacts/warped.gcode/summary", headers=OP).status_code == 200
    assert vclient.post("/api/v1/viewer/focus", json={"job_id": warm}, headers=OP).status_code == 200
    job_id = _job_with_program(vclient, HUGE_CIRCLE)
    before = _cpu_s()
    summary = vclient.get(f"/api/v1/jobs/{job_id}/artifacts/warped.gcode/summary", headers=OP)
    spent = _cpu_s() - before
    assert summary.status_code == 422, summary.text
    body = summary.json()
    assert body["errors"][0]["loc"] == ["name"]
    assert "'warped.gcode'" in body["detail"] and "line 4" in body["detail"]
    # 2 pi / 4e-6 rad chords for one turn of radius 1e9 at 0.002 mm: beyond the budget of 80 bytes
    assert body["errors"][0]["value"]["max_chords"] == arc_chord_budget(len(HUGE_CIRCLE))
    assert body["errors"][0]["value"]["line"] == 4
    assert spent < 1.0

    before = _cpu_s()
    shown = vclient.post("/api/v1/viewer/focus", json={"job_id": job_id}, headers=OP)
    spent = _cpu_s() - before
    assert shown.status_code == 200, shown.text
    [note] = shown.json()["notes"]
    assert "warped.gcode: line 4: the arcs need" in note
    assert spent < 1.0


def test_a_small_program_with_arcs_gets_its_exact_summary_in_the_request(vclient):
    text = "G21 G90\nG1 X10 Y0 F600\n" + CIRCLE * 50           # 7,900 chords, 960 bytes
    job_id = _job_with_program(vclient, text)
    summary = vclient.get(f"/api/v1/jobs/{job_id}/artifacts/warped.gcode/summary", headers=OP)
    assert summary.status_code == 200, summary.text
    expected = program_summary(text)
    assert summary.json()["lines"] == 52 and summary.json()["time_s"] == expected["time_s"]
    # 50 turns of 2 pi 10 mm at 10 mm/s: within the accelerations' share of the analytic 314.16 s
    assert summary.json()["time_s"] == pytest.approx(50 * 2 * math.pi * 10 / 10 + 1.0, rel=0.02)


def test_programs_beyond_the_requests_share_are_summarised_in_a_bounded_child(vclient):
    # 200 turns = 31,600 chords: more than a request reads, within the 10,000 + 8 / byte budget
    # of a program padded to 20 KB with feed lines
    pad = "G1 X10 Y0\n" * 1_100
    fits = "G21 G90\nG1 X10 Y0 F600\n" + pad + CIRCLE * 200
    assert 31_600 <= arc_chord_budget(len(fits))
    beyond = "G21 G90\nG1 X10 Y0 F600\n" + CIRCLE * 800                  # 14.4 KB: budget 125,400
    job_fits, job_beyond = _job_with_program(vclient, fits), _job_with_program(vclient, beyond)
    summary = vclient.get(f"/api/v1/jobs/{job_fits}/artifacts/warped.gcode/summary", headers=OP)
    assert summary.status_code == 200, summary.text
    assert summary.json()["lines"] == 1_302 and summary.json()["time_s"] == program_summary(fits)["time_s"]
    refused = vclient.get(f"/api/v1/jobs/{job_beyond}/artifacts/warped.gcode/summary", headers=OP)
    assert refused.status_code == 422, refused.text
    budget = arc_chord_budget(len(beyond))
    first_over = budget // 158 + 1
    assert refused.json()["errors"][0]["value"] == {"name": "warped.gcode", "line": first_over + 2,
                                                    "max_chords": budget, "chords": 158 * first_over}
    # a large program (beyond the request's 64 KiB) is read in the child too
    large = "G21 G90\nG1 X10 Y0 F600\n" + "G1 X10 Y0\n" * 8_000 + CIRCLE * 10
    job_large = _job_with_program(vclient, large)
    summary = vclient.get(f"/api/v1/jobs/{job_large}/artifacts/warped.gcode/summary", headers=OP)
    assert summary.status_code == 200 and summary.json()["time_s"] == program_summary(large)["time_s"]


def test_the_views_parse_draws_every_chord_within_the_budget_and_refuses_beyond():
    text = "G1 X10 Y0 F600\n" + CIRCLE * 3
    pool = ParsePool(inline_chords=100)               # the request's share: 100 chords; the worker: the size's
    try:
        segments = pool.parse(text.encode(), None, None)
        assert segments.count == 1 + 3 * 158 == parse_toolpath(text).count
        before = _cpu_s()
        with pytest.raises(ArcBudgetError) as refused:
            pool.parse(HUGE_CIRCLE.encode(), None, None)
        assert _cpu_s() - before < 0.5                # refused in the API process: no worker asked
        assert refused.value.value["line"] == 4 and "the arcs need" in refused.value.message
    finally:
        pool.close()


def test_a_summary_beyond_the_childs_time_is_a_413_naming_the_artifact(settings_factory):
    from fastapi.testclient import TestClient

    from app.main import create_app

    with TestClient(create_app(settings_factory(import_time_s=0.05)), raise_server_exceptions=False) as client:
        text = "G21 G90\nG1 X10 Y0 F600\n" + "G1 X1\nG1 X2\n" * 20_000       # 240 KB: ~2 s to summarise
        job_id = _job_with_program(client, text)
        refused = client.get(f"/api/v1/jobs/{job_id}/artifacts/warped.gcode/summary", headers=OP)
        assert refused.status_code == 413, refused.text
        assert refused.json()["errors"][0]["loc"] == ["name"]
        assert refused.json()["errors"][0]["value"] == {"name": "warped.gcode", "bytes": len(text)}
        assert "the summary of artifact 'warped.gcode' took longer than 0.05 s" in refused.json()["detail"]
