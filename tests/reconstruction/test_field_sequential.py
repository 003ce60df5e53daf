"""One round's decision of the sequential field planner (:func:`decide_round`): the first round
after the pilot sized by the forecast of the run's bound, a later round that adds stations at
the target the previous one planned for as it is, a round past the touch budget stopped.

The planner and the forecast are analytic stand-ins (a pointwise target t buys ceil(C / t)
stations, n stations give a bound of K / n), so the loosest target within the aim is known in
closed form."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

import app.reconstruction.field_sequential as field_sequential
from app.probing.deviation_prior import DeviationPrior, Sites
from app.probing.selection import PlanParams
from app.reconstruction.field_sequential import bound_aim, decide_round

USER = PlanParams()                      # target 5 um: the aim is TARGET_SLACK x 5 um
STATIONS_MM = 0.05                       # ceil(0.05 mm / t) stations at the pointwise target t: 10 at 5 um
LEARNED = SimpleNamespace(prior=DeviationPrior(amplitude_mm=0.15, wavelength_mm=40.0, sigma_mm=USER.probe_sigma_mm))


def plan(at: PlanParams) -> SimpleNamespace:
    return SimpleNamespace(count=math.ceil(STATIONS_MM / at.target_error_mm - 1e-9))


def forecasting(bound_times_stations_mm: float):
    """A stand-in for :func:`round_forecast`: n more stations give a run's bound of K / n (mm)."""
    def round_forecast(*args, **kwargs):
        return lambda more: bound_times_stations_mm / more.count
    return round_forecast


def decide(first: bool, plan_target_mm: float = USER.target_error_mm):
    empty = np.zeros(0)
    return decide_round(USER, LEARNED, Sites(np.zeros((0, 2)), np.zeros((0, 2))), empty, empty, empty,  # type: ignore[arg-type]
                        np.zeros(2), [], plan, plan_target_mm, 80.0, first=first)  # type: ignore[arg-type]


def test_the_first_round_is_the_fewest_stations_whose_forecast_is_within_the_aim(monkeypatch):
    """10 stations at the user's 5 um target forecast a 4 um bound, inside the 6.25 um aim:
    the first round plans for a looser target and adds fewer stations (the fewest the search
    reaches within its SEARCH_WITHIN bracket), their forecast still within the aim; a later
    round at the same target is not re-sized (10)."""
    monkeypatch.setattr(field_sequential, "round_forecast", forecasting(0.040))
    aim = bound_aim(USER.target_error_mm)
    first = decide(first=True)
    later = decide(first=False)
    assert later.more.count == 10 and later.params.target_error_mm == USER.target_error_mm
    assert math.ceil(0.040 / aim) <= first.more.count < later.more.count
    assert 0.040 / first.more.count <= aim    # the fewer stations still meet the aim
    assert USER.target_error_mm < first.params.target_error_mm < aim
    assert plan(first.params).count == first.more.count   # the stations its target buys
    assert first.stopped is None and first.bound_mm is None


def test_a_first_round_whose_target_misses_the_aim_adds_the_fewest_stations_that_meet_it(monkeypatch):
    """10 stations at the target forecast an 8 um bound, over the aim: the first round adds
    the 13 the aim needs (0.080 / 13 <= 6.25 um < 0.080 / 12), not the target's 10 and a
    second round after them; without a forecast the target's plan as it is."""
    monkeypatch.setattr(field_sequential, "round_forecast", forecasting(0.080))
    aim = bound_aim(USER.target_error_mm)
    over = decide(first=True)
    assert over.more.count == math.ceil(0.080 / aim) == 13
    assert over.params.target_error_mm < USER.target_error_mm
    monkeypatch.setattr(field_sequential, "round_forecast", lambda *args, **kwargs: None)
    unforecast = decide(first=True)
    assert unforecast.more.count == 10 and unforecast.params.target_error_mm == USER.target_error_mm


def test_a_round_past_the_touch_budget_stops_there(monkeypatch):
    monkeypatch.setattr(field_sequential, "round_forecast", forecasting(0.080))
    empty = np.zeros(0)
    decision = decide_round(USER, LEARNED, Sites(np.zeros((0, 2)), np.zeros((0, 2))), empty, empty, empty,  # type: ignore[arg-type]
                            np.zeros(2), [], plan, USER.target_error_mm, 80.0, room=9)  # type: ignore[arg-type]
    assert decision.stopped == "budget" and decision.more.count == 10
