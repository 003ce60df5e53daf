"""Probe readings become true surface points (the measuring side) through the API.

The mock probes with a ball stylus (radius 0.5 mm), 15 um pre-travel, 1 um/min Z drift and
1 um noise, with a reference pad beside the part.  The machine's probe calibration is a
``calibrate_probe`` result holding the mock's truth (ball 0.5 mm, pre-travel 15 um, the pad
reading of the undrifted machine), so these tests check the corrections alone, against the
known true surface: the raw readings sit r / n_z - delta above it (485..530 um on S1's
slopes), the corrected points within a few um; each correction switched off leaves its
own error (radius: r (1 / n_z - 1); pre-travel: 15 um; drift: growing with machine time).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
from sqlmodel import Session

from app.calibration import PretravelModel, ProbeCalibration
from app.platform.models import Job, new_id, utcnow
from app.reference.s1 import as_made, nominal_height, s1_mesh, s1_traces
from tests.conftest import KEYS, auth
from tests.helpers.jobs import wait_for

OP = auth("operator")
BALL_MM = 0.5
PRETRAVEL_MM = 0.015
DRIFT_MM_PER_MIN = 0.001
PAD = (80.0, 20.0, 5.0, 20.0)  # x, y, z top, size (mm): beside the part (x 0..60, y 0..40)
FAST_DRIFT_MM_PER_MIN = 0.02  # the drift tests: a short run drifts visibly (1 um/min ~ 1 um per run here)


def physics(drift_mm_per_min: float = DRIFT_MM_PER_MIN) -> str:
    return (f"stylus_radius_mm={BALL_MM}&pretravel_mm={PRETRAVEL_MM}&drift_mm_per_min={drift_mm_per_min}"
            f"&pad={','.join(str(v) for v in PAD)}")


@pytest.fixture(scope="module")
def client(tmp_path_factory) -> Iterator:
    """One service for the module (its parts, plans and machines are independent of one another):
    the meshes are uploaded and parsed once, not once per test."""
    from fastapi.testclient import TestClient

    from app.main import create_app
    from app.platform.config import load_settings

    settings = load_settings({}, data_dir=tmp_path_factory.mktemp("measuring") / "data",
                             api_keys=",".join(f"{k}:{r}" for r, k in KEYS.items()), viewer=False, lease_s=5.0,
                             reaper_interval_s=0.2, job_plugins="tests.jobs.sample_kinds")
    with TestClient(create_app(settings), raise_server_exceptions=False) as test_client:
        yield test_client


@pytest.fixture(scope="module")
def meshes(client) -> dict[str, dict]:
    """The uploaded parts: the nominal S1 (0.5 mm grid), S1 as true part (0.15 mm) and the steep as-made S1."""
    stls = {"nominal": s1_mesh(grid_mm=0.5).export(file_type="stl"),
            "true": s1_mesh(grid_mm=0.15).export(file_type="stl"),
            "as_made": steep_as_made().mesh(grid_mm=0.15).export(file_type="stl")}
    return {name: upload(client, stl, f"s1-{name}.stl") for name, stl in stls.items()}


@pytest.fixture(scope="module")
def trace7(client, meshes) -> dict:
    return trace_on(client, meshes["nominal"]["id"])


@pytest.fixture(scope="module")
def plan7(client, trace7) -> dict:
    """The 16-station deviation plan on S1 trace 7 that the probe-run tests share."""
    return plan_on(client, trace7["id"])


def steep_as_made():
    """An as-made S1 whose machining error tilts the surface by up to 0.07 along trace 7:
    the nominal normal then misjudges r / n_z by up to ~6 um."""
    return as_made(seed=5, amplitude_mm=0.3, min_wavelength_mm=10.0)


def submit(client, kind: str, params: dict) -> dict:
    response = client.post("/api/v1/jobs", json={"kind": kind, "params": params}, headers=OP)
    assert response.status_code == 202, response.text
    job = wait_for(client, response.json()["id"], timeout=300)
    assert job["status"] == "succeeded", job["error"]
    return job


def upload(client, stl: bytes, name: str) -> dict:
    return client.post("/api/v1/parts", files={"file": (name, stl)}, headers=OP).json()


def machine(client, true_part_id: str, *, calibrated: bool = True,
            drift_mm_per_min: float = DRIFT_MM_PER_MIN, dialect: str = "marlin",
            placement: dict | None = None, faults: dict | None = None, options: str = "") -> dict:
    """A mock Marlin machine with probe physics holding ``true_part_id`` in place, a
    reference pad in its profile, and (``calibrated``) a probe calibration with the truth."""
    row = client.post("/api/v1/machines", json={
        "name": new_id("sim"), "port": f"mock://?{physics(drift_mm_per_min)}{options}", "dialect": dialect,
        "profile": {"reference": {"pad": {"centre_mm": list(PAD[:3]), "size_mm": PAD[3]}}},
        "mock": {"true_part_id": true_part_id, "probe_noise_mm": 0.001, "faults": {"seed": 2, **(faults or {})},
                 "placement": placement or {}}}, headers=OP)
    assert row.status_code == 201, row.text
    if calibrated:
        calibrate(client, row.json()["id"])
    return row.json()


def calibrate(client, machine_id: str, ball_mm: float = BALL_MM, pretravel_mm: float = PRETRAVEL_MM,
              scatter_mm: float = 0.001) -> str:
    """A succeeded calibrate_probe job with a known result (the pad read by the undrifted probe;
    ``scatter_mm``: the qualification's residual rms, a touch's measured scatter)."""
    cal = ProbeCalibration(ball_radius_mm=ball_mm, pretravel=PretravelModel(pretravel_mm),
                           sphere_centre_mm=(0.0, 0.0, 0.0), pad_reading_z_mm=PAD[2] + ball_mm - pretravel_mm,
                           std={"ball_radius_mm": 0.0005}, residual_rms_mm=scatter_mm, touches=40)
    with Session(client.app.state.runtime.engine) as session:
        job = Job(id=new_id("job"), kind="calibrate_probe", status="succeeded", progress=1.0,
                  params={"machine_id": machine_id}, result=cal.to_dict(), machine_id=machine_id,
                  created_at=utcnow(), finished_at=utcnow())
        session.add(job)
        session.commit()
        return job.id


def trace_on(client, part_id: str, index: int = 6) -> dict:
    return client.post(f"/api/v1/parts/{part_id}/traces", json=s1_traces()[index].to_api(), headers=OP).json()


def plan_on(client, trace_id: str, count: int = 16) -> dict:
    return submit(client, "probe_plan", {"trace_id": trace_id, "method": "deviation", "count": count})


def run(client, plan_id: str, machine_id: str, **params) -> dict:
    """The succeeded probe_run job."""
    return submit(client, "probe_run", {"plan_job_id": plan_id, "machine_id": machine_id, **params})


def errors(result: dict, truth=nominal_height) -> np.ndarray:
    """measured z - true height at each station (mm)."""
    measured = np.array([p["measured"] for p in result["points"]])
    return measured[:, 2] - truth(measured[:, :2])


def slopes(result: dict) -> np.ndarray:
    return np.array([p["normal"][2] for p in result["points"]])


def test_plan_records_carry_the_unit_normal(plan7):
    plan = plan7["result"]
    normals = np.array([r["normal"] for r in plan["records"]])
    assert normals.shape == (plan["count"], 3)
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0) and (normals[:, 2] > 0).all()
    # the S1 top is analytic: the normal is unit(-grad h, 1); the trace's draped normals are it
    from app.reference.s1 import nominal_gradient

    g = nominal_gradient(np.array(plan["points"])[:, :2])
    truth = np.column_stack([-g, np.ones(len(g))])
    truth /= np.linalg.norm(truth, axis=1, keepdims=True)
    # within the faceting of the 0.5 mm nominal mesh the trace was draped on
    assert np.degrees(np.arccos(np.clip(np.sum(normals * truth, axis=1), -1, 1))).max() < 1.5


def test_drift_is_tracked_by_pad_retouches(client, meshes, plan7):
    """20 um/min: the pad readings fall with machine time; the corrected points stay on the
    surface while the uncorrected ones sink with the clock.  grbl: its G38.2 probes at the
    plan's feed, so the estimated touch times follow the machine clock (Marlin's G30 probes
    at the firmware's own feed, which the estimate does not know: see docs/calibration.md)."""
    true, plan = meshes["true"], plan7
    runs = {}
    for drift in (True, False):
        sim = machine(client, true["id"], drift_mm_per_min=FAST_DRIFT_MM_PER_MIN, dialect="grbl")
        runs[drift] = run(client, plan["id"], sim["id"], drift_interval_s=8, corrections={"drift": drift})["result"]
    track = runs[True]["calibration"]["drift"]
    slope = np.polyfit(track["times_s"], track["pad_z_mm"], 1)[0] * 60
    assert -0.025 < slope < -0.015, slope  # mm/min: the pad sees the drift
    assert np.abs(errors(runs[True])).max() < 0.004
    lost = errors(runs[False])
    times = np.array([p["t_s"] for p in runs[False]["points"]])
    sink = np.polyfit(times, lost, 1)[0] * 60  # mm/min
    assert -0.03 < sink < -0.01 and lost.mean() < -0.002, (sink, lost)


