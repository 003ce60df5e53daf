"""surface_fit and five_axis jobs through the API on a part with an analytic (spherical) top.

The part is the convex solid under the sphere cap z = zc + sqrt(R^2 - x^2 - y^2) over a
square, so its top is a sphere up to the tessellation (< 1 um).  Programs are checked
from their TEXT with the issue's machine rule written out here independently:
workpiece p -> machine m = Rx(A) Rz(C) (p - pivot) + pivot.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from app.geometry.nurbs_surface import NurbsSurface
from app.jobs.results.five_axis import FiveAxisResult
from app.jobs.results.models import ProgramEcho, StoredResultError
from app.platform.models import Job
from hardware.protocol import commands_sha256
from tests.conftest import auth
from tests.helpers.gcode_words import g1_lines_missing, g1_rows
from tests.helpers.jobs import submit, wait_for

OP = auth("operator")
R = 40.0  # sphere radius, mm
CENTER = np.array([0.0, 0.0, -10.0])  # sphere centre: the cap's top is at z = 30
HALF = 20.0  # the part covers [-20, 20]^2
H = 0.5  # standoff, mm
PIVOT = [5.0, -3.0, -20.0]
ARC = {"type": "arc", "center": [2.0, 1.0], "radius": 11.0, "start_deg": -30.0, "end_deg": 250.0}


def sphere_z(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return CENTER[2] + np.sqrt(R**2 - (x - CENTER[0]) ** 2 - (y - CENTER[1]) ** 2)


@pytest.fixture(scope="module")
def cap_stl() -> bytes:
    x = np.linspace(-HALF, HALF, 81)
    xx, yy = np.meshgrid(x, x, indexing="ij")
    top = np.column_stack([xx.ravel(), yy.ravel(), sphere_z(xx, yy).ravel()])
    base = np.array([[sx * HALF, sy * HALF, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
    return trimesh.convex.convex_hull(np.vstack([top, base])).export(file_type="stl")


def rx(a: float) -> np.ndarray:
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


def rz(c: float) -> np.ndarray:
    return np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])


def upload(client, stl: bytes, name: str = "cap.stl") -> dict:
    response = client.post("/api/v1/parts", files={"file": (name, stl)}, headers=OP)
    assert response.status_code == 201, response.text
    return response.json()


def add_trace(client, part_id: str, geometry: dict) -> dict:
    response = client.post(f"/api/v1/parts/{part_id}/traces", headers=OP,
                           json={"name": "t", "geometry": geometry, "frame": "xy", "standoff_mm": H})
    assert response.status_code == 201, response.text
    return response.json()


def run_job(client, kind: str, params: dict) -> dict:
    response = submit(client, kind, params)
    assert response.status_code == 202, response.text
    return wait_for(client, response.json()["id"], timeout=60.0)


def artifact(client, job: dict, name: str):
    entry = next(a for a in job["artifacts"] if a["name"] == name)
    response = client.get(entry["url"], headers=OP)
    assert response.status_code == 200
    assert response.headers["content-type"].startswith(entry["media_type"])
    return entry, response


def workpiece_frames(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nozzle tips in workpiece coordinates (k, 3) and the nozzle axis +Z seen from the
    workpiece (k, 3), by inverting m = Rx(A) Rz(C) (p - pivot) + pivot per line."""
    tips, axes = [], []
    pivot = np.array(PIVOT)
    for x, y, z, a_deg, c_deg, _ in rows:
        rot = rx(np.radians(a_deg)) @ rz(np.radians(c_deg))
        tips.append(rot.T @ (np.array([x, y, z]) - pivot) + pivot)
        axes.append(rot.T @ np.array([0.0, 0.0, 1.0]))
    return np.array(tips), np.array(axes)


def assert_normal_and_standoff(surface: NurbsSurface, tips: np.ndarray, axes: np.ndarray) -> None:
    """The nozzle is H +- 1 um from the surface and the surface normal at the contact point
    is within 0.05 deg of the nozzle axis (i.e. turned to +Z by the line's A and C)."""
    inv = surface.invert(tips)
    assert np.abs(inv.distance - H).max() < 1e-3
    normal = surface.normal(inv.u, inv.v)
    normal *= np.sign(normal[:, 2:3])
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", normal, axes), -1, 1)))
    assert angle.max() < 0.05


