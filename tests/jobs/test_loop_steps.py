"""A trace that starts at a pad centre, where its plan has no probe: the loop holds the end
at the nearest probe's height within its stated bound (and says so), or stops naming the
trace beyond it; never a trace left out silently."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from sqlmodel import Session

from app.domain.errors import ConformaError
from app.jobs.loop_steps import HOLD_ROUND_MM, end_hold
from app.jobs.results.models import ReconstructResult
from app.platform.models import Job
from app.reference.s1 import as_made, s1_mesh, s1_traces
from tests.conftest import auth
from tests.helpers.jobs import submit, wait_for

OP = auth("operator")
PAD_RADIUS_MM = 0.333  # the trace starts at the pad's centre; the probes begin at the pad's edge


def _at_arc_length(points: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Points (m, 3) of the polyline ``points`` (n, 3) at arc lengths ``s`` (m,) mm."""
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    return np.column_stack([np.interp(s, cum, points[:, k]) for k in range(3)])


@pytest.fixture
def pad_trace(client):  # type: ignore[no-untyped-def]
    """A trace of the S1 part and the truth of its as-made part; (trace, truth, length mm)."""
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_mesh(grid_mm=0.5).export(file_type="stl"))},
                       headers=OP).json()
    trace = client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[4].to_api(), headers=OP).json()
    nominal = np.array(trace["nominal"]["points"])
    length = float(np.linalg.norm(np.diff(nominal, axis=0), axis=1).sum())
    return trace, as_made(seed=4, amplitude_mm=0.15), length


def _jobs(client, trace: dict, truth, first_s: float, length: float) -> tuple[Job, Job]:  # type: ignore[no-untyped-def]
    """A plan of ``trace`` and a reconstruction from touches of the true part from ``first_s``
    to its end (nothing nearer its start), as stored jobs."""
    plan = wait_for(client, submit(client, "probe_plan", {"trace_id": trace["id"], "method": "uniform",
                                                          "count": 8}).json()["id"], timeout=120)
    xy = _at_arc_length(np.array(trace["nominal"]["points"]), np.linspace(first_s, length, 12))[:, :2]
    touches = np.column_stack([xy, truth.true_height(xy)])
    rebuilt = wait_for(client, submit(client, "reconstruct", {"trace_id": trace["id"], "points": touches.tolist(),
                                                              "method": "deviation"}).json()["id"], timeout=120)
    assert plan["status"] == rebuilt["status"] == "succeeded", (plan["error"], rebuilt["error"])
    with Session(client.app.state.runtime.engine) as session:
        return session.get(Job, plan["id"]), session.get(Job, rebuilt["id"])  # type: ignore[return-value]


def test_a_trace_starting_at_a_pad_centre_is_held_at_the_nearest_probe_and_printable(client, pad_trace):
    trace, truth, length = pad_trace
    plan, rebuilt = _jobs(client, trace, truth, PAD_RADIUS_MM, length)
    loop = SimpleNamespace(hold_mm=0.0, end_hold_max_mm=0.5)
    hold, held = end_hold(loop, plan, rebuilt, trace["id"])
    assert (held is not None and held[0] == pytest.approx(PAD_RADIUS_MM, abs=1e-6)
            and held[1] == pytest.approx(0, abs=1e-6))
    assert PAD_RADIUS_MM < hold <= PAD_RADIUS_MM + 2 * HOLD_ROUND_MM
    # without the hold the compensation refuses the unprobed start; with it the trace gets its program
    refused = wait_for(client, submit(client, "compensate", {"trace_id": trace["id"],
                                                             "reconstruct_job_id": rebuilt.id}).json()["id"],
                       timeout=120)
    assert refused["status"] == "failed" and "probes cover only" in refused["error"]["detail"]
    held_job = wait_for(client, submit(client, "compensate", {"trace_id": trace["id"], "reconstruct_job_id": rebuilt.id,
                                                              "hold_mm": hold}).json()["id"], timeout=120)
    assert held_job["status"] == "succeeded", held_job["error"]
    assert held_job["result"]["extension_mm"][0] == pytest.approx(PAD_RADIUS_MM, abs=1e-3)
    # the held stretch stands at the first probe's deviation: the program's start is the nominal start
    # shifted by the deviation the reconstruction found at the first probe
    first = held_job["result"]["points"][0]
    start = np.array(trace["nominal"]["points"][0])
    assert np.allclose(first[:2], start[:2], atol=1e-6)
    s_first, dz_first = ReconstructResult.of(rebuilt).deviation.samples[0]
    assert s_first == pytest.approx(PAD_RADIUS_MM, abs=1e-3)
    assert first[2] - (start[2] + trace["standoff_mm"]) == pytest.approx(dz_first, abs=0.005)


def test_a_gap_beyond_the_bound_stops_the_loop_naming_the_trace(client, pad_trace):
    trace, truth, length = pad_trace
    plan, rebuilt = _jobs(client, trace, truth, 0.9, length)
    with pytest.raises(ConformaError) as refused:
        end_hold(SimpleNamespace(hold_mm=0.0, end_hold_max_mm=0.5), plan, rebuilt, trace["id"])
    assert refused.value.value == trace["id"] and "0.900 mm" in refused.value.message
    assert "start" in refused.value.message and "end_hold_max_mm 0.500" in refused.value.message
    # a loop-wide hold_mm that covers it holds nothing more
    assert end_hold(SimpleNamespace(hold_mm=1.0, end_hold_max_mm=0.5), plan, rebuilt, trace["id"]) == (1.0, None)
