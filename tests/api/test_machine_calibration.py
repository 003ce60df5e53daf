"""The machine profile's tools and reference artifacts, the calibration jobs' refusals and
GET /machines/{id}/calibration (404, an uncalibrated machine, the stale flag)."""

from __future__ import annotations

from datetime import timedelta

import pytest
from sqlalchemy import update
from sqlmodel import Session

from app.platform.models import Job
from tests.conftest import auth
from tests.jobs.test_calibration_jobs import PROFILE, calibrate, calibration, physics_machine

OP = auth("operator")


def register(client, profile: dict):
    return client.post("/api/v1/machines", json={"name": "m", "port": "mock://", "profile": profile}, headers=OP)


def loc(response) -> str:
    return ".".join(str(p) for p in response.json()["errors"][0]["loc"] if p != "body")


@pytest.mark.parametrize(("change", "field"), [
    ({"tools": {"nozzles": [{"tool": 9, "outer_diameter_mm": 0.8, "offset_mm": [0, 0, -5]}]}},
     "profile.tools.nozzles.0.tool"),
    ({"tools": {"nozzles": [{"tool": 1, "outer_diameter_mm": 0.8, "offset_mm": [0, 0, -5]},
                            {"tool": 1, "outer_diameter_mm": 0.5, "offset_mm": [1, 0, -5]}]}}, "profile.tools.nozzles"),
    ({"tools": {"nozzles": [{"tool": 1, "outer_diameter_mm": -1, "offset_mm": [0, 0, -5]}]}},
     "profile.tools.nozzles.0.outer_diameter_mm"),
    ({"tools": {"nozzles": [{"tool": 1, "outer_diameter_mm": 1, "offset_mm": [0, 0]}]}},
     "profile.tools.nozzles.0.offset_mm"),
    ({"tools": {"probe": {"ball_radius_mm": 0.5, "offset_mm": [1, 0, 0]}}}, "profile.tools.probe.offset_mm"),
    ({"tools": {"probe": {"ball_radius_mm": 11}}}, "profile.tools.probe.ball_radius_mm"),
    ({"tools": {"probe": {"ball_radius_mm": 0.5, "colour": "red"}}}, "profile.tools.probe.colour"),
    ({"reference": {"sphere": {"centre_mm": [0, 0, 0], "diameter_mm": 0}}}, "profile.reference.sphere.diameter_mm"),
    ({"reference": {"pad": {"centre_mm": [0, 0, float("1e9")], "size_mm": 10}}}, "profile.reference.pad.centre_mm.2"),
    ({"calibration_max_age_h": 0}, "profile.calibration_max_age_h"),
])
def test_bad_profiles_are_refused_naming_the_field(client, change, field):
    response = register(client, change)
    assert response.status_code == 422, response.text
    assert loc(response) == field, response.json()


def test_a_profile_without_tools_keeps_working_and_has_no_calibration(client):
    machine = register(client, {"clearance_z": 7}).json()
    assert machine["profile"]["tools"] is None and machine["profile"]["calibration_max_age_h"] == 24
    summary = calibration(client, machine)
    assert summary == {"machine_id": machine["id"], "max_age_h": 24.0, "probe": None, "nozzles": [], "sensor": None,
                       "flags": []}
    missing = client.get("/api/v1/machines/mach_nope/calibration", headers=auth("viewer"))
    assert missing.status_code == 404 and "mach_nope" in missing.json()["detail"]


def test_calibration_jobs_refuse_what_they_cannot_do(client):
    bare = register(client, {}).json()
    response = client.post("/api/v1/jobs", json={"kind": "calibrate_probe", "params": {"machine_id": bare["id"]}},
                           headers=OP)
    assert response.status_code == 422 and loc(response) == "profile.reference.sphere", response.text
    machine = register(client, PROFILE).json()
    unknown = client.post("/api/v1/jobs", json={"kind": "calibrate_nozzle",
                                                "params": {"machine_id": machine["id"], "tool": 2}}, headers=OP)
    assert unknown.status_code == 422 and loc(unknown) == "params.tool" and "T1" in unknown.json()["detail"]
    early = client.post("/api/v1/jobs", json={"kind": "calibrate_nozzle",
                                              "params": {"machine_id": machine["id"], "tool": 1}}, headers=OP)
    assert early.status_code == 422 and "calibrate the probe first" in early.json()["detail"], early.text
    no_pad = register(client, {**PROFILE, "reference": {"sphere": PROFILE["reference"]["sphere"]}}).json()
    refused = client.post("/api/v1/jobs", json={"kind": "calibrate_nozzle",
                                                "params": {"machine_id": no_pad["id"], "tool": 1}}, headers=OP)
    assert refused.status_code == 422 and loc(refused) == "profile.reference.pad"
    small_pad = {**PROFILE["reference"]["pad"], "size_mm": 6.0}    # the default 12 x 12 grid spans 5.5 mm
    small = register(client, {**PROFILE, "reference": {**PROFILE["reference"], "pad": small_pad}}).json()
    crowded = client.post("/api/v1/jobs", json={"kind": "calibrate_nozzle",
                                                "params": {"machine_id": small["id"], "tool": 1}}, headers=OP)
    assert crowded.status_code == 422 and loc(crowded) == "params.pad_touches", crowded.text
    assert "12 x 12 grid" in crowded.json()["detail"] and "6 mm pad" in crowded.json()["detail"], crowded.text
    viewer = client.post("/api/v1/jobs", json={"kind": "calibrate_probe", "params": {"machine_id": machine["id"]}},
                         headers=auth("viewer"))
    assert viewer.status_code == 403  # nothing moves without an operator


def test_an_old_calibration_is_flagged_stale(client):
    machine = physics_machine(client, {**PROFILE, "calibration_max_age_h": 24})
    job = calibrate(client, "calibrate_probe", {"machine_id": machine["id"], "per_ring": 4, "equator": 8})
    fresh = calibration(client, machine)
    assert fresh["probe"]["stale"] is False and fresh["probe"]["age_h"] < 0.1 and fresh["flags"] == []
    assert fresh["probe"]["ball_radius_std_um"] > 0 and fresh["nozzles"][0]["calibrated"] is False
    runtime = client.app.state.runtime
    with Session(runtime.engine) as session:  # the calibration was made 30 h ago
        row = session.get(Job, job["id"])
        created, finished = row.created_at - timedelta(hours=30), row.finished_at - timedelta(hours=30)
        session.exec(update(Job).where(Job.id == job["id"]).values(created_at=created, finished_at=finished))
        session.commit()
    old = calibration(client, machine)
    assert old["probe"]["stale"] is True and 29.9 < old["probe"]["age_h"] < 30.2
    assert old["flags"] == [f"probe calibration is {old['probe']['age_h']:.1f} h old (max 24 h)"]