# --------------------------------------------------------------------------- surface_fit
def test_surface_fit_of_the_nominal_grid_matches_the_sphere(client, cap_stl):
    part = upload(client, cap_stl)
    job = run_job(client, "surface_fit", {"part_id": part["id"], "region": {"x": [-15, 15], "y": [-12, 14]},
                                          "grid": [20, 16]})
    assert job["status"] == "succeeded", job["error"]
    result = job["result"]
    assert result["source"] == "nominal_grid" and result["residual"]["max_mm"] < 2e-3
    # the planned grid: 20 x 16 points in serpentine order, at the sphere's height
    grid = np.array(result["probe_grid"]["points"])
    assert grid.shape == (320, 3)
    np.testing.assert_allclose(grid[:16, 0], -15.0)
    np.testing.assert_allclose(grid[16:32, 0], -15 + 30 / 19)
    assert np.all(np.diff(grid[:16, 1]) > 0) and np.all(np.diff(grid[16:32, 1]) < 0)
    np.testing.assert_allclose(grid[:, 2], sphere_z(grid[:, 0], grid[:, 1]), atol=2e-3)
    # the fitted surface is the sphere over the region
    surface = NurbsSurface.from_dict(result["surface"])
    uu, vv = np.meshgrid(np.linspace(0, 1, 40), np.linspace(0, 1, 40), indexing="ij")
    p = surface.evaluate(uu.ravel(), vv.ravel())
    assert np.abs(p[:, 2] - sphere_z(p[:, 0], p[:, 1])).max() < 5e-3
    np.testing.assert_allclose([p[:, 0].min(), p[:, 0].max(), p[:, 1].min(), p[:, 1].max()],
                               [-15, 15, -12, 14], atol=1e-4)  # least squares: corners within 0.1 um
    entry, response = artifact(client, job, "surface.json")
    assert entry["media_type"] == "application/json" and response.json() == result["surface"]


def test_surface_fit_of_noisy_cmm_points_json_and_csv(client, cap_stl):
    part = upload(client, cap_stl)
    rng = np.random.default_rng(7)
    x, y = np.meshgrid(np.linspace(-15, 15, 20), np.linspace(-15, 15, 20), indexing="ij")
    points = np.column_stack([x.ravel(), y.ravel(), sphere_z(x, y).ravel() + rng.normal(0, 0.005, x.size)])
    points[57, 2] += 0.5  # one bad point
    base = {"part_id": part["id"], "region": {"x": [-15, 15], "y": [-15, 15]}, "grid": [20, 20]}
    job = run_job(client, "surface_fit", {**base, "points": points.tolist()})
    assert job["status"] == "succeeded", job["error"]
    result = job["result"]
    assert result["source"] == "points"
    np.testing.assert_allclose(result["removed_points"], [points[57]])
    surface = NurbsSurface.from_dict(result["surface"])
    uu, vv = np.meshgrid(np.linspace(0, 1, 40), np.linspace(0, 1, 40), indexing="ij")
    p = surface.evaluate(uu.ravel(), vv.ravel())
    error = np.abs(p[:, 2] - sphere_z(p[:, 0], p[:, 1])).max()
    assert error <= 0.010, error  # the goal for 5 um noise on a 20 x 20 grid
    assert 0.002 < result["residual"]["rms_mm"] < 0.008
    csv = "x;y;z\n# CMM export\n" + "\n".join(f"{a!r}; {b!r}; {c!r}" for a, b, c in points.tolist()) + "\n"
    again = run_job(client, "surface_fit", {**base, "points_csv": csv})
    assert again["status"] == "succeeded", again["error"]
    assert again["result"]["surface"] == result["surface"]  # same points -> the same surface
    assert artifact(client, again, "surface.json")[1].content == artifact(client, job, "surface.json")[1].content


