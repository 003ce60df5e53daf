"""jetting and jetting_next_layer jobs through the API, on small grids (150 dpi, 5 mm part)."""

from __future__ import annotations

import base64
import io
import time

import numpy as np
import pytest
from PIL import Image

from app.jetting import DropParams, TargetSpec, target_from_spec
from app.jobs.results.jetting import JettingResult, NextLayerResult
from tests.conftest import auth
from tests.helpers.jobs import submit, wait_for
from tests.jobs.test_program_results import round_trips

OP = auth("operator")
SMALL = {"dpi": 150, "target": {"size_mm": 5, "hole_mm": 2}, "layers": 20, "nozzle_spread": 0.06, "png_every": 5}
DROP_MM3 = 6e-6  # the default 6 pL drop


def run_job(client, kind: str, params: dict) -> dict:
    response = submit(client, kind, params)
    assert response.status_code == 202, response.text
    job = wait_for(client, response.json()["id"])
    assert job["status"] == "succeeded", job["error"]
    return job


def artifact(client, job: dict, name: str) -> tuple[bytes, str]:
    row = next(a for a in job["artifacts"] if a["name"] == name)
    response = client.get(row["url"], headers=OP)
    assert response.status_code == 200
    assert response.headers["content-type"].split(";")[0] == row["media_type"]
    return response.content, row["media_type"]


def npz(data: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(data), allow_pickle=False) as archive:
        return {name: archive[name] for name in archive.files}


def sha(job: dict, name: str) -> str:
    return next(a["sha256"] for a in job["artifacts"] if a["name"] == name)


def error_field(response) -> str:
    return ".".join(response.json()["errors"][0]["loc"])


def png_b64(mask: np.ndarray) -> str:
    out = io.BytesIO()
    Image.fromarray(mask.astype(np.uint8) * 255).save(out, format="PNG")
    return base64.b64encode(out.getvalue()).decode()


def small_target():
    """The small target built by the core independently of the service (for grid shapes)."""
    return target_from_spec(TargetSpec(size_mm=5, hole_mm=2), DropParams(dpi=150), 0.25)


def test_mpc_beats_open_loop_and_artifacts_decode(client):
    open_loop = run_job(client, "jetting", {**SMALL, "controller": "open_loop"})
    mpc = run_job(client, "jetting", {**SMALL, "controller": "mpc"})
    grid = small_target()
    for job in (open_loop, mpc):
        result = job["result"]
        assert round_trips(JettingResult, job).final.layer == 20
        assert [row["layer"] for row in result["layers"]] == list(range(1, 21))
        assert result["final"] == result["layers"][-1]
        assert result["grid"]["shape"] == list(grid.shape)
        assert result["grid"]["part_cells"] == int(grid.mask.sum())
    assert all(row["drops"] == int(grid.mask.sum()) for row in open_loop["result"]["layers"])
    ol, mp = open_loop["result"]["final"], mpc["result"]["final"]
    assert mp["sa_um"] < 0.7 * ol["sa_um"], (mp["sa_um"], ol["sa_um"])
    assert mp["edge_collapse_um"] < 0.7 * ol["edge_collapse_um"]
    assert all(row["kkt_residual"] >= 0 and row["integer_gap"] >= -1e-9 for row in mpc["result"]["layers"])

    data, media = artifact(client, mpc, "patterns.npz")
    arrays = npz(data)
    assert media == "application/zip"
    assert arrays["patterns"].shape == (20, *grid.shape) and arrays["patterns"].dtype == bool
    assert np.array_equal(arrays["mask"], grid.mask)
    assert not arrays["patterns"][:, ~grid.mask].any()  # the MPC only jets on the part
    assert [int(p.sum()) for p in arrays["patterns"]] == [row["drops"] for row in mpc["result"]["layers"]]
    heights = npz(artifact(client, mpc, "heights.npz")[0])
    assert heights["heights"].shape == (1, *grid.shape) and heights["layers"].tolist() == [20]
    assert np.allclose(heights["heights"][0], heights["final"], atol=1e-6)
    part = heights["final"][grid.mask] * 1e3
    assert np.mean(np.abs(part - part.mean())) == pytest.approx(mp["sa_um"], rel=1e-9)

    assert mpc["result"]["pattern_pngs"] == ["pattern_0005.png", "pattern_0010.png", "pattern_0015.png",
                                             "pattern_0020.png"]
    for name in mpc["result"]["pattern_pngs"]:
        data, media = artifact(client, mpc, name)
        image = Image.open(io.BytesIO(data))
        assert media == "image/png" and image.mode == "1" and image.size == (grid.shape[1], grid.shape[0])
        layer = int(name[8:12])
        assert np.array_equal(np.asarray(image, dtype=bool), arrays["patterns"][layer - 1])