def _calibrated_run_measures_the_true_surface(result: dict) -> None:
    """The run with every correction: the points on the true surface, the raw readings r / n_z - delta
    above it, the drift track bracketing the stations."""
    err = errors(result)
    assert np.abs(err).max() < 0.004, err
    # the raw readings sit r / n_z - delta (minus the drift so far) above the surface
    reading = np.array([p["reading"] for p in result["points"]])
    raw = reading[:, 2] - nominal_height(reading[:, :2])
    expected = BALL_MM / slopes(result) - PRETRAVEL_MM
    assert raw.min() > 0.47 and np.abs(raw - expected).max() < 0.006, (raw, expected)
    assert (slopes(result) < 0.99).any(), "the trace must cross slopes for this test to mean anything"
    cal = result["calibration"]
    assert cal["corrections"] == {"radius": True, "pretravel": True, "drift": True}
    drift = cal["drift"]
    assert len(drift["times_s"]) >= 3 and np.all(np.diff(drift["times_s"]) > 0)
    times = np.array([p["t_s"] for p in result["points"]])
    assert np.all(np.diff(times) > 0) and drift["times_s"][0] < times[0] and drift["times_s"][-1] > times[-1]


def test_each_correction_switched_off_shows_its_error(client, meshes, plan7):
    """The ablation table on S1 trace 7 (16 stations): all corrections (the calibrated run measures
    the true surface), then each one off (printed with -s: the figures in docs/measured.md)."""
    true, plan = meshes["true"], plan7
    table = {}
    for off in (None, "radius", "pretravel", "drift"):
        sim = machine(client, true["id"])
        result = run(client, plan["id"], sim["id"], drift_interval_s=8,
                     corrections={off: False} if off else {})["result"]
        err = errors(result)
        table[off] = err
        print(f"corrections off: {off or 'none':9s} error max |e| {np.abs(err).max() * 1e3:6.1f} um, "
              f"mean {err.mean() * 1e3:6.1f} um")
        if off is None:
            _calibrated_run_measures_the_true_surface(result)
        if off == "radius":
            nz = slopes(result)
    raw = np.array([p["reading"][2] for p in result["points"]]) - nominal_height(
        np.array([p["reading"][:2] for p in result["points"]]))
    print(f"raw readings: {raw.min() * 1e3:.1f}..{raw.max() * 1e3:.1f} um above the surface")
    assert np.abs(table[None]).max() < 0.004
    # radius off (taken off vertically): left r (1 / n_z - 1) on the slopes
    assert np.abs(table["radius"] - BALL_MM * (1 / nz - 1)).max() < 0.004 and table["radius"].max() > 0.010
    # pre-travel off: the probe triggered delta late, everything 15 um low
    assert np.abs(table["pretravel"] + PRETRAVEL_MM).max() < 0.004
    # drift off (1 um/min): low by the drift since the machine started, < 2 um in this short run
    assert -0.004 < table["drift"].mean() < 0.001