def test_surface_fit_grid_holes_fail_or_are_filled(client):
    """A round part inside a square region: corner probes miss the part."""
    disc = upload(client, trimesh.creation.cylinder(radius=10.0, height=4.0, sections=64).export(file_type="stl"),
                  "disc.stl")
    params = {"part_id": disc["id"], "region": {"x": [-9.9, 9.9], "y": [-9.9, 9.9]}, "grid": [8, 8]}
    failed = run_job(client, "surface_fit", params)
    assert failed["status"] == "failed" and failed["error"]["status"] == 422
    assert failed["error"]["errors"][0]["loc"] == ["params", "region"] and "missing" in failed["error"]["detail"]
    filled = run_job(client, "surface_fit", {**params, "hole_policy": "fill"})
    assert filled["status"] == "succeeded", filled["error"]
    assert filled["result"]["filled_holes"] > 0
    missing = [p for p in filled["result"]["probe_grid"]["points"] if p[2] is None]
    assert len(missing) == filled["result"]["filled_holes"]
    assert all(np.hypot(p[0], p[1]) > 9.5 for p in missing)
    assert filled["result"]["residual"]["max_mm"] < 1e-6  # a flat top


# --------------------------------------------------------------------------- five_axis
def check_program(client, job: dict, surface: NurbsSurface) -> np.ndarray:
    entry, response = artifact(client, job, "five_axis.gcode")
    text = response.text
    assert entry["media_type"] == "text/x-gcode"
    assert entry["meta"]["commands_sha256"] == commands_sha256(text.splitlines()).sha256
    assert entry["meta"] == job["result"]["program"]
    rows = g1_rows(text)
    assert not g1_lines_missing(text, "XYZAC") and rows.shape[0] == job["result"]["lines"]
    tips, axes = workpiece_frames(rows)
    assert_normal_and_standoff(surface, tips, axes)
    # and against the analytic sphere: h above it, nozzle along its normal (fit error only)
    radial = tips - CENTER
    assert np.abs(np.linalg.norm(radial, axis=1) - R - H).max() < 5e-3
    sphere_normal = radial / np.linalg.norm(radial, axis=1, keepdims=True)
    assert np.degrees(np.arccos(np.einsum("ij,ij->i", sphere_normal, axes).min())) < 0.05
    assert np.abs(np.diff(rows[:, 4])).max() <= 180.0  # no C flips
    # dispensing: on after the approach move, off after the last move
    lines = text.splitlines()
    g1 = [i for i, line in enumerate(lines) if line.startswith("G1 ")]
    assert lines.count("M8") == 1 and lines.count("M9") == 1
    assert lines.index("M8") == g1[0] + 1 and lines.index("M9") == g1[-1] + 1
    return rows


