"""Reconstruction: interpolation through points, deviation model, outliers, bad input."""

import numpy as np
import pytest
from geomdl import fitting as geomdl_fitting

from app.geometry.nurbs import NurbsCurve
from app.platform.problems import http_status
from app.probing.selection import PlanParams, plan_probes
from app.reconstruction.preprocess import PreprocessParams, ReconstructionError
from app.reconstruction.reconstruct import ReconstructParams, reconstruct
from app.reference.s1 import as_made, nominal_path, s1_traces


@pytest.fixture(scope="module")
def path():
    return nominal_path(s1_traces()[7], 0.1)  # a NURBS trace


def measure(path, s, dz_fn):
    pts = path.at(s)
    pts[:, 2] += dz_fn(s)
    return pts


def cubic_dz(s):
    return 0.05 + 2e-3 * s - 3e-4 * s ** 2 + 6e-6 * s ** 3


def test_interpolation_passes_through_every_point(path):
    s = np.linspace(0, path.length_mm, 9)
    pts = measure(path, s, cubic_dz)
    rec = reconstruct(path, pts, "interpolate", sigma_mm=0.0)
    assert rec.curve.invert(pts).distance.max() < 1e-9
    assert np.abs(rec.height_at_xy(pts[:, :2]) - pts[:, 2]).max() < 1e-9
    # the seed's eqs. 2-3 are The NURBS Book's global interpolation: geomdl agrees
    ref = geomdl_fitting.interpolate_curve(pts.tolist(), 3)
    assert np.abs(np.array(ref.ctrlpts) - rec.curve.control_points).max() < 1e-9
    assert np.allclose(ref.knotvector, rec.curve.knots, atol=1e-12)


def test_deviation_model_is_exact_for_a_cubic_deviation(path):
    s = np.linspace(0, path.length_mm, 6)
    rec = reconstruct(path, measure(path, s, cubic_dz), "deviation", sigma_mm=0.0)
    q = np.linspace(0, path.length_mm, 301)
    assert np.abs(rec.deviation_at_s(q) - cubic_dz(q)).max() < 1e-9
    assert np.abs(rec.height_at_s(q) - (path.z_at(q) + cubic_dz(q))).max() < 1e-9
    # the result curve follows the real trace to its CL tolerance
    real = path.at(q)
    real[:, 2] += cubic_dz(q)
    assert rec.curve.invert(real).distance.max() < 2e-3
    assert np.allclose(rec.samples[:, 1], cubic_dz(s), atol=1e-12)
    assert rec.max_mm == pytest.approx(np.abs(cubic_dz(s)).max())
    assert rec.rms_mm == pytest.approx(np.sqrt(np.mean(cubic_dz(s) ** 2)))


def test_all_methods_recover_the_as_made_trace(path):
    part = as_made(2)
    rng = np.random.default_rng(0)
    plan = plan_probes(path, "uniform", PlanParams(count=40))
    pts = plan.points.copy()
    pts[:, 2] = part.true_height(pts[:, :2]) + rng.normal(0, 0.001, len(pts))
    q = np.linspace(0, path.length_mm, 200)
    truth = part.true_height(path.at(q)[:, :2])
    for method in ("interpolate", "approximate", "deviation"):
        rec = reconstruct(path, pts, method, sigma_mm=0.001)
        assert np.abs(rec.height_at_s(q) - truth).max() < 0.006, method
        assert rec.clean.outliers == ()