def test_uncalibrated_machine_keeps_todays_readings(client, meshes, plan7):
    true, plan = meshes["true"], plan7
    sim = machine(client, true["id"], calibrated=False)
    result = run(client, plan["id"], sim["id"])["result"]
    assert "calibration" not in result and "reading" not in result["points"][0]
    assert errors(result).min() > 0.47  # the ball's raw readings


def _station_truth_error(job: dict, plan: dict, truth) -> np.ndarray:
    samples = np.array(job["result"]["deviation"]["samples"])
    points = np.array(plan["result"]["points"])
    s = np.array(plan["result"]["s_mm"])
    assert np.allclose(samples[:, 0], s, atol=1e-3)
    return points[:, 2] + samples[:, 1] - truth(points[:, :2])


def test_reconstruct_iterates_the_normal_where_the_deviation_slopes(client, meshes, trace7):
    truth = steep_as_made()
    real, trace = meshes["as_made"], trace7
    sim = machine(client, real["id"])
    plan = plan_on(client, trace["id"], count=24)
    probe_run = run(client, plan["id"], sim["id"])
    first = errors(probe_run["result"], truth.true_height)  # nominal normals only
    job = submit(client, "reconstruct", {"trace_id": trace["id"], "probe_run_job_id": probe_run["id"],
                                         "method": "deviation", "sigma_mm": 0.0})
    iteration = job["result"]["normal_iteration"]
    assert iteration["passes"] == 2 and iteration["max_change_mm"][1] < 0.25 * iteration["max_change_mm"][0]
    after = _station_truth_error(job, plan, truth.true_height)
    print("nominal normals um", np.round(first * 1e3, 1), "\niterated um", np.round(after * 1e3, 1), iteration)
    assert np.abs(first).max() > 0.003, first  # the deviation's slope matters here
    assert iteration["max_change_mm"][0] > 0.002 and iteration["max_tilt_deg"] > 1.0
    # where the iteration moved a point most, it moved it toward the truth
    moved = np.abs(after - first) > 0.0015
    assert moved.any() and np.all(np.abs(after[moved]) < np.abs(first[moved])), (first, after)
    assert np.abs(after).max() < 0.8 * np.abs(first).max() and np.abs(after).max() < 0.003, (first, after)



