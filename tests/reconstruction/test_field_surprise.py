"""Surprise by spot: each station predicted with its re-touches left out, and the gap points
it places reading a step at a trace's end that the one-touch-at-a-time residuals hide."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from app.geometry.traces import TracePolyline
from app.probing.deviation_prior import Sites, path_sites
from app.probing.field import plan_field
from app.probing.field_verify import GAP_FRACTION, with_sequential_verification
from app.probing.selection import PlanParams
from app.reconstruction.field import fit_field
from app.reconstruction.field_learning import loo_check, touch_precision
from app.reconstruction.field_surprise import spot_residuals, surprise

NOISE_MM = 0.001
COVERAGE = PlanParams().coverage
# a short-wavelength prior (the learned prior of a 10-15 mm part): the fit's band between stations is wide
PRIOR = PlanParams(deviation_amplitude_mm=0.3, deviation_wavelength_mm=12.0).prior()
CENTER = np.array([30.0, 20.0])
LINE = TracePolyline.from_points(np.column_stack([np.full(81, 30.0), np.linspace(4.0, 36.0, 81), np.zeros(81)]))
# stations every 4 mm, each end touched three times (the planner re-touches a trace's ends)
S_MM = np.array([0.0, 0.0, 0.0, 4.0, 8.0, 12.0, 16.0, 20.0, 24.0, 28.0, 32.0, 32.0, 32.0])


def stepped(xy: np.ndarray) -> np.ndarray:
    """The truth (m,) mm at xy (m, 2): a smooth 25 mm wave, and the part 20 um higher everywhere
    along the trace but at its two ends (a step whose edge runs through the trace's end points)."""
    return 0.05 * np.sin(2 * np.pi * xy[:, 1] / 25.0) + 0.02 * ((xy[:, 1] > 4.0) & (xy[:, 1] < 36.0))


def touched() -> tuple[Sites, np.ndarray]:
    sites = path_sites(LINE, S_MM)
    return sites, stepped(sites.xy) + np.random.default_rng(3).normal(0.0, NOISE_MM, len(S_MM))


def test_a_spot_alone_is_its_leave_one_out_and_a_spot_is_predicted_by_the_rest_only():
    """Singletons: the exact leave-one-out residual and sd; a re-touched spot: the Gaussian
    conditional of the spot's touches given every other touch (an independent formula: the
    covariance's blocks, not the precision's)."""
    sites, dz = touched()
    residual, sd = spot_residuals(PRIOR, sites, dz, CENTER)
    loo = loo_check(PRIOR, sites, dz, CENTER)
    alone = slice(3, 10)
    assert np.allclose(residual[alone], loo.residual_mm[alone]) and np.allclose(sd[alone], loo.sd_mm[alone])
    k = np.linalg.inv(touch_precision(PRIOR, sites, CENTER))
    spot, rest = np.arange(3), np.arange(3, len(dz))
    gain = k[np.ix_(spot, rest)] @ np.linalg.inv(k[np.ix_(rest, rest)])
    assert np.allclose(residual[spot], dz[spot] - gain @ dz[rest])
    assert np.allclose(sd[spot] ** 2, np.diag(k[np.ix_(spot, spot)] - gain @ k[np.ix_(rest, spot)]))
    # the re-touches predict each other: one at a time the ends read their noise (a few um), by spot
    # the step (over 40 um: the fit's trend over the gap and the step), more than any station between
    ends = np.r_[0:3, 10:13]
    assert np.abs(loo.residual_mm[ends]).max() < 5 * NOISE_MM < 0.04 < np.abs(residual[ends]).min()
    assert np.abs(residual[ends]).min() > np.abs(residual[3:10]).max()


def test_a_step_along_a_traces_end_is_read_by_a_gap_point_beside_the_end():
    """The step's edge runs through the trace's re-touched end points: the fit follows the end
    stations down and misses the part beside them by nearly the step's 20 um.  The gap points
    beside the stations the others predict worst (by spot) lie a quarter of the gap from the
    ends, and one reads the step outside COVERAGE x its predictive sd; a point midway in any gap
    (where the posterior is least certain) reads it within the band."""
    sites, dz = touched()
    trace = np.zeros(len(S_MM), dtype=int)
    plan = plan_field([LINE], PlanParams())
    empty = replace(plan, xy=plan.xy[:0], z=plan.z[:0], grad=plan.grad[:0], trace=plan.trace[:0],
                    s_mm=plan.s_mm[:0], order=plan.order[:0])
    fit = fit_field(PRIOR, sites, np.zeros(len(S_MM)), np.column_stack([sites.xy, dz]), CENTER, trace, S_MM)
    dense = path_sites(LINE, np.linspace(0.0, LINE.s[-1], 321))
    assert np.abs(stepped(dense.xy) - fit.deviation(dense)).max() > 0.015   # the step the fit does not hold

    def read(points) -> np.ndarray:
        at = Sites(points.xy, points.grad)
        sd = np.sqrt(fit.posterior.sd(at) ** 2 + NOISE_MM ** 2)
        out: np.ndarray = np.abs(stepped(points.xy) - fit.deviation(at)) / sd
        return out
    points = with_sequential_verification(empty, sites, [LINE], PRIOR, 5, surprise(PRIOR, sites, dz, CENTER,
                                                                                   trace, S_MM))
    for end in (0.0, 32.0):                                                # beside both ends
        assert np.isclose(np.abs(points.s_mm - end), GAP_FRACTION * 4.0).any()
    assert read(points).max() > COVERAGE                                   # the step read: not verified
    gaps = np.unique(S_MM)
    midway = path_sites(LINE, (gaps[:-1] + gaps[1:]) / 2)                  # every gap's middle reads within
    assert read(replace(points, xy=midway.xy, grad=midway.grad)).max() < COVERAGE
