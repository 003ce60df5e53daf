"""Evaluation: standoff along deposited moves on analytic surfaces, the width model's
shape and calibration against the seed's Table 1 magnitudes, table rows."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.platform.problems import http_status
from app.reference import s1
from app.reference.evaluation import (
    EvaluationError,
    LineWidthModel,
    evaluate_deposition,
    format_table,
    predicted_width,
    table_row,
)


def plane(a: float = 0.0, b: float = 0.0, c: float = 1.0):
    return lambda xy: c + a * xy[:, 0] + b * xy[:, 1]


def test_flat_surface_constant_standoff():
    moves = np.array([[[0, 0, 1.1], [5, 0, 1.1]], [[5, 0, 1.1], [5, 3, 1.1]]], float)
    rep = evaluate_deposition(moves, plane(), 0.1, sample_mm=0.5)
    np.testing.assert_allclose(rep.standoff_mm, 0.1, atol=1e-12)
    assert rep.max_abs_error_mm < 1e-12 and rep.rms_error_mm < 1e-12
    assert rep.length_mm == pytest.approx(8.0)
    assert rep.s_mm[-1] == pytest.approx(8.0) and rep.weight_mm.sum() == pytest.approx(8.0)
    assert np.all(np.diff(rep.s_mm) >= 0)


@settings(max_examples=20, deadline=None)
@given(e1=st.floats(-0.2, 0.2), e2=st.floats(-0.2, 0.2), slope=st.floats(-0.5, 0.5))
def test_linear_standoff_error_on_tilted_plane_matches_closed_form(e1, e2, slope):
    """Surface z = slope x; tip from standoff t + e1 to t + e2 along x in [0, 10]:
    error is linear, max = max|e|, rms^2 = (e1^2 + e1 e2 + e2^2) / 3 (per unit length)."""
    t = 0.1
    a = [0.0, 2.0, t + e1]
    b = [10.0, 2.0, 10 * slope + t + e2]
    rep = evaluate_deposition(np.array([[a, b]]), plane(slope, 0.0, 0.0), t, sample_mm=0.01)
    assert rep.max_abs_error_mm == pytest.approx(max(abs(e1), abs(e2)), abs=1e-12)
    rms = np.sqrt((e1 ** 2 + e1 * e2 + e2 ** 2) / 3)
    assert rep.rms_error_mm == pytest.approx(rms, abs=2e-5)
    assert rep.mean_error_mm == pytest.approx((e1 + e2) / 2, abs=1e-9)


def test_accepts_deposited_move_objects_and_reports_contact():
    moves = [SimpleNamespace(start=(0, 0, 0.05), end=(4, 0, -0.05), feed_mm_min=300)]
    rep = evaluate_deposition(moves, plane(c=0.0), 0.1, sample_mm=0.001)
    assert rep.contact_mm == pytest.approx(2.0, abs=2e-3)
    assert rep.max_abs_error_mm == pytest.approx(0.15)


def test_off_part_and_bad_input_are_typed_errors():
    def height(xy):
        return np.where(xy[:, 0] < 3, 0.0, np.nan)

    with pytest.raises(EvaluationError) as info:
        evaluate_deposition(np.array([[[0, 0, 0.1], [5, 0, 0.1]]]), height, 0.1)
    assert "not over the part" in info.value.message
    for bad in ([], np.zeros((2, 3)), np.full((1, 2, 3), np.nan)):
        with pytest.raises(EvaluationError):
            evaluate_deposition(bad, plane(), 0.1)
    with pytest.raises(EvaluationError):
        evaluate_deposition(np.zeros((1, 2, 3)), plane(), 0.1)  # zero length
    with pytest.raises(EvaluationError):
        evaluate_deposition(np.array([[[0, 0, 1], [1, 0, 1]]]), plane(), 0.1, sample_mm=0)


def test_width_model_shape():
    m = LineWidthModel()
    h = np.linspace(-0.1, 0.5, 6001)
    w = m.width(h)
    assert m.width(m.nominal_standoff_mm)[0] == pytest.approx(m.nominal_width_mm)
    assert np.all(np.diff(w) <= 1e-12)  # non-increasing
    for join in (m.pile_standoff_mm, m.stretch_standoff_mm, m.break_standoff_mm):
        left, right = m.width(np.array([join - 1e-10, join + 1e-10]))
        assert left == pytest.approx(right, abs=1e-4)  # continuous at every regime join
    assert w.max() == pytest.approx(m.max_width_mm) and np.all(w >= 0)
    assert np.all(m.width(np.array([0.30, 0.4])) == 0.0)  # broken line
    # piling: bead cross-section w h conserved below the pile standoff (above the cap)
    hp = np.array([0.028, 0.029, 0.03])
    wh = m.width(hp) * hp
    np.testing.assert_allclose(wh, wh[-1], rtol=1e-12)
    # normal regime: the seed's compensated widths 421 / 406 / 396 um at 0.08 / 0.10 / 0.11
    ratio = m.width(np.array([0.08, 0.11])) / m.width(0.10)
    np.testing.assert_allclose(ratio, [421.17 / 406.28, 395.99 / 406.28], atol=0.03)


@pytest.mark.parametrize("bad", [{"nominal_width_mm": 0}, {"exponent": float("inf")},
                                 {"pile_standoff_mm": 0.2}, {"max_width_mm": 0.3},
                                 {"process_std_mm": -0.01}])
def test_width_model_validation(bad):
    with pytest.raises(EvaluationError) as info:
        LineWidthModel(**bad)
    assert http_status(info.value)[0] == 422


def test_perfect_standoff_gives_nominal_width_and_process_scatter():
    m = LineWidthModel()
    moves = np.array([[[0, 0, 0.1], [32, 0, 0.1]]], float)
    pred = predicted_width(evaluate_deposition(moves, plane(c=0.0), 0.1), m)
    assert pred.mean_mm == pytest.approx(m.nominal_width_mm)
    assert pred.std_mm == pytest.approx(m.process_std_mm)
    assert pred.standoff_std_mm == pytest.approx(0.0, abs=1e-12)
    assert pred.open_fraction == 0.0


def nominal_report(part, trace, offset_mm: float = 0.0):
    path = s1.nominal_path(trace, 0.2)
    tips = path.points.copy()
    tips[:, 2] += trace.standoff_mm + offset_mm
    return evaluate_deposition(np.stack([tips[:-1], tips[1:]], axis=1), part.true_height,
                               trace.standoff_mm)


def test_calibration_matches_seed_table1_magnitudes():
    """Uncompensated S1 prints (+-0.15 mm machining, 0.03 mm z): widths in the seed's band."""
    part = s1.as_made(seed=0, amplitude_mm=0.15, placement=s1.centred_placement(dz=0.03))
    preds = [predicted_width(nominal_report(part, t)) for t in s1.s1_traces()]
    means = np.array([p.mean_mm for p in preds]) * 1000
    stds = np.array([p.std_mm for p in preds]) * 1000
    assert 370 <= means.min() and means.max() <= 650 and np.median(means) > 420
    assert 60 <= stds.min() and stds.max() <= 130


def test_table_row_and_format():
    part = s1.as_made(seed=0, amplitude_mm=0.15, placement=s1.centred_placement(dz=0.03))
    trace = s1.s1_traces()[0]
    before = nominal_report(part, trace)
    flat = np.array([[[0, 0, 0.08], [32, 0, 0.08]]], float)
    after = evaluate_deposition(flat, plane(c=0.0), 0.08)
    row = table_row(1, before, after, probes=11)
    assert row.standoff_max_before_um == pytest.approx(before.max_abs_error_mm * 1000, abs=0.01)
    assert row.standoff_max_after_um == 0.0 and row.probes == 11
    assert row.width_std_after_um == pytest.approx(70.0)
    text = format_table([row])
    assert len(text.splitlines()) == 2 and "probes" in text