PLACED = {"dx": 0.2, "dy": -0.15, "dz": 0.03, "rz_deg": 0.3}


@pytest.mark.parametrize("mode", ["edges", "z_only"])
def test_registration_corrects_the_datum_touches(client, meshes, mode):
    """The datum heights are corrected along the touched face's normal (edges: the level
    top; z_only: the slopes), the walls found by the ball's edge catch (the calibrated
    radius): the placement within 3 sigma and dz within a few um; the same machine without
    its calibration puts dz off by the ball's r - delta."""
    part = meshes["nominal"]
    found = {}
    for calibrated in (True, False):
        sim = machine(client, part["id"], calibrated=calibrated, placement=PLACED)
        found[calibrated] = submit(client, "register", {"part_id": part["id"], "machine_id": sim["id"],
                                                       "mode": mode})["result"]
    est, std = found[True]["placement"], found[True]["std"]
    assert found[True]["calibration"]["tip_radius_mm"] == BALL_MM and "calibration" not in found[False]
    for key in ("dz", *(("dx", "dy") if mode == "edges" else ())):
        assert abs(est[key] - PLACED[key]) <= max(3 * std[f"{key}_mm"], 0.004), (key, est[key], std)
    assert abs(est["dz"] - PLACED["dz"]) < 0.005
    if mode == "edges":
        assert abs(est["rz_deg"] - PLACED["rz_deg"]) <= max(3 * std["rz_deg"], 0.005)
    # uncorrected: the ball reads r / n_z - delta high on the (sloped) top datums
    assert found[False]["placement"]["dz"] - PLACED["dz"] > BALL_MM - PRETRAVEL_MM - 0.005