def test_open_loop_without_noise_conserves_the_jetted_volume(client):
    job = run_job(client, "jetting", {**SMALL, "controller": "open_loop", "layers": 5, "nozzle_spread": 0,
                                      "drop_noise": 0, "png_every": 0})
    final = npz(artifact(client, job, "heights.npz")[0])["final"]
    pitch = job["result"]["grid"]["pitch_mm"]
    drops = sum(row["drops"] for row in job["result"]["layers"])
    assert pitch == pytest.approx(25.4 / 150)
    assert final.sum() * pitch**2 == pytest.approx(drops * DROP_MM3, rel=1e-9)
    assert job["result"]["grid"]["layer_height_um"] == pytest.approx(DROP_MM3 / pitch**2 * 1e3)
    assert [a["name"] for a in job["artifacts"] if a["name"].endswith(".png")] == []


def test_same_params_give_identical_artifacts_and_another_seed_does_not(client):
    params = {**SMALL, "layers": 8, "png_every": 4}
    first, second = run_job(client, "jetting", params), run_job(client, "jetting", params)
    other = run_job(client, "jetting", {**params, "seed": 1})
    for name in ("patterns.npz", "heights.npz", "pattern_0008.png"):
        assert sha(first, name) == sha(second, name)
    assert sha(first, "heights.npz") != sha(other, "heights.npz")


def test_mask_artifact_of_a_previous_job_reproduces_its_run(client):
    params = {**SMALL, "controller": "open_loop", "layers": 3, "png_every": 1}
    square = run_job(client, "jetting", params)
    masked = run_job(client, "jetting", {**params, "target": {
        "mask": {"job_id": square["id"], "artifact": "pattern_0001.png"}}})
    assert masked["result"]["grid"] == square["result"]["grid"]
    assert sha(masked, "patterns.npz") == sha(square, "patterns.npz")
    inline = run_job(client, "jetting", {**params, "target": {"mask": {"png_base64": png_b64(small_target().mask)}}})
    assert sha(inline, "heights.npz") == sha(square, "heights.npz")
    # the stored mask is read and checked at submission: a drop larger than that part is a 422 now,
    # not a failed job later
    too_big = submit(client, "jetting", {**params, "drop_diameter_um": 5000, "target": {
        "mask": {"job_id": square["id"], "artifact": "pattern_0001.png"}}})
    assert too_big.status_code == 422, too_big.text
    assert error_field(too_big) == "params.drop_diameter_um"