def test_five_axis_on_a_surface_fit(client, cap_stl):
    part = upload(client, cap_stl)
    trace = add_trace(client, part["id"], ARC)
    fit = run_job(client, "surface_fit", {"part_id": part["id"], "region": {"x": [-15, 15], "y": [-15, 15]},
                                          "grid": [20, 20]})
    assert fit["status"] == "succeeded", fit["error"]
    job = run_job(client, "five_axis", {"part_id": part["id"], "trace_id": trace["id"], "surface_fit_job_id": fit["id"],
                                        "feed_mm_min": 1200, "pivot": PIVOT})
    assert job["status"] == "succeeded", job["error"]
    result = job["result"]
    assert result["surface_source"] == {"kind": "surface_fit", "job_id": fit["id"]}
    assert result["surface"] == fit["result"]["surface"]
    assert (result["dispense_on"], result["dispense_off"], result["standoff_mm"]) == ("M8", "M9", H)
    rows = check_program(client, job, NurbsSurface.from_dict(result["surface"]))
    assert result["max_normal_error_deg"] < 0.05 and result["max_standoff_error_mm"] < 1e-3
    assert result["feed_fluctuation"] < 1e-3 and result["feed_fluctuation"] < result["feed_fluctuation_first_order"]
    assert np.ptp(rows[:, 4]) > 90  # C follows the arc around the cap
    # inverse time: the F words sum to the trace's print time at the set feed
    assert "G93" in artifact(client, job, "five_axis.gcode")[1].text
    minutes = (1.0 / rows[1:, 5]).sum()
    assert minutes == pytest.approx(result["duration_s"] / 60.0, rel=1e-3)
    assert result["duration_s"] == pytest.approx(trace["length_mm"] / 1200 * 60, rel=2e-3)
    # the nominal program: three axes, h straight above the contact points, no tilt
    entry, response = artifact(client, job, "nominal.gcode")
    nominal = g1_rows(response.text)
    assert entry["meta"] == result["nominal_program"] and not np.any(nominal[:, 3:5])
    assert all(" A" not in line and " C" not in line for line in response.text.splitlines())
    np.testing.assert_allclose(nominal[:, 2], sphere_z(nominal[:, 0], nominal[:, 1]) + H, atol=5e-3)
    assert result["nominal_max_normal_error_deg"] > 10
    # the stored result reads back through the five_axis model, by attribute
    typed = FiveAxisResult.of_record(job)
    assert typed.pivot == PIVOT and typed.post == "conforma" and typed.lines == result["lines"]
    assert typed.surface_source == {"kind": "surface_fit", "job_id": fit["id"]}
    assert typed.model_dump(exclude_unset=True) == result
    echo = ProgramEcho.of_any(Job(id=job["id"], kind=job["kind"], params=job["params"], result=result))
    assert (echo.pivot, echo.post, echo.dispense_on, echo.dispense_off) == (PIVOT, "conforma", "M8", "M9")
    for key in ("pivot", "surface", "max_standoff_error_mm"):
        with pytest.raises(StoredResultError) as caught:
            FiveAxisResult.of_record({**job, "result": {k: v for k, v in result.items() if k != key}})
        assert caught.value.field == f"result.{key}"


def test_five_axis_default_surface_is_deterministic(client, cap_stl):
    part = upload(client, cap_stl)
    trace = add_trace(client, part["id"], ARC)
    params = {"part_id": part["id"], "trace_id": trace["id"], "feed_mm_min": 1200, "pivot": PIVOT,
              "dispense_on": "M106 S255", "dispense_off": "M107", "feed_mode": "tcp"}
    first, second = run_job(client, "five_axis", params), run_job(client, "five_axis", params)
    assert first["status"] == second["status"] == "succeeded", first["error"]
    source = first["result"]["surface_source"]
    assert source["kind"] == "nominal_top" and source["residual"]["max_mm"] < 2e-3
    xy = np.array(trace["nominal"]["points"])[:, :2]
    np.testing.assert_allclose(source["region"]["x"], [xy[:, 0].min() - 1, xy[:, 0].max() + 1])
    for name in ("five_axis.gcode", "nominal.gcode"):
        a, b = artifact(client, first, name)[1].text, artifact(client, second, name)[1].text
        assert a.replace(first["id"], second["id"]) == b  # identical but for the job id in the header
    text = artifact(client, first, "five_axis.gcode")[1].text
    assert "G93" not in text and "M106 S255" in text.splitlines() and "M107" in text.splitlines()
    assert json.dumps(first["result"], sort_keys=True) == json.dumps(second["result"], sort_keys=True)
    tips, axes = workpiece_frames(g1_rows(text))
    assert_normal_and_standoff(NurbsSurface.from_dict(first["result"]["surface"]), tips, axes)