def test_field_plan_run_gets_corrected_points_and_the_field_iterates(client, meshes):
    truth = steep_as_made()
    part, real = meshes["nominal"], meshes["as_made"]
    traces = client.post(f"/api/v1/parts/{part['id']}/traces:import",
                         json=[s1_traces()[i].to_api() for i in (0, 6)], headers=OP).json()["items"]
    sim = machine(client, real["id"])
    plan = submit(client, "probe_plan", {"trace_ids": [t["id"] for t in traces], "count": 24,
                                         "deviation_amplitude_mm": 0.3, "deviation_wavelength_mm": 10.0})
    assert plan["result"]["method"] == "field"
    normals = np.array([r["normal"] for r in plan["result"]["records"]])
    assert (normals[:, 2] > 0).all() and np.allclose(np.linalg.norm(normals, axis=1), 1.0)
    probe_run = run(client, plan["id"], sim["id"])
    first = errors(probe_run["result"], truth.true_height)
    assert np.abs(first).max() < 0.025  # nominal normals: only the deviation's slope is left
    for trace in traces:
        job = submit(client, "reconstruct", {"trace_id": trace["id"], "probe_run_job_id": probe_run["id"],
                                             "method": "field"})
        iteration = job["result"]["normal_iteration"]
        assert iteration["passes"] == 2 and iteration["max_change_mm"][1] < 0.5 * iteration["max_change_mm"][0]
        samples = np.array(job["result"]["deviation"]["samples"])
        own = [(r["s_mm"], p) for p, r in zip(probe_run["result"]["points"], plan["result"]["field"]["stations"])
               if r["trace"] == traces.index(trace) and not r.get("verify")]  # verification points: not fitted
        rows = [p for _, p in sorted(own, key=lambda sp: sp[0])]
        assert len(rows) == len(samples)
        xy = np.array([p["nominal"][:2] for p in rows])
        z = np.array([p["nominal"][2] for p in rows]) + samples[:, 1]
        after = z - truth.true_height(xy)
        assert np.abs(after).max() < 0.005, after


def test_probe_calibrated_through_the_api_then_measured(client, meshes, plan7):
    """calibrate_probe on the datum sphere and the pad (nominal places ~0.3 mm off, pre-travel
    scatter 2 um), then a probe run: the points sit on the true surface within the touch's own
    scatter (2 um pre-travel + 1 um noise: 2.2 um rms, 4 sigma = 9 um; they are in the
    calibration's frame: low by the drift at calibration time, ~1 um here)."""
    true = meshes["true"]
    sphere = (75.3, 45.2, 10.25)
    row = client.post("/api/v1/machines", json={
        "name": "qualified",
        "port": f"mock://?{physics()}&pretravel_sd_mm=0.002&sphere={','.join(map(str, sphere))},10",
        "dialect": "marlin",
        "profile": {"tools": {"probe": {"ball_radius_mm": 0.5}},
                    "reference": {"pad": {"centre_mm": [80.2, 19.8, 5.0], "size_mm": PAD[3]},
                                  "sphere": {"centre_mm": [75.0, 45.0, 10.0], "diameter_mm": 10.0}}},
        "mock": {"true_part_id": true["id"], "probe_noise_mm": 0.001, "faults": {"seed": 4}}}, headers=OP)
    assert row.status_code == 201, row.text
    sim = row.json()
    # a lighter qualification than the default (its repeatability is tests/jobs/test_calibration_jobs.py's)
    cal = submit(client, "calibrate_probe", {"machine_id": sim["id"], "per_ring": 24, "equator": 48})
    assert abs(cal["result"]["ball_radius_mm"] - BALL_MM) < 0.003
    plan = plan7
    result = run(client, plan["id"], sim["id"])["result"]
    assert result["calibration"]["probe_job_id"] == cal["id"]
    err = errors(result)
    print(f"API-calibrated probe run: max |e| {np.abs(err).max() * 1e3:.1f} um, mean {err.mean() * 1e3:.1f} um")
    assert np.abs(err).max() < 0.009 and np.sqrt(np.mean(err ** 2)) < 0.003 and abs(err.mean()) < 0.002, err