def test_outliers_rejected_and_clean_data_kept(path):
    part = as_made(4)
    rng = np.random.default_rng(1)
    for count in (8, 12, 25):
        plan = plan_probes(path, "deviation", PlanParams(count=count))
        pts = plan.points.copy()
        pts[:, 2] = part.true_height(pts[:, :2]) + rng.normal(0, 0.001, count)
        assert reconstruct(path, pts, "deviation").clean.outliers == ()
    plan = plan_probes(path, "deviation", PlanParams(count=25))
    pts = plan.points.copy()
    pts[:, 2] = part.true_height(pts[:, :2]) + rng.normal(0, 0.001, 25)
    bad = pts.copy()
    bad[[6, 17], 2] += [0.3, -0.15]  # a chip and a probe dip
    shuffled = rng.permutation(25)
    rec = reconstruct(path, bad[shuffled], "deviation")
    assert sorted(shuffled[list(rec.clean.outliers)].tolist()) == [6, 17]
    clean = reconstruct(path, pts, "deviation")
    q = np.linspace(0, path.length_mm, 100)
    assert np.abs(rec.height_at_s(q) - clean.height_at_s(q)).max() < 0.01


def test_duplicates_merged_or_refused(path):
    s = np.linspace(0, path.length_mm, 7)
    pts = measure(path, s, cubic_dz)
    twice = np.concatenate([pts, pts[[3]] + [0, 0, 0.002]])
    rec = reconstruct(path, twice, "interpolate")
    assert rec.clean.merged == 1 and len(rec.clean.s) == 7
    assert rec.clean.dz[3] == pytest.approx(cubic_dz(s[3]) + 0.001)
    params = ReconstructParams(preprocess=PreprocessParams(duplicates="error"))
    with pytest.raises(ReconstructionError) as info:
        reconstruct(path, twice, "interpolate", params=params)
    assert info.value.field == "points[7]"


@pytest.mark.parametrize("case", ["nan", "few", "off", "method", "shape", "sigma"])
def test_bad_input_is_a_typed_422(path, case):
    pts = measure(path, np.linspace(0, path.length_mm, 6), cubic_dz)
    method, sigma = "interpolate", None
    if case == "nan":
        pts[2, 1] = np.nan
    elif case == "few":
        pts = pts[:3]
    elif case == "off":
        pts[4, 0] += 3.0
    elif case == "method":
        method = "magic"
    elif case == "shape":
        pts = pts[:, :2]
    else:
        sigma = -1.0
    with pytest.raises(ReconstructionError) as info:
        reconstruct(path, pts, method, sigma_mm=sigma)
    assert http_status(info.value)[0] == 422 and info.value.field
    if case in ("nan", "off"):
        assert info.value.field == ("points[2]" if case == "nan" else "points[4]")


def test_api_result_round_trips(path):
    pts = measure(path, np.linspace(0, path.length_mm, 8), cubic_dz)
    result = reconstruct(path, pts, "deviation").to_result()
    curve = NurbsCurve.from_dict(result["curve"])
    assert curve.evaluate([0.0, 1.0]).shape == (2, 3)
    assert len(result["deviation"]["samples"]) == 8
    assert set(result["deviation"]) == {"max_mm", "rms_mm", "samples"}


def test_kriging_passes_through_noise_free_points_and_recovers_placement(path):
    from app.reference.s1 import centred_placement
    s = np.linspace(0, path.length_mm, 8)
    pts = measure(path, s, cubic_dz)
    rec = reconstruct(path, pts, "kriging", sigma_mm=0.0)
    assert rec.method == "kriging"
    assert np.abs(rec.height_at_xy(pts[:, :2]) - pts[:, 2]).max() < 1e-5
    assert rec.to_result()["curve"]["degree"] == 3
    # a placed part without machining error: the CAD slopes carry the whole deviation
    part = as_made(4, amplitude_mm=1e-12, placement=centred_placement(0.09, -0.07, 0.02, 0.18))
    s = np.linspace(0, path.length_mm, 6)
    pts = path.at(s)
    pts[:, 2] = part.true_height(pts[:, :2])
    truth = part.true_height(path.points[:, :2])
    err = np.abs(reconstruct(path, pts, "kriging", sigma_mm=0.0).height_at_s(path.s) - truth)
    spline = reconstruct(path, pts, "deviation", sigma_mm=0.0).height_at_s(path.s) - truth
    assert err.max() < 1.2e-3 and err.max() < 0.5 * np.abs(spline).max()
