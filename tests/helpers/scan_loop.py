"""A mock machine holding an as-made reference part, the reference pad and sphere, and a mock LK-G
with hidden errors, for the closed loop measuring by scanning (a test and a bench).

The sensor's offset, time offset, scale error and tilt bias are drawn from the part's seed
(never used to tune anything); it drops out beyond ``acceptance_deg`` of tilt (the wavy top's
steep flanks) and in the ``dark`` spots.  :func:`trace_errors` checks each trace's rebuilt
height against the as-made part's analytic top, independently of the loop's own figures."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from app.geometry.traces import TracePolyline
from app.reconstruction.stored import read_reconstruction
from app.reference.s1 import AsMadePart, as_made, s1_mesh, s1_traces
from tests.conftest import auth
from tests.helpers.jobs import submit, wait_for

OP = auth("operator")
PAD, SPHERE, DIAMETER = (150.0, 10.0, 3.0), (110.0, 12.0, 12.0), 25.4
NOMINAL_OFFSET = (30.0, 5.0, -10.0)
GRID = 0.2  # mesh facets: the sensor reads the true mesh, deviations are taken against the nominal mesh


@dataclass
class ScanBed:
    truth: AsMadePart
    part: dict[str, Any]
    traces: list[dict[str, Any]]
    machine: dict[str, Any]
    hidden: dict[str, Any]
    port: str


def scan_bed(client: Any, seed: int, trace_indices: tuple[int, ...], acceptance_deg: float = 10.0,
             dark: str = "", disconnect_at_line: int | None = None) -> ScanBed:
    """Upload the nominal and the as-made part (seed), the traces, a mock machine (its link
    dropping once at ``disconnect_at_line``) and the sensor's link."""
    truth = as_made(seed=seed, amplitude_mm=0.15)
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_mesh(grid_mm=GRID).export(file_type="stl"))},
                       headers=OP).json()
    real = client.post("/api/v1/parts", files={"file": ("real.stl", truth.mesh(grid_mm=GRID).export(file_type="stl"))},
                       headers=OP).json()
    traces = client.post(f"/api/v1/parts/{part['id']}/traces:import",
                         json=[s1_traces()[i].to_api() for i in trace_indices], headers=OP).json()["items"]
    reference = {"pad": {"centre_mm": list(PAD), "size_mm": 20.0},
                 "sphere": {"centre_mm": list(SPHERE), "diameter_mm": DIAMETER}}
    machine = client.post("/api/v1/machines", json={
        "name": "sim", "port": "mock://", "dialect": "marlin", "profile": {"reference": reference},
        "mock": {"true_part_id": real["id"], "probe_noise_mm": 0.001, "physics": reference,
                 "faults": {"disconnect_at_line": disconnect_at_line}}}, headers=OP).json()
    rng = np.random.default_rng(seed)
    hidden = {"offset": np.asarray(NOMINAL_OFFSET) + rng.uniform(-0.2, 0.2, 3), "tau": rng.uniform(0.5e-3, 4e-3),
              "scale_error": rng.uniform(-0.005, 0.005), "bias": rng.uniform(0.0, 0.003)}
    port = (f"lkg://{machine['id']}?offset={','.join(f'{v:.6f}' for v in hidden['offset'])}"
            f"&time_offset_ms={hidden['tau'] * 1e3:.6f}&scale_error={hidden['scale_error']:.6f}"
            f"&slope_bias_mm={hidden['bias']:.6f}&acceptance_deg={acceptance_deg:g}&noise_mm=0.0005&rate_hz=2000"
            f"&seed={seed}" + (f"&dark={dark}" if dark else ""))
    return ScanBed(truth, part, traces, machine, hidden, port)


def hidden_calibration(bed: ScanBed) -> dict[str, Any]:
    """The sensor's true calibration (what a perfect calibrate_sensor would store)."""
    return {"offset_mm": bed.hidden["offset"].tolist(), "scale": 1 + bed.hidden["scale_error"],
            "time_offset_s": bed.hidden["tau"], "slope_bias_mm": bed.hidden["bias"]}


def calibrate(client: Any, bed: ScanBed) -> dict[str, Any]:
    """Run calibrate_sensor on the bed's machine (asserts it succeeded); its result."""
    response = submit(client, "calibrate_sensor", {"machine_id": bed.machine["id"], "sensor_port": bed.port,
                                                   "nominal_offset_mm": list(NOMINAL_OFFSET)})
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"], timeout=300)
    assert done["status"] == "succeeded", done["error"]
    return dict(done["result"])


def scan_loop(client: Any, bed: ScanBed, scan: dict[str, Any], timeout: float = 600) -> dict[str, Any]:
    """Run closed_loop measuring scan over the bed's traces; the finished job."""
    response = submit(client, "closed_loop", {"part_id": bed.part["id"], "trace_ids": [t["id"] for t in bed.traces],
                                              "machine_id": bed.machine["id"], "measuring": "scan",
                                              "scan": {"sensor_port": bed.port, **scan}})
    assert response.status_code == 202, response.text
    return dict(wait_for(client, response.json()["id"], timeout=timeout))


def trace_errors(client: Any, bed: ScanBed, loop: dict[str, Any], points: int = 161) -> list[tuple[float, float]]:
    """(largest |rebuilt - true| height mm, the loop's bound mm) of each trace, the truth being
    the as-made part's analytic top along the trace's nominal path."""
    out = []
    jobs: dict[str, dict[str, Any]] = {}
    for row, trace in zip(loop["result"]["traces"], bed.traces):
        if row["reconstruct"] not in jobs:
            jobs[row["reconstruct"]] = wait_for(client, row["reconstruct"], timeout=5)
        rebuilt = jobs[row["reconstruct"]]
        urls = {a["name"]: a["url"] for a in rebuilt["artifacts"]}
        name = next(r["reconstruction"] for r in rebuilt["result"]["traces"] if r["trace_id"] == trace["id"])
        nominal = TracePolyline.from_dict(trace["nominal"])
        rec = read_reconstruction(client.get(urls[name], headers=OP).content, nominal)
        s = np.linspace(0.0, nominal.length_mm, points)
        error = np.abs(rec.height_at_s(s) - bed.truth.true_height(nominal.at(s)[:, :2]))
        out.append((float(error.max()), float(row["bound_mm"])))
    return out
