"""The Bessel tables against scipy.special (the independent reference), and the field plan
they give against the plan with scipy's own j1 in the kernel."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import j0, j1

from app.probing import deviation_prior as dp
from app.probing.bessel_table import STEP, TABLE_END, bessel_j0, jinc
from app.probing.field import plan_field
from app.probing.selection import PlanParams
from app.reference.s1 import nominal_path, s1_traces


def _scipy_jinc(x: np.ndarray) -> np.ndarray:
    safe = np.where(x == 0.0, 1.0, x)
    out: np.ndarray = np.where(x == 0.0, 1.0, 2.0 * j1(safe) / safe)
    return out


def _whole_table() -> np.ndarray:
    """Every node, every cell's middle and quarter points, and random points of [0, TABLE_END)."""
    nodes = np.arange(int(TABLE_END / STEP)) * STEP
    inside = (nodes[:, None] + STEP * np.array([0.0, 0.25, 0.5, 0.75])).ravel()
    return np.concatenate([inside, np.random.default_rng(3).uniform(0.0, TABLE_END, 400_000),
                           [1e-12, 1e-7, 1e-6, 2e-6, TABLE_END - 1e-9]])


def test_jinc_from_its_table_is_within_1e_12_of_scipys_j1_over_the_whole_table():
    x = _whole_table()
    err = np.abs(jinc(x) - _scipy_jinc(x))
    assert err.max() <= 1e-12
    assert err.max() < 1e-14   # the interpolant's own bound, 4.8e-15, beside the nodes' rounding


def test_j0_from_its_table_is_within_1e_12_of_scipys_j0_over_the_whole_table():
    x = _whole_table()
    err = np.abs(bessel_j0(x) - j0(x))
    assert err.max() <= 1e-12
    assert err.max() < 3e-14   # the interpolant's own bound, 1.5e-14, beside the nodes' rounding


def test_the_tables_are_exact_at_zero_and_scipys_own_where_they_do_not_reach():
    assert jinc(np.zeros(3)).tolist() == [1.0, 1.0, 1.0] and bessel_j0(np.zeros(2)).tolist() == [1.0, 1.0]
    far = np.array([TABLE_END, TABLE_END + 0.3, 1e3, 1e6])
    assert np.array_equal(jinc(far), 2.0 * j1(far) / far) and np.array_equal(bessel_j0(far), j0(far))
    got = jinc(np.array([np.nan, -2.5]))   # NaN stays NaN; jinc is even
    assert math.isnan(got[0]) and got[1] == _scipy_jinc(np.array([2.5]))[0]


def test_the_tables_keep_the_shape_and_write_into_out():
    x = np.random.default_rng(4).uniform(0.0, 40.0, (7, 9))
    out = np.empty((7, 9))
    assert jinc(x, out=out) is out and np.array_equal(out, jinc(x.ravel()).reshape(7, 9))
    assert bessel_j0(x).shape == (7, 9)


def _scipy_jinc_kernel(a: np.ndarray, b: np.ndarray, wavelength_mm: float, block_elements: int = 0) -> np.ndarray:
    """The kernel with scipy's j1 (the reference the table replaces)."""
    x = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1]) * (2 * math.pi / wavelength_mm)
    return _scipy_jinc(x)


@pytest.mark.parametrize("params", [PlanParams(deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0),
                                    PlanParams(deviation_amplitude_mm=0.3, deviation_wavelength_mm=8.0,
                                               target_error_mm=0.004)])
def test_the_field_plan_with_the_table_is_the_plan_with_scipys_j1(params, monkeypatch):
    paths = [nominal_path(t, 0.05) for t in s1_traces()]
    table = plan_field(paths, params)
    for module in ("app.probing.field", "app.probing.field_reuse", "app.probing.field_exchange"):
        monkeypatch.setattr(f"{module}.jinc_kernel", _scipy_jinc_kernel)
    monkeypatch.setattr(dp, "jinc_kernel", _scipy_jinc_kernel)
    scipy_plan = plan_field(paths, params)
    assert np.array_equal(table.xy, scipy_plan.xy) and np.array_equal(table.order, scipy_plan.order)
    assert table.max_sd_mm == pytest.approx(scipy_plan.max_sd_mm, rel=5e-8)
    # the sd is a small difference of the prior and the explained variance through K^-1 (noise
    # 1e-6 mm^2 beside rms^2 2.5e-3): it carries a kernel's last bits at ~1e-8 relative (the
    # distance by sqrt(dx^2 + dy^2) instead of hypot moves these plans' sd by 2.6e-9 and 1.1e-8)
    assert np.allclose(table.trace_sd_mm, scipy_plan.trace_sd_mm, rtol=5e-8, atol=0.0)
