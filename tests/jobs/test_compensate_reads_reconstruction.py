"""``compensate`` reads the reconstruction its ``reconstruct`` job stored instead of building it
again, and writes the very program the old way (rebuilding the reconstruction from the
reconstruct job's parameters) wrote: compared byte for byte with that rebuild here."""

from __future__ import annotations

import io
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from app.compensation.standoff import CompensationParams, compensate_trace
from app.geometry.traces import as_trace_polyline
from app.probing import PlanParams
from app.reconstruction import ReconstructParams, reconstruct
from app.reference.s1 import as_made, s1_mesh, s1_traces
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")


@pytest.fixture(scope="module")
def s1_stl() -> bytes:
    return s1_mesh(grid_mm=0.5).export(file_type="stl")


def _submit(client, kind: str, params: dict) -> dict:
    answer = client.post("/api/v1/jobs", json={"kind": kind, "params": params}, headers=OP)
    assert answer.status_code in (200, 201, 202), answer.text
    return wait_for(client, answer.json()["id"], timeout=120.0)


@pytest.mark.parametrize("method", ["interpolate", "deviation", "kriging"])
def test_the_program_from_the_stored_reconstruction_is_the_rebuilt_ones(client, s1_stl, method):
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_stl)}, headers=OP).json()
    trace = client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[6].to_api(), headers=OP).json()
    plan = _submit(client, "probe_plan", {"trace_id": trace["id"], "method": "deviation"})
    xy = np.array(plan["result"]["points"])[:, :2]
    measured = np.column_stack([xy, as_made(seed=3, amplitude_mm=0.15).true_height(xy)])
    rec = _submit(client, "reconstruct", {"trace_id": trace["id"], "points": measured.tolist(), "method": method,
                                          "sigma_mm": 0.001})
    assert rec["status"] == "succeeded", rec["error"]
    assert "reconstruction.npz" in [a["name"] for a in rec["artifacts"]]
    job = _submit(client, "compensate", {"trace_id": trace["id"], "reconstruct_job_id": rec["id"]})
    assert job["status"] == "succeeded", job["error"]
    url = next(a["url"] for a in job["artifacts"] if a["name"] == "print.gcode")
    stored_program = client.get(url, headers=OP).content

    # the old way: the reconstruction built again from the reconstruct job's parameters
    normals = trace["nominal"].get("normals")
    nominal = as_trace_polyline(SimpleNamespace(points=np.array(trace["nominal"]["points"]),
                                              normals=None if normals is None else np.array(normals)))
    rebuilt = reconstruct(nominal, measured.tolist(), method, sigma_mm=0.001,
                          params=ReconstructParams(prior=PlanParams(deviation_amplitude_mm=0.2,
                                                                    deviation_wavelength_mm=20.0).prior()))
    stated = dict(rec["result"])
    assert stated.pop("sigma") == {"sigma_mm": 0.001, "source": "params"}  # the job states the noise it used
    assert rebuilt.to_result() == stated
    mesh = trimesh.load(io.BytesIO(s1_stl), file_type="stl")
    path = compensate_trace(rebuilt, CompensationParams(
        standoff_mm=trace["standoff_mm"], feed_mm_min=trace.get("feed_mm_min") or 300.0, chord_error_mm=0.002,
        dialect="marlin", clearance_mm=2.0,  # no dispense commands: the dialect's, as the job without a machine
        part_max_z_mm=float(mesh.bounds[1][2]), hold_mm=0.0, tool=None, tool_offset_mm=(0.0, 0.0, 0.0)),
        job_id=job["id"])
    assert stored_program == path.program.encode()


def test_a_reconstruct_job_without_its_stored_reconstruction_is_refused(client, s1_stl):
    """A reconstruct job from before reconstructions were stored has no reconstruction.npz:
    compensate is a 422 naming params.reconstruct_job_id, not a rebuild behind the user's back."""
    from sqlmodel import Session, select

    from app.platform.models import Artifact

    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_stl)}, headers=OP).json()
    trace = client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[6].to_api(), headers=OP).json()
    nominal = np.array(trace["nominal"]["points"])
    points = nominal[np.linspace(0, len(nominal) - 1, 8).astype(int)] + [0.0, 0.0, 0.01]
    rec = _submit(client, "reconstruct", {"trace_id": trace["id"], "points": points.tolist(), "method": "deviation"})
    assert rec["status"] == "succeeded", rec["error"]
    with Session(client.app.state.runtime.engine) as session:
        session.delete(session.exec(select(Artifact).where(Artifact.job_id == rec["id"],
                                                           Artifact.name == "reconstruction.npz")).one())
        session.commit()
    answer = client.post("/api/v1/jobs", json={"kind": "compensate", "params": {
        "trace_id": trace["id"], "reconstruct_job_id": rec["id"]}}, headers=OP)
    assert answer.status_code == 422, answer.text
    assert answer.json()["errors"][0]["loc"] == ["params", "reconstruct_job_id"]
    assert "no stored reconstruction" in answer.json()["detail"]