@pytest.mark.parametrize("offset_mm", [0.0, 0.1])
def test_five_axis_over_the_apex_keeps_the_tip_on_the_path(client, cap_stl, offset_mm):
    """A straight trace through the cap's apex, and one 0.1 mm beside it, on the default
    (fitted nominal top) surface: C is blended near A = 0 instead of swinging, and
    halfway through every move (all five axes linear) the tip is h above the sphere and
    over the trace, to 10 um, from the program text alone."""
    part = upload(client, cap_stl)
    along = np.array([np.cos(0.5), np.sin(0.5)])
    across = np.array([-along[1], along[0]])
    start, end = -12.0 * along + offset_mm * across, 12.0 * along + offset_mm * across
    trace = add_trace(client, part["id"], {"type": "line", "start": start.tolist(), "end": end.tolist()})
    job = run_job(client, "five_axis", {"part_id": part["id"], "trace_id": trace["id"], "feed_mm_min": 1200,
                                        "pivot": PIVOT, "segment_mm": 0.5})
    assert job["status"] == "succeeded", job["error"]
    result = job["result"]
    assert result["max_midpoint_error_mm"] < 0.01 and result["max_c_step_deg"] < 10.0
    assert result["max_normal_error_deg"] <= 0.5  # the default pole window
    text = artifact(client, job, "five_axis.gcode")[1].text
    rows = g1_rows(text)
    assert rows.shape[0] == result["lines"] and np.abs(np.diff(rows[:, 4])).max() < 10.0
    tips, _ = workpiece_frames(0.5 * (rows[1:] + rows[:-1]))
    radial = tips - CENTER
    radius = np.linalg.norm(radial, axis=1)
    assert np.abs(radius - R - H).max() < 0.01
    assert np.abs((radial * (R / radius)[:, None])[:, :2] @ across - offset_mm).max() < 0.01
    lines = text.splitlines()
    g1 = [i for i, line in enumerate(lines) if line.startswith("G1 ")]
    assert lines.index("M8") == g1[0] + 1 and lines.index("M9") == g1[-1] + 1


def test_a_limit_violation_is_a_failed_job_naming_the_limits(client, cap_stl):
    part = upload(client, cap_stl)
    trace = add_trace(client, part["id"], ARC)
    job = run_job(client, "five_axis", {"part_id": part["id"], "trace_id": trace["id"], "a_limits_deg": [-5, 5]})
    assert job["status"] == "failed" and job["error"]["status"] == 422
    assert job["error"]["errors"][0]["loc"] == ["params", "a_limits_deg"]
    assert "outside the A limits" in job["error"]["detail"] and job["artifacts"] == []


