"""The run report of a field loop: the fitted hyperparameters with their uncertainty, every
verification residual in a table and on a map of the part, and what the operator can do about
a misfit."""

from __future__ import annotations

import re

from app.reporting.collect import RunRecords
from app.reporting.html import render_run_report
from tests.helpers.residuals import VERDICT


def _learned() -> dict:
    def parameter(value: float, told: float, sd: float | None) -> dict:
        return {"value": value, "prior": told, "relative_sd": sd, "at_bound": None}
    return {"amplitude_mm": parameter(0.137, 0.2, 0.21), "wavelength_mm": parameter(13.2, 20.0, 0.08),
            "sigma_mm": parameter(0.0011, 0.001, None), "touches": 34, "log_likelihood": 120.0,
            "prior_log_likelihood": 95.0, "loo": {"statistic": 1.9, "statistic_limit": 1.6, "max_abs_z": 3.1,
                                                   "z_limit": 3.4, "misfit": True, "reasons": ["mean z² 1.9"]}}


def _report(verdict: dict) -> str:
    root = {"id": "job_loop", "kind": "closed_loop", "status": "needs_attention", "created_at": "t0",
            "started_at": "t0",
            "finished_at": "t1", "result": {"traces": [], "table": [], "verdict": verdict, "needs_attention": True}}
    return render_run_report(RunRecords(root, jobs=[root]), "test")


def test_the_report_shows_hyperparameters_residual_table_map_and_actions():
    verdict = {**VERDICT, "needs_attention": True, "reasons": ["the field model misfits the touches: mean z² 1.9"],
               "verified": "NOT verified at 3 points", "bound_mm": 0.007, "learned": _learned(), "exclusions": []}
    text = _report(verdict)
    # the fitted hyperparameters with their uncertainty (relative sd as a percentage; none at a bound)
    assert "13.2" in text and "± 8 %" in text and "± 21 %" in text and "uncertainty (1 sd)" in text
    # every residual in the table, in µm
    for p in VERDICT["verification"]:
        assert f"{p['residual_mm'] * 1000:.2f}" in text
    # the map: one dot per verification point, coloured, the flagged ones ringed, with its legend
    svg = re.search(r'<svg id="residual-map".*?</svg>', text, re.S)
    assert svg is not None
    dots = re.findall(r'<circle [^>]*stroke-width="(\d)"', svg.group(0))
    assert dots == ["1", "3", "3"]                                  # points 2 and 3 are flagged
    assert "-8.0 µm" in svg.group(0) and "+8.0 µm" in svg.group(0)  # the symmetric legend
    assert "residual +2.0 µm" in svg.group(0) and "residual -8.0 µm" in svg.group(0)
    # what the operator can do about the misfit (the loop named no action of its own)
    actions = re.search(r'<p id="misfit-actions">(.*?)</p>', text, re.S)
    assert actions is not None and "add stations and refit" in actions.group(1)


def test_the_loops_own_actions_are_shown_when_it_names_them():
    verdict = {**VERDICT, "needs_attention": True, "reasons": ["x"], "learned": None, "exclusions": [],
               "actions": ["run the loop again with probe = suggested_probe"]}
    text = _report(verdict)
    assert "run the loop again with probe = suggested_probe" in text and 'id="residual-map"' in text