def test_slice_layer_target_matches_the_same_parametric_square(client):
    """A 6 mm plate with a 2 mm square hole, sliced: its layer gives the grid and mask of
    the parametric square_with_hole (size 6, hole 2), so the open-loop runs agree exactly."""
    import manifold3d

    from tests.slicing.conftest import to_trimesh

    plate = manifold3d.Manifold.cube((6.0, 6.0, 1.0)) - manifold3d.Manifold.cube((2.0, 2.0, 3.0)).translate((2, 2, -1))
    stl = to_trimesh(plate).export(file_type="stl")
    part = client.post("/api/v1/parts", files={"file": ("plate.stl", stl)}, headers=OP)
    assert part.status_code == 201, part.text
    sliced = run_job(client, "slice", {"part_id": part.json()["id"], "layer_mm": 0.5})
    params = {**SMALL, "controller": "open_loop", "layers": 2, "png_every": 0}
    from_slice = run_job(client, "jetting", {**params, "target": {"slice": {"slice_job_id": sliced["id"], "layer": 1}}})
    square = run_job(client, "jetting", {**params, "target": {"size_mm": 6, "hole_mm": 2}})
    assert from_slice["result"]["grid"] == square["result"]["grid"]
    assert sha(from_slice, "patterns.npz") == sha(square, "patterns.npz")
    missing = submit(client, "jetting", {**params, "target": {"slice": {"slice_job_id": sliced["id"], "layer": 2}}})
    assert missing.status_code == 422 and error_field(missing) == "params.target.slice.layer"


def test_next_layer_from_a_jetting_snapshot(client):
    printed = run_job(client, "jetting", {**SMALL, "snapshot_every": 10, "png_every": 10})
    job = run_job(client, "jetting_next_layer", {
        "dpi": 150, "target": {"size_mm": 5, "hole_mm": 2}, "layer": 10,
        "measured": {"job_id": printed["id"], "layer": 10},
        "previous_pattern": {"job_id": printed["id"], "artifact": "pattern_0010.png"}})
    result, grid = job["result"], small_target()
    assert result["measured_layer"] == 10 and round_trips(NextLayerResult, job).measured_layer == 10
    assert result["reference_height_um"] == pytest.approx(11 * 0.8 * result["grid"]["layer_height_um"])
    assert 0 < result["drops"] <= grid.mask.sum() and result["integer_gap"] >= -1e-9
    arrays = npz(artifact(client, job, "next_pattern.npz")[0])
    image = Image.open(io.BytesIO(artifact(client, job, "next_pattern.png")[0]))
    assert image.mode == "1" and np.array_equal(np.asarray(image, dtype=bool), arrays["pattern"])
    assert arrays["relaxed"].shape == (1, *grid.shape) and int(arrays["pattern"].sum()) == result["drops"]
    assert not arrays["pattern"][~grid.mask].any()
    assert np.all((arrays["relaxed"] >= -1e-9) & (arrays["relaxed"] <= 1 + 1e-9))


