"""Registration: placement round trips, recovery of a known placement from simulated
touches (within 3 sigma of the reported uncertainty), degenerate sets, datum planning,
side faces found with -Z touches only (what the mock can do)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from app.geometry.placement import Placement, apply_placement, remove_placement
from app.platform.problems import http_status
from app.reference import s1
from app.registration.datum_plan import (
    DatumProbeParams,
    find_edge,
    plan_datum_probes,
    register_with_z_probe,
)
from app.registration.registration import (
    DegenerateDatumError,
    RegistrationError,
    RegistrationParams,
    fit_placement,
    place_path,
)

CENTER = (30.0, 20.0)
TRUE = Placement.from_deg(dx=0.08, dy=-0.05, dz=0.03, rz_deg=0.15, pivot_xy=CENTER)
SIDES = {"-x": (np.array([-1.0, 0, 0]), 0.0), "+x": (np.array([1.0, 0, 0]), 60.0),
         "-y": (np.array([0, -1.0, 0]), 0.0), "+y": (np.array([0, 1.0, 0]), 40.0)}


@settings(max_examples=25, deadline=None)
@given(dx=st.floats(-5, 5), dy=st.floats(-5, 5), dz=st.floats(-1, 1),
       rz=st.floats(-3.0, 3.0), px=st.floats(-50, 50), py=st.floats(-50, 50))
def test_apply_remove_round_trip(dx, dy, dz, rz, px, py):
    pl = Placement.from_deg(dx, dy, dz, rz, (px, py))
    pts = np.random.default_rng(0).uniform(-40, 40, (7, 3))
    np.testing.assert_allclose(remove_placement(apply_placement(pts, pl), pl), pts, atol=1e-9)
    # rigid: distances preserved; xy-only input ignores dz
    moved = apply_placement(pts, pl)
    np.testing.assert_allclose(np.linalg.norm(moved[0] - moved[1]),
                               np.linalg.norm(pts[0] - pts[1]), rtol=1e-12)
    np.testing.assert_allclose(apply_placement(pts[:, :2], pl), moved[:, :2], atol=1e-9)


def test_placement_matches_reference_part_convention():
    part = s1.as_made(seed=0, placement=s1.centred_placement(0.08, -0.05, 0.03, 0.15))
    xy = np.random.default_rng(1).uniform(0, 40, (5, 2))
    np.testing.assert_allclose(apply_placement(xy, TRUE), part.to_machine(xy), atol=1e-12)


def test_place_path_moves_trace_into_machine_frame():
    part = s1.as_made(seed=0, placement=s1.centred_placement(0.08, -0.05, 0.03, 0.15))
    path = s1.nominal_path(s1.s1_traces()[6], 0.2)
    placed = place_path(path, TRUE)
    np.testing.assert_allclose(placed.points[:, :2], part.to_machine(path.points[:, :2]),
                               atol=1e-12)
    np.testing.assert_allclose(placed.points[:, 2], path.points[:, 2] + 0.03, atol=1e-12)
    np.testing.assert_allclose(placed.s, path.s)
    # the placed nominal lies on the placed (machining-error-free) part: normals rotated
    # with it stay perpendicular to the placed trace's tangent
    tangent = np.diff(placed.points, axis=0)
    dots = np.einsum("ij,ij->i", tangent, placed.normals[:-1]) / np.linalg.norm(tangent, axis=1)
    assert np.abs(dots).max() < 0.02


def side_touch(q: np.ndarray, n: np.ndarray, pl: Placement, noise: float, approach=2.0):
    """Probe from q + n*approach along -n (machine frame, placement unknown to the
    machine) until the placed plane through T(q) with normal R n."""
    rot = pl.rotation()
    start, d = q + n * approach, -n
    rn = rot @ n
    target = apply_placement(q[None], pl)[0]
    lam = rn @ (target - start) / (rn @ d)
    return start + (lam + noise) * d


def top_touch(xy: np.ndarray, pl: Placement, noise: float, height=s1.nominal_height):
    part_xy = remove_placement(xy[None], pl)
    return np.array([xy[0], xy[1], height(part_xy)[0] + pl.dz + noise])


def s1_surface(kinds):
    """Foot points and normals for the fit: planes for side touches, the nominal top
    (vertical foot point, gradient normal) for top touches."""
    def surface(p):
        foot, nrm = p.copy(), np.zeros_like(p)
        for i, kind in enumerate(kinds):
            if kind == "top":
                foot[i, 2] = s1.nominal_height(p[i:i + 1, :2])[0]
                g = s1.nominal_gradient(p[i:i + 1, :2])[0]
                n = np.array([-g[0], -g[1], 1.0])
                nrm[i] = n / np.linalg.norm(n)
            else:
                n, c = SIDES[kind]
                nrm[i] = n
                foot[i] = p[i] - (p[i] @ n - c) * n
        return foot, nrm
    return surface


def simulate(pl: Placement, sigma: float, seed: int):
    rng = np.random.default_rng(seed)
    touches = [("-x", [0.0, 8.0, 5.0]), ("-x", [0.0, 32.0, 5.0]), ("-y", [40.0, 0.0, 5.0]),
               ("+y", [20.0, 40.0, 5.0]), ("top", [15.0, 12.0]), ("top", [45.0, 28.0]),
               ("top", [25.0, 30.0])]
    kinds, q, n, m, d = [], [], [], [], []
    for kind, p in touches:
        e = rng.normal(0.0, sigma)
        if kind == "top":
            xy = np.array(p)
            z = s1.nominal_height(xy[None])[0]
            g = s1.nominal_gradient(xy[None])[0]
            nn = np.array([-g[0], -g[1], 1.0]) / math.hypot(1, *g)
            q.append([*xy, z]), n.append(nn), m.append(top_touch(xy, pl, e))
            d.append([0, 0, -1.0])
        else:
            nn = SIDES[kind][0]
            q.append(p), n.append(nn), m.append(side_touch(np.array(p), nn, pl, e))
            d.append(-nn)
        kinds.append(kind)
    return kinds, np.array(q, float), np.array(n), np.array(m), np.array(d)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_recovers_known_placement_within_three_sigma(seed):
    kinds, q, n, m, d = simulate(TRUE, 0.001, seed)
    reg = fit_placement(q, n, m, RegistrationParams(sigma_mm=0.001, pivot_xy=CENTER),
                        surface=s1_surface(kinds), directions=d)
    est = reg.placement
    for name, truth in (("dx", TRUE.dx), ("dy", TRUE.dy), ("dz", TRUE.dz),
                        ("rz", TRUE.rz_rad)):
        value = est.rz_rad if name == "rz" else getattr(est, name)
        assert abs(value - truth) <= 3 * reg.std[name], (name, value, truth, reg.std[name])
    assert reg.std["dx"] < 0.003 and reg.std["rz"] < math.radians(0.01)
    assert reg.rms_mm < 0.005
    result = reg.to_result()
    assert set(result["uncertainty"]) == {"dx_mm", "dy_mm", "dz_mm", "rz_deg"}


def test_exact_touches_recover_exactly():
    kinds, q, n, m, d = simulate(TRUE, 0.0, 0)
    reg = fit_placement(q, n, m, RegistrationParams(pivot_xy=CENTER),
                        surface=s1_surface(kinds), directions=d)
    assert abs(reg.placement.dx - TRUE.dx) < 1e-7 and abs(reg.placement.dy - TRUE.dy) < 1e-7
    assert abs(reg.placement.rz_rad - TRUE.rz_rad) < 1e-8
    assert abs(reg.placement.dz - TRUE.dz) < 1e-7


def flat_top_touches(pl, count=6):
    xy = np.random.default_rng(3).uniform(5, 35, (count, 2))
    q = np.column_stack([xy, np.full(count, 10.0)])
    n = np.tile([0.0, 0.0, 1.0], (count, 1))
    m = apply_placement(q, pl)
    m[:, :2] = xy  # vertical touches at the planned xy see only the height
    return q, n, m


def test_all_touches_on_one_face_is_degenerate():
    q, n, m = flat_top_touches(TRUE)
    with pytest.raises(DegenerateDatumError) as info:
        fit_placement(q, n, m, RegistrationParams(pivot_xy=CENTER))
    assert http_status(info.value)[0] == 422 and info.value.field == "measured"
    # estimating only what a flat top can see works
    reg = fit_placement(q, n, m, RegistrationParams(pivot_xy=CENTER, estimate=("dz",)))
    assert reg.placement.dz == pytest.approx(TRUE.dz, abs=1e-9) and reg.estimated == ("dz",)


def test_too_few_touches_and_bad_input():
    _kinds, q, n, m, _d = simulate(TRUE, 0.0, 0)
    with pytest.raises(DegenerateDatumError):
        fit_placement(q[:3], n[:3], m[:3])
    with pytest.raises(RegistrationError):
        fit_placement(q, n, m[:-1])
    with pytest.raises(RegistrationError):
        fit_placement(q, np.zeros_like(n), m)
    with pytest.raises(RegistrationError):
        RegistrationParams(estimate=("dx", "tilt"))


@pytest.fixture(scope="module")
def s1_part_mesh():
    return s1.s1_mesh(grid_mm=1.0)


def test_plan_sides_covers_both_side_axes_and_top(s1_part_mesh):
    plan = plan_datum_probes(s1_part_mesh, "sides", count=7, candidates=2000)
    labels = set(plan.faces)
    assert labels & {"+x", "-x"} and labels & {"+y", "-y"} and labels & {"top", "slope"}
    assert plan.unobservable == () and set(plan.predicted_std) == {"dx", "dy", "dz", "rz"}
    # every probing move starts outside the part and travels toward the touch point
    np.testing.assert_allclose(plan.starts + plan.directions * 2.0, plan.points, atol=1e-9)
    assert not s1_part_mesh.contains(plan.starts).any()
    # simulated touches with this plan recover the placement
    kinds = [f if f in SIDES else "top" for f in plan.faces]
    rng = np.random.default_rng(5)
    meas = []
    for kind, p, nn in zip(kinds, plan.points, plan.normals):
        e = rng.normal(0.0, 0.001)
        meas.append(top_touch(p[:2], TRUE, e) if kind == "top"
                    else side_touch(p, SIDES[kind][0], TRUE, e))
    q = plan.points.copy()
    reg = fit_placement(q, plan.normals, np.array(meas),
                        RegistrationParams(pivot_xy=plan.pivot_xy), surface=s1_surface(kinds),
                        directions=plan.directions)
    assert abs(reg.placement.dx - TRUE.dx) <= 3 * reg.std["dx"] + 2e-4


def test_plan_z_only_reports_what_a_flat_top_cannot_see():
    box = trimesh.creation.box(extents=(60, 40, 10))
    plan = plan_datum_probes(box, "z_only", count=6, candidates=1500)
    assert set(plan.unobservable) >= {"dx", "dy"} and "dz" in plan.predicted_std
    assert np.all(plan.directions[:, 2] == -1.0)


def test_plan_z_only_on_free_form_top_observes_xy(s1_part_mesh):
    plan = plan_datum_probes(s1_part_mesh, "z_only", count=10, candidates=2000)
    assert plan.unobservable == ()
    # slopes of a few tenths: xy uncertainty tens of times the probe sigma, not 1x
    assert 0.001 < plan.predicted_std["dx"] < 0.05


def placed_probe(part: s1.AsMadePart):
    """-Z touch on the as-made part (with machining error) or the bed at z = 0."""
    def probe(x, y):
        z = part.true_height(np.array([[x, y]]))[0]
        return 0.0 if np.isnan(z) else float(z)
    return probe


def test_side_faces_found_with_z_touches_recover_xy_and_rz():
    """The mock's path: edges by -Z bisection + top touches; dx, dy, rz are exact to the
    resolution although the free-form top carries +-0.15 mm machining error."""
    part = s1.as_made(seed=2, amplitude_mm=0.15,
                      placement=s1.centred_placement(0.08, -0.05, 0.03, 0.15))
    probe = placed_probe(part)
    edges = [find_edge(probe, (1.0, y), (-1.0, y), 4.0, resolution_mm=0.0005)
             for y in (8.0, 32.0)]
    edges.append(find_edge(probe, (30.0, 1.0), (30.0, -1.0), 4.0, resolution_mm=0.0005))
    assert all(e.touches <= 15 for e in edges)
    m = np.array([e.point for e in edges])
    n = np.array([e.normal for e in edges])
    q = m.copy()
    q[:2, 0] = 0.0  # the nominal wall x = 0 (y and z of a plane point do not matter)
    q[2, 1] = 0.0   # the nominal wall y = 0
    reg = fit_placement(q, n, m, RegistrationParams(pivot_xy=CENTER,
                                                    estimate=("dx", "dy", "rz"),
                                                    sigma_mm=0.0005))
    assert abs(reg.placement.dx - 0.08) < 0.001 and abs(reg.placement.dy + 0.05) < 0.001
    assert abs(reg.placement.rz_deg - 0.15) < 0.005


def test_find_edge_refuses_ends_that_do_not_straddle():
    part = s1.as_made(seed=2, placement=s1.centred_placement())
    with pytest.raises(RegistrationError):
        find_edge(placed_probe(part), (5.0, 5.0), (6.0, 5.0), 4.0)


def mesh_probe(mesh: trimesh.Trimesh, pl: Placement, noise: float = 0.0, seed: int = 0):
    """-Z touch on ``mesh`` placed by ``pl`` (ray cast), the bed z = 0 beside it."""
    placed = mesh.copy()
    placed.apply_transform(pl.matrix())
    top = placed.bounds[1][2] + 1.0
    rng = np.random.default_rng(seed)

    def probe(x, y):
        hits, _, _ = placed.ray.intersects_location([[x, y, top]], [[0.0, 0.0, -1.0]])
        z = float(hits[:, 2].max()) if len(hits) else 0.0
        return z + (rng.normal(0.0, noise) if noise else 0.0)
    return probe


def test_register_with_z_probe_exact_on_the_placed_mesh(s1_part_mesh):
    """No noise, no machining error: walls to the bisection resolution, dz exactly
    (the height touches land on their nominal points), covariance in two blocks."""
    truth = Placement.from_deg(0.2, -0.15, 0.03, 0.3)  # about the origin, as the mock
    plan = plan_datum_probes(s1_part_mesh, "sides", candidates=2000)
    reg = register_with_z_probe(plan, mesh_probe(s1_part_mesh, truth), 0.0,
                                DatumProbeParams(resolution_mm=0.0002))
    got = reg.placement
    assert abs(got.dx - 0.2) < 5e-4 and abs(got.dy + 0.15) < 5e-4
    assert abs(got.rz_deg - 0.3) < 0.001 and abs(got.dz - 0.03) < 1e-4  # 0.1 um
    assert reg.unobservable == () and reg.fit_names == ("edges", "heights")
    assert reg.covariance[2, [0, 1, 3]].tolist() == [0.0, 0.0, 0.0]
    assert reg.probe_count == sum(t.touches for t in reg.touches) > len(plan.points)
    # the found wall points lie on the placed walls
    for t in reg.touches:
        if t.face in SIDES:
            back = remove_placement(t.measured[None], truth)[0]
            assert abs(t.normal @ (back - t.nominal)) < 3e-4
    result = reg.to_result()
    assert result["std"]["rz_deg"] == pytest.approx(math.degrees(reg.std["rz"]))


@pytest.mark.parametrize("seed", [0, 1])
def test_register_with_z_probe_within_three_sigma_with_machining_error(s1_part_mesh, seed):
    """1 um noise, +-0.15 mm machining error on the top: dx, dy, rz within 3 sigma (the
    walls are planar); dz within the machining error."""
    part = s1.as_made(seed=seed + 4, amplitude_mm=0.15,
                      placement=s1.centred_placement(0.12, 0.09, 0.03, -0.25))
    rng = np.random.default_rng(seed)

    def probe(x, y):
        return placed_probe(part)(x, y) + rng.normal(0.0, 0.001)
    plan = plan_datum_probes(s1_part_mesh, "sides", candidates=2000)
    reg = register_with_z_probe(plan, probe, 0.0, DatumProbeParams(pivot_xy=CENTER))
    got, std = reg.placement, reg.std
    assert abs(got.dx - 0.12) <= 3 * std["dx"] and abs(got.dy - 0.09) <= 3 * std["dy"]
    assert abs(got.rz_deg + 0.25) <= 3 * math.degrees(std["rz"]) and std["dx"] < 0.002
    assert abs(got.dz - 0.03) <= 0.15


def test_register_with_z_probe_flat_top_and_out_of_reach():
    box = trimesh.creation.box(extents=(60, 40, 10))
    box.apply_translation([30.0, 20.0, 5.0])
    truth = Placement.from_deg(0.3, 0.0, 0.05, 0.2)
    z_only = plan_datum_probes(box, "z_only", count=4, candidates=1500)
    reg = register_with_z_probe(z_only, mesh_probe(box, truth), 0.0)
    assert {"dx", "dy"} <= set(reg.unobservable) and reg.placement.dx == 0.0
    assert abs(reg.placement.dz - 0.05) < 1e-9 and reg.probe_count == 4
    sides = plan_datum_probes(box, "sides", candidates=1500)
    with pytest.raises(RegistrationError, match="straddle"):  # moved further than the search
        register_with_z_probe(sides, mesh_probe(box, Placement(dx=2.5, dy=2.5)), 0.0,
                              DatumProbeParams(search_mm=1.0))