def test_bad_input_is_refused_at_submission_and_nothing_is_stored(client, cap_stl):
    part = upload(client, cap_stl)
    other = upload(client, cap_stl, "other.stl")
    trace = add_trace(client, part["id"], ARC)
    corner = add_trace(client, part["id"], {"type": "line", "start": [14.0, 14.0], "end": [18.0, 18.0]})
    stranger = add_trace(client, other["id"], ARC)
    small = run_job(client, "surface_fit", {"part_id": part["id"], "region": {"x": [-10, 10], "y": [-10, 10]},
                                            "grid": [12, 12]})
    probe = run_job(client, "probe_plan", {"trace_id": trace["id"], "method": "uniform", "count": 6})
    assert small["status"] == probe["status"] == "succeeded"
    fit = {"part_id": part["id"], "region": {"x": [-10, 10], "y": [-10, 10]}}
    five = {"part_id": part["id"], "trace_id": trace["id"]}
    cases = [
        ("surface_fit", {**fit, "region": {"x": [5, -5], "y": [0, 1]}}, "params.region", "x0 < x1"),
        ("surface_fit", {**fit, "region": {"x": [-25, 5], "y": [0, 1]}}, "params.region", "footprint"),
        ("surface_fit", {**fit, "grid": [1, 20]}, "params.grid.0", "greater than or equal"),
        ("surface_fit", {**fit, "grid": [3, 20]}, "params.grid", "at least 4"),
        ("surface_fit", {**fit, "moving_average_window": 4}, "params.moving_average_window", "odd"),
        ("surface_fit", {**fit, "control_points": [30, 8]}, "params.control_points", "exceed"),
        ("surface_fit", {**fit, "points": [[0, 0, 1]] * 40}, "params.points", "at least 32"),
        ("surface_fit", {**fit, "points": [[0, 0, 1]] * 40, "remove_bad_points": False}, "params.points",
         "at least 16"),
        ("surface_fit", {**fit, "points": [[i, 2 * i, 1] for i in range(40)]}, "params.points", "one line"),
        ("surface_fit", {**fit, "points": [[i % 7, i // 7, 1] for i in range(49)] * 2, "resample_to_grid": True},
         "params.points", "repeat"),
        ("surface_fit", {**fit, "points_csv": "x,y,z\n1,2,3\n1,2\n"}, "params.points_csv", "line 3"),
        ("surface_fit", {**fit, "points_csv": "1,2,nan\n"}, "params.points_csv", "finite"),
        ("surface_fit", {**fit, "points": [[0, 0, 1]] * 20, "points_csv": "1,2,3\n"}, "params", "not both"),
        ("surface_fit", {**fit, "machine_id": "m1"}, "params.machine_id", "Extra inputs"),
        ("five_axis", {**five, "a_limits_deg": [10, -10]}, "params.a_limits_deg", "min <= max"),
        ("five_axis", {**five, "a_limits_deg": [-200, 10]}, "params.a_limits_deg.0", "greater than"),
        ("five_axis", {**five, "normal": "binormal"}, "params.normal", "surface"),
        ("five_axis", {**five, "period_s": 0}, "params.period_s", "greater than"),
        ("five_axis", {**five, "pivot": [0, 0]}, "params.pivot", "at least 3"),
        ("five_axis", {**five, "dispense_on": "M8\nG28"}, "params.dispense_on", "pattern"),
        ("five_axis", {**five, "standoff_mm": -1}, "params.standoff_mm", "greater than"),
        ("five_axis", {**five, "trace_id": stranger["id"]}, "params.trace_id", "belongs to part"),
        ("five_axis", {**five, "trace_id": "trace_nope"}, "params.trace_id", "does not exist"),
        ("five_axis", {**five, "surface_fit_job_id": probe["id"]}, "params.surface_fit_job_id",
         "succeeded surface_fit"),
        ("five_axis", {**five, "part_id": other["id"], "trace_id": stranger["id"], "surface_fit_job_id": small["id"]},
         "params.surface_fit_job_id", "fitted part"),
        ("five_axis", {**five, "trace_id": corner["id"], "surface_fit_job_id": small["id"]}, "params.trace_id",
         "leaves the surface"),
    ]
    for kind, params, field, needle in cases:
        response = submit(client, kind, params)
        assert response.status_code == 422, (params, response.text)
        body = response.json()
        assert ".".join(body["errors"][0]["loc"]) == field, (field, body)
        assert needle.lower() in body["detail"].lower(), (needle, body["detail"])
    nan = client.post("/api/v1/jobs", headers={**OP, "content-type": "application/json"},
                      content=b'{"kind": "surface_fit", "params": {"part_id": "%s", "region": {"x": [0, 1], '
                              b'"y": [0, 1]}, "points": [[1, 2, NaN]]}}' % part["id"].encode())
    assert nan.status_code == 422
    jobs = client.get("/api/v1/jobs", headers=OP).json()
    assert sorted(job["kind"] for job in jobs["items"]) == ["probe_plan", "surface_fit"]


def test_a_straight_trace_with_the_principal_normal_is_a_422_naming_params_normal(client):
    """The core's ``params.normal`` is this job's parameter of the same name."""
    box = trimesh.creation.box(extents=(20.0, 20.0, 3.0))
    box.apply_translation((10.0, 10.0, 1.5))  # a flat top at z = 3: a straight trace stays straight
    part = upload(client, box.export(file_type="stl"), "box.stl")["id"]
    trace = add_trace(client, part, {"type": "line", "start": [2.0, 2.0], "end": [18.0, 2.5]})
    response = submit(client, "five_axis", {"part_id": part, "trace_id": trace["id"], "normal": "principal"})
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"], timeout=60.0)
    assert done["status"] == "failed" and done["error"]["status"] == 422, done
    assert done["error"]["errors"][0]["loc"] == ["params", "normal"] and "straight" in done["error"]["detail"]
    refused = submit(client, "five_axis", {"part_id": part, "trace_id": trace["id"], "period_s": 0})
    assert refused.status_code == 422 and refused.json()["errors"][0]["loc"] == ["params", "period_s"]