def test_next_layer_fills_a_measured_trench(client):
    """The right half already stands at the next reference height, the left half one layer
    below it: the next pattern jets on the left half and (almost) nowhere on the right."""
    grid = small_target()
    layer_um = 1e3 * DROP_MM3 / grid.pitch_mm**2
    heights = np.where(grid.mask, 11 * 0.8 * layer_um, 0.0)  # r_(l+1) after l = 10 layers, fill 0.8
    left = np.zeros(grid.shape, dtype=bool)
    left[:, : grid.shape[1] // 2] = True
    heights[left & grid.mask] -= layer_um
    params = {"dpi": 150, "target": {"size_mm": 5, "hole_mm": 2}, "layer": 10, "edge_lead": 0,  # a flat reference
              "measured": {"heights_um": heights.tolist()}}
    job, again = run_job(client, "jetting_next_layer", params), run_job(client, "jetting_next_layer", params)
    for name in ("next_pattern.png", "next_pattern.npz"):
        assert sha(job, name) == sha(again, name)
    assert job["result"]["reference_height_um"] == pytest.approx(11 * 0.8 * layer_um)
    assert job["result"]["measured_layer"] is None
    pattern = npz(artifact(client, job, "next_pattern.npz")[0])["pattern"]
    density_left = pattern[left & grid.mask].mean()
    density_right = pattern[~left & grid.mask].mean()
    assert density_left > 0.9 and density_right < 0.1, (density_left, density_right)


def test_next_layer_from_an_uploaded_height_map_equals_the_inline_one(client):
    """The printer uploads its sensor's map (NPZ, heights (L, W) mm) as a file: same pattern
    as sending it inline; a file of the wrong type or grid is refused."""
    grid = small_target()
    layer_um = 1e3 * DROP_MM3 / grid.pitch_mm**2
    heights_um = np.where(grid.mask, 5 * 0.8 * layer_um, 0.0)
    buffer = io.BytesIO()
    np.savez(buffer, heights=heights_um / 1e3)
    upload = client.post("/api/v1/files", files={"file": ("sensor.npz", buffer.getvalue())}, headers=OP).json()
    base = {"dpi": 150, "target": {"size_mm": 5, "hole_mm": 2}, "layer": 4}
    from_file = run_job(client, "jetting_next_layer", {**base, "measured": {"file_id": upload["id"]}})
    inline = run_job(client, "jetting_next_layer", {**base, "measured": {"heights_um": heights_um.tolist()}})
    assert sha(from_file, "next_pattern.npz") == sha(inline, "next_pattern.npz")
    csv = client.post("/api/v1/files", files={"file": ("points.csv", b"x,y\n1,2\n")}, headers=OP).json()
    refused = submit(client, "jetting_next_layer", {**base, "measured": {"file_id": csv["id"]}})
    assert refused.status_code == 422 and error_field(refused) == "params.measured.file_id"
    buffer = io.BytesIO()
    np.savez(buffer, heights=np.zeros((3, 4)))
    wrong = client.post("/api/v1/files", files={"file": ("small.npz", buffer.getvalue())}, headers=OP).json()
    failed = submit(client, "jetting_next_layer", {**base, "measured": {"file_id": wrong["id"]}}).json()
    done = wait_for(client, failed["id"])
    assert done["status"] == "failed" and "does not match" in done["error"]["detail"]


def _black_png() -> str:
    return png_b64(np.zeros((20, 20), dtype=bool))


@pytest.mark.parametrize(("params", "field"), [
    ({"target": {"mask": {"png_base64": _black_png()}}}, "params.target.mask"),
    ({"target": {"mask": {"png_base64": ""}}}, "params.target.mask"),
    ({"target": {"mask": {"png_base64": base64.b64encode(b"not an image").decode()}}}, "params.target.mask"),
    ({"target": {"mask": {"png_base64": "***"}}}, "params.target.mask.png_base64"),
    ({"target": {"size_mm": 0.1, "hole_mm": 0}, "dpi": 1200, "drop_diameter_um": 200}, "params.drop_diameter_um"),
    ({"target": {"size_mm": 50, "hole_mm": 0}, "dpi": 2400}, "params.dpi"),
    ({"dpi": 5000}, "params.dpi"),
    ({"target": {"size_mm": 4, "hole_mm": 4}}, "params.target"),
    ({"target": {"size_mm": 4, "mask": {"png_base64": _black_png()}}}, "params.target"),
    ({"layers": 5000, "png_every": 1}, "params"),
    ({"horizon": 0}, "params.horizon"),
    ({"controller": "pid"}, "params.controller"),
    ({"dead_nozzles": [384]}, "params"),
    ({"tolerance": 1}, "params.tolerance"),
])
def test_bad_jetting_input_is_refused_at_submission(client, params, field):
    response = submit(client, "jetting", {**SMALL, **params})
    assert response.status_code == 422, response.text
    assert error_field(response) == field, response.json()
    assert client.get("/api/v1/jobs?kind=jetting", headers=OP).json()["total"] == 0


def test_bad_references_are_refused_at_submission(client):
    printed = run_job(client, "jetting", {**SMALL, "layers": 2, "png_every": 1})
    grid = small_target()
    cases = [
        ("jetting", {**SMALL, "target": {"mask": {"job_id": printed["id"], "artifact": "patterns.npz"}}},
         "params.target.mask"),
        ("jetting", {**SMALL, "target": {"mask": {"job_id": printed["id"], "artifact": "nope.png"}}},
         "params.target.mask"),
        ("jetting", {**SMALL, "target": {"slice": {"slice_job_id": printed["id"]}}},
         "params.target.slice.slice_job_id"),
        ("jetting_next_layer", {"dpi": 150, "target": SMALL["target"],
                                "measured": {"heights_um": np.zeros((grid.shape[0], 3)).tolist()}},
         "params.measured.heights_um"),
        ("jetting_next_layer", {"dpi": 150, "target": SMALL["target"], "measured": {"job_id": printed["id"],
                                                                                   "layer": 1}},
         "params.measured.layer"),
        ("jetting_next_layer", {"dpi": 300, "target": SMALL["target"], "measured": {"job_id": printed["id"]}},
         "params.measured"),
        ("jetting_next_layer", {"dpi": 150, "measured": {"job_id": printed["id"], "heights_um": [[0.0]]}},
         "params.measured"),
    ]
    for kind, params, field in cases:
        response = submit(client, kind, params)
        assert response.status_code == 422, (field, response.text)
        assert error_field(response) == field, (field, response.json())
    assert client.get("/api/v1/jobs?kind=jetting_next_layer", headers=OP).json()["total"] == 0
    assert client.get("/api/v1/jobs?kind=jetting", headers=OP).json()["total"] == 1


def test_cancel_stops_a_run_between_layers(client):
    response = submit(client, "jetting", {"dpi": 150, "layers": 5000, "png_every": 0})
    job_id = response.json()["id"]
    job = wait_for(client, job_id, states=("running",))
    deadline = time.monotonic() + 20
    while job["progress"] < 0.05 and time.monotonic() < deadline:
        time.sleep(0.05)
        job = client.get(f"/api/v1/jobs/{job_id}?include=result&include=artifacts", headers=OP).json()
    assert client.post(f"/api/v1/jobs/{job_id}/cancel", headers=OP).status_code == 202
    done = wait_for(client, job_id)
    assert done["status"] == "cancelled" and done["progress"] < 0.9
    assert done["artifacts"] == []


def test_job_kinds_describe_every_jetting_parameter(client):
    schemas = {k["name"]: k["params_schema"] for k in client.get("/api/v1/job-kinds", headers=OP).json()}
    for name in ("jetting", "jetting_next_layer"):
        schema = schemas[name]
        models = [schema, *schema.get("$defs", {}).values()]
        undocumented = [f"{m.get('title')}.{field}" for m in models
                        for field, prop in m.get("properties", {}).items() if "description" not in prop]
        assert undocumented == [], undocumented
    assert {"dpi", "drop_diameter_um", "layers", "controller", "horizon", "nozzle_spread", "seed",
            "png_every"} <= set(schemas["jetting"]["properties"])
    assert schemas["jetting"]["properties"]["dpi"]["maximum"] == 2400


def test_a_non_finite_measured_map_is_a_422_naming_params_measured(client):
    """The core's ``measured`` error names the job's parameter of the same name."""
    base = {"dpi": 150, "target": {"size_mm": 5, "hole_mm": 2}, "layer": 4}
    heights = np.zeros(small_target().shape)  # the grid of base's target
    heights[0, 0] = np.nan
    buffer = io.BytesIO()
    np.savez(buffer, heights=heights)
    upload_row = client.post("/api/v1/files", files={"file": ("nan.npz", buffer.getvalue())}, headers=OP).json()
    response = submit(client, "jetting_next_layer", {**base, "measured": {"file_id": upload_row["id"]}})
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"])
    assert done["status"] == "failed" and done["error"]["status"] == 422
    assert done["error"]["errors"][0]["loc"] == ["params", "measured"] and "non-finite" in done["error"]["detail"]