def test_an_interrupted_calibrated_run_resumes_with_its_drift_track(client, meshes, plan7):
    true, plan = meshes["true"], plan7
    sim = machine(client, true["id"], faults={"disconnect_at_line": 60})
    response = client.post("/api/v1/jobs", json={"kind": "probe_run", "params": {
        "plan_job_id": plan["id"], "machine_id": sim["id"], "drift_interval_s": 8}}, headers=OP)
    interrupted = wait_for(client, response.json()["id"], states=("interrupted", "succeeded", "failed"))
    assert interrupted["status"] == "interrupted", interrupted["error"]
    state = interrupted["program_state"]
    assert 0 < state["executed"] < plan["result"]["count"] and len(state["drift"]["times_s"]) >= 1
    before = len(state["drift"]["times_s"])
    assert client.post(f"/api/v1/jobs/{interrupted['id']}/resume", json={"confirm": True},
                       headers=OP).status_code == 202
    resumed = wait_for(client, interrupted["id"], timeout=120)
    assert resumed["status"] == "succeeded", resumed["error"]
    result = resumed["result"]
    assert result["resumes"] == 1 and [p["index"] for p in result["points"]] == list(range(plan["result"]["count"]))
    track = result["calibration"]["drift"]
    assert len(track["times_s"]) > before and track["times_s"][:before] == state["drift"]["times_s"]
    assert np.abs(errors(result)).max() < 0.004


def test_reconstruct_takes_its_probe_noise_from_the_calibration_when_asked(client, meshes, trace7, plan7):
    """sigma_from_calibration without sigma_mm: a run on a calibrated machine is reconstructed with the
    calibration's measured scatter (stated in the result), exactly as with that sigma given; by default,
    and on an uncalibrated machine, the method's own."""
    sim = machine(client, meshes["true"]["id"], calibrated=False)
    cal_id = calibrate(client, sim["id"], scatter_mm=0.004)
    probe_run = run(client, plan7["id"], sim["id"])
    base = {"trace_id": trace7["id"], "probe_run_job_id": probe_run["id"], "method": "deviation"}
    asked = submit(client, "reconstruct", {**base, "sigma_from_calibration": True})["result"]
    assert asked["sigma"] == {"sigma_mm": 0.004, "source": "calibration: the probe qualification's residual rms",
                              "probe_job_id": cal_id}
    given = submit(client, "reconstruct", {**base, "sigma_mm": 0.004})["result"]
    assert given["sigma"] == {"sigma_mm": 0.004, "source": "params"}
    assert asked["deviation"]["samples"] == given["deviation"]["samples"]
    default = submit(client, "reconstruct", base)["result"]
    assert default["sigma"] == {"sigma_mm": None, "source": "default: the method's own"}
    assert default["deviation"]["samples"] != asked["deviation"]["samples"]   # the noise level matters here
    bare = machine(client, meshes["true"]["id"], calibrated=False)
    uncalibrated = submit(client, "reconstruct", {**base, "sigma_from_calibration": True,
                                                  "probe_run_job_id": run(client, plan7["id"], bare["id"])["id"]})
    assert uncalibrated["result"]["sigma"] == {"sigma_mm": None, "source": "default: the method's own"}
