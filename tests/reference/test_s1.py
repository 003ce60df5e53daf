"""S1 reference part: analytic surface vs NURBS core vs mesh, trace layout, as-made parts."""

import numpy as np
import pytest

from app.reference.s1 import (
    as_made,
    centred_placement,
    nominal_height,
    nominal_path,
    s1_mesh,
    s1_surface,
    s1_traces,
    trace_xy,
)


@pytest.fixture(scope="module")
def mesh():
    return s1_mesh()


def ray_heights(mesh, xy):
    origins = np.column_stack([xy, np.full(len(xy), 100.0)])
    loc, ray, _ = mesh.ray.intersects_location(origins, np.tile([0, 0, -1.0], (len(xy), 1)))
    z = np.full(len(xy), -np.inf)
    np.maximum.at(z, ray, loc[:, 2])
    return z


def test_surface_matches_geometry_core_nurbs():
    surf = s1_surface()
    rng = np.random.default_rng(0)
    uv = rng.uniform(0, 1, (200, 2))
    p = surf.evaluate(uv[:, 0], uv[:, 1])
    # Greville control points: x = 60 u, y = 40 v exactly, z = the analytic height
    assert np.allclose(p[:, 0], 60 * uv[:, 0], atol=1e-12)
    assert np.allclose(p[:, 1], 40 * uv[:, 1], atol=1e-12)
    assert np.allclose(p[:, 2], nominal_height(p[:, :2]), atol=1e-12)
    z = nominal_height(np.stack(np.meshgrid(np.linspace(0, 60, 61), np.linspace(0, 40, 41)),
                                -1).reshape(-1, 2))
    assert 2.0 < np.ptp(z) < 6.0  # "a few mm of relief"
    assert np.isnan(nominal_height([[61.0, 5.0]]))[0]


def test_mesh_is_a_watertight_block_and_tessellation_error_is_sub_micron(mesh):
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert np.allclose(mesh.bounds[0], [0, 0, 0])
    assert mesh.bounds[1][:2].tolist() == [60.0, 40.0]
    # volume = integral of the height field (fine midpoint rule)
    x = (np.arange(600) + 0.5) * 0.1
    y = (np.arange(400) + 0.5) * 0.1
    grid = np.stack(np.meshgrid(x, y, indexing="ij"), -1).reshape(-1, 2)
    assert mesh.volume == pytest.approx(nominal_height(grid).mean() * 2400, rel=1e-4)
    for trace in s1_traces()[::4]:
        xy = trace_xy(trace.geometry, 0.05)
        assert np.abs(ray_heights(mesh, xy) - nominal_height(xy)).max() < 0.5e-3


def test_nine_traces_in_the_paper_layout():
    traces = s1_traces()
    assert [t.kind for t in traces] == ["line"] * 3 + ["arc"] * 3 + ["nurbs"] * 3
    assert [t.standoff_mm for t in traces] == [0.08, 0.10, 0.11] * 3
    paths = [trace_xy(t.geometry, 0.02) for t in traces]
    for i, p in enumerate(paths):
        ends = p[[0, -1]]
        assert np.linalg.norm(ends[1] - ends[0]) == pytest.approx(32.0, abs=1e-9)
        assert ends[0, 0] == pytest.approx(6.0 + 4.0 * i) and ends[:, 1].tolist() == [4.0, 36.0]
        assert p[:, 1].min() >= 4.0 - 1e-9 and p[:, 1].max() <= 36.0 + 1e-9
    arc = traces[3].geometry
    assert arc["radius"] == 40.0
    assert np.allclose(np.linalg.norm(paths[3] - arc["center"], axis=1), 40.0)
    for a, b in zip(paths[:-1], paths[1:]):  # neighbours never come closer than 1 mm
        d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2).min()
        assert d > 1.0
    assert traces[0].to_api()["frame"] == "xy"


def test_as_made_part_is_consistent_and_seeded():
    part = as_made(5, amplitude_mm=0.15, placement=centred_placement(0.1, -0.05, 0.02, 0.3))
    assert as_made(5).waves.tolist() == as_made(5).waves.tolist()
    assert as_made(5).waves.tolist() != as_made(6).waves.tolist()
    rng = np.random.default_rng(0)
    p = rng.uniform([5, 5], [55, 35], (300, 2))
    assert np.allclose(part.to_part(part.to_machine(p)), p, atol=1e-12)
    grid = np.stack(np.meshgrid(np.linspace(0, 60, 121), np.linspace(0, 40, 81)), -1).reshape(-1, 2)
    assert np.abs(part.machining_error(grid)).max() == pytest.approx(0.15)
    # the true height at the machine xy of a part point = nominal + error + dz there
    m = part.to_machine(p)
    expected = nominal_height(p) + part.machining_error(p) + 0.02
    assert np.allclose(part.true_height(m), expected, atol=1e-12)
    true_mesh = part.mesh(grid_mm=0.25)
    assert true_mesh.is_watertight
    assert np.abs(ray_heights(true_mesh, m) - part.true_height(m)).max() < 2e-3


def test_nominal_path_lies_on_the_surface():
    path = nominal_path(s1_traces()[4], 0.05)
    assert np.allclose(path.points[:, 2], nominal_height(path.points[:, :2]))
    assert np.allclose(np.linalg.norm(path.normals, axis=1), 1.0)
    assert path.length_mm > 32.0


def test_end_to_end_with_the_geometry_core():
    """Drape an S1 trace on the mesh (geometry core), plan, probe program, reconstruct."""
    from app.geometry.traces import build_nominal_trace
    from app.probing.program import build_probe_program
    from app.probing.selection import PlanParams, plan_probes
    from app.reconstruction.reconstruct import reconstruct

    mesh = s1_mesh(grid_mm=0.5)
    trace = s1_traces()[7]
    nominal = build_nominal_trace(mesh, trace.geometry, "xy")
    # the draped trace lies on the analytic top to the mesh's tessellation error
    assert np.abs(nominal.points[:, 2] - nominal_height(nominal.points[:, :2])).max() < 0.01
    plan = plan_probes(nominal, "deviation", PlanParams(count=12))
    prog = build_probe_program(plan, mesh)
    assert prog.gcode.count("G38.2") == 12
    part = as_made(7, placement=centred_placement())
    pts = plan.points.copy()
    pts[:, 2] = part.true_height(pts[:, :2])
    rec = reconstruct(nominal, pts, "deviation", sigma_mm=0.0)
    q = np.linspace(0, rec.nominal.length_mm, 200)
    xy = rec.nominal.at(q)[:, :2]
    # real height = mesh nominal + reconstructed deviation; truth = analytic + error
    assert np.abs(rec.height_at_s(q) - part.true_height(xy)).max() < 0.015
