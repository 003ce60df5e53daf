"""Probe program: collision-free travel against the part, approach, dialects, records."""

import numpy as np
import pytest

from app.probing.program import ProbeProgramParams, build_probe_program, segment_top_max
from app.probing.selection import PlanError, PlanParams, plan_probes
from app.reference.s1 import as_made, nominal_height, nominal_path, s1_mesh, s1_traces


@pytest.fixture(scope="module")
def plans():
    traces = s1_traces()
    return [plan_probes(nominal_path(traces[i], 0.2), "uniform", PlanParams(count=8))
            for i in (0, 4, 8)]


def xy_moves(moves):
    """(a, b) pairs of consecutive waypoints that move in X/Y."""
    return [(a, b) for a, b in zip(moves[:-1], moves[1:]) if np.linalg.norm(b[:2] - a[:2]) > 1e-9]


def dense_top(a, b, height, step=0.01):
    n = int(np.ceil(np.linalg.norm(b[:2] - a[:2]) / step)) + 1
    t = np.linspace(0, 1, n)[:, None]
    z = height(a[:2] + t * (b[:2] - a[:2]))
    return np.nanmax(z) if np.isfinite(z).any() else -np.inf


@pytest.mark.parametrize("dialect,style", [("grbl", "g38"), ("marlin", "g30"), ("marlin", "g38")])
def test_travel_clears_the_part_everywhere(plans, dialect, style):
    clearance = 2.0
    params = ProbeProgramParams(dialect=dialect, probe_style=style, clearance_mm=clearance,
                                sample_mm=0.25)
    for plan in plans:
        prog = build_probe_program(plan, nominal_height, params)
        moves = prog.moves
        pairs = xy_moves(moves)
        assert len(pairs) == plan.count - 1  # one X/Y travel between points
        assert moves[0][2] >= max(m[2] for m in moves)  # enters at the highest level
        for a, b in pairs:
            assert a[2] == b[2]  # X/Y travel is level
            # never below the part's highest point along the segment + clearance
            # (1 um slack: the callable is sampled every 0.25 mm)
            assert a[2] >= dense_top(a, b, nominal_height) + clearance - 1e-3
        lines = prog.gcode.splitlines()
        probe_cmd = "G38.2" if style == "g38" else "G30"
        assert sum(line.startswith(probe_cmd) for line in lines) == plan.count
        assert lines[0].startswith("; conforma job=- kind=probe_plan")
        # the first motion is straight up, before any X/Y move
        assert lines[4].startswith("G0 Z")


def test_approach_above_true_part_and_target_below(plans):
    part = as_made(3)
    params = ProbeProgramParams(approach_mm=1.0, overtravel_mm=1.0)
    for plan in plans:
        prog = build_probe_program(plan, nominal_height, params)
        for rec in prog.records:
            true_z = part.true_height(np.array([rec.nominal[:2]]))[0]
            assert rec.approach_z_mm > true_z > rec.target_z_mm
            assert rec.safe_z_mm >= rec.approach_z_mm
            assert rec.expected_trigger_z_mm == rec.nominal[2]
        assert [r.index for r in prog.records] == list(range(plan.count))
        d = prog.records[0].to_dict()
        assert set(d) >= {"index", "s_mm", "nominal", "safe_z_mm", "expected_trigger_z_mm"}


def test_exact_mesh_segment_max_and_program_on_mesh(plans):
    mesh = s1_mesh(grid_mm=1.0)
    a, b = np.array([2.0, 3.0]), np.array([55.0, 37.0])
    exact = segment_top_max(mesh, a, b, 0.25)
    # the mesh is linear between edge crossings: dense ray samples can only be lower
    n = 4001
    t = np.linspace(0, 1, n)[:, None]
    xy = a + t * (b - a)
    origins = np.column_stack([xy, np.full(n, 100.0)])
    loc, ray, _ = mesh.ray.intersects_location(origins, np.tile([0, 0, -1.0], (n, 1)))
    sampled = loc[:, 2].max()
    assert sampled <= exact + 1e-9 and exact - sampled < 1e-3
    prog = build_probe_program(plans[1], mesh, ProbeProgramParams(clearance_mm=1.0))
    for p, q in xy_moves(prog.moves):
        assert p[2] >= segment_top_max(mesh, p[:2], q[:2], 0.25) + 1.0 - 1e-9


def test_same_inputs_same_bytes_and_bad_params(plans):
    one = build_probe_program(plans[0], nominal_height, job_id="abc").gcode
    assert one == build_probe_program(plans[0], nominal_height, job_id="abc").gcode
    assert "job=abc" in one.splitlines()[0]
    with pytest.raises(PlanError):
        ProbeProgramParams(dialect="grbl", probe_style="g30")
    with pytest.raises(PlanError):
        ProbeProgramParams(clearance_mm=0)
