"""The layer controller's reference: the published flat one and the edge-aware target (a lead
on the rings of cells along the part's edges), and what the lead buys early in a run."""

import numpy as np
import pytest

from app.jetting import (
    ControllerParams,
    DropParams,
    FlowParams,
    JettingError,
    JettingParams,
    PlantParams,
    TargetSpec,
    drop_kernel,
    simulate,
    target_from_mask,
)
from app.jetting.controller import edge_lead_map, lead_ramp, mpc_layer, references, validate_controller
from app.jetting.flow import mobility_map

DROP = DropParams()


def square_with_hole():
    """A 20 x 20 cell part with a 4 x 4 cell hole whose corner is at (8, 8)."""
    mask = np.ones((20, 20), dtype=bool)
    mask[8:12, 8:12] = False
    return target_from_mask(mask, DROP, margin_mm=0.0)


def ring_of(target):
    """Taxicab distance (cells) of each part cell to the nearest cell off the part, by brute force."""
    part = np.argwhere(target.mask)
    off = np.argwhere(~target.mask)
    dist = np.abs(part[:, None, :] - off[None, :, :]).sum(axis=2).min(axis=1)
    out = np.zeros(target.shape, dtype=int)
    out[tuple(part.T)] = dist
    return out


def test_the_lead_tapers_over_the_rings_of_outer_and_hole_edges():
    target = square_with_hole()
    ctrl = ControllerParams(edge_lead=8.0, edge_rings=4)
    lead = edge_lead_map(target, ctrl)
    ring = ring_of(target)
    for k in range(1, 5):  # edge cells (k = 1) carry 8, then 6, 4, 2 nominal layer heights
        assert np.allclose(lead[target.mask & (ring == k)], 8.0 * (5 - k) / 4)
    assert np.all(lead[target.mask & (ring > 4)] == 0.0) and np.all(lead[~target.mask] == 0.0)
    assert np.all(lead[target.hole_edge] == 8.0) and np.all(lead[target.outer_edge] == 8.0)
    assert not edge_lead_map(target, ControllerParams(edge_lead=0.0)).any()
    assert not edge_lead_map(target, ControllerParams(edge_rings=0)).any()


@pytest.mark.parametrize("horizon", [1, 3])
def test_references_are_the_published_ramp_plus_the_lead(horizon):
    target = square_with_hole()
    t = DROP.layer_mm
    flat = references(target, DROP, ControllerParams(horizon=horizon, fill=0.8, edge_lead=0.0), 10)
    for i in range(horizon):  # r_(l+i) = (l + i) * fill * t on the part, 0 off it
        assert np.allclose(flat[i], (11 + i) * 0.8 * t * target.mask)
    ctrl = ControllerParams(horizon=horizon, fill=0.8)
    lead = references(target, DROP, ctrl, 10) - flat
    assert np.allclose(lead, edge_lead_map(target, ctrl)[None] * t)  # the same lead at every step


def test_the_lead_comes_in_between_one_and_two_flow_thresholds_of_level():
    target = square_with_hole()
    t, tau = DROP.layer_mm, 3e-3
    ctrl = ControllerParams(fill=0.8)
    full = edge_lead_map(target, ctrl) * t
    for layer in range(0, 12):  # levels 0.67 .. 8.7 um: no lead up to 3 um, all of it from 6 um
        level = (layer + 1) * 0.8 * t
        share = min(max(level / tau - 1.0, 0.0), 1.0)
        lead = references(target, DROP, ctrl, layer, tau)[0] - level * target.mask
        assert np.allclose(lead, share * full, atol=1e-15)
    assert lead_ramp(np.array([0.0, 3e-3, 4.5e-3, 6e-3, 1.0]), tau) == pytest.approx([0.0, 0.0, 0.5, 1.0, 1.0])
    assert lead_ramp(np.array([0.0, 1.0]), 0.0) == pytest.approx([1.0, 1.0])


def test_on_a_part_at_its_level_only_the_edge_rings_are_jetted():
    """The part stands exactly at the next reference level: the published MPC jets (almost)
    nothing, the edge-aware one jets the rings its lead raises and nothing farther in."""
    target = square_with_hole()
    flow = FlowParams()
    layer = 10  # level 9.2 um: above two flow thresholds, all of the lead
    args = (target, drop_kernel(DROP), DROP, flow, mobility_map(np.zeros(target.shape), flow))
    measured = (layer + 1) * 0.8 * DROP.layer_mm * target.mask
    published = mpc_layer(measured, *args, ControllerParams(edge_lead=0.0), layer)
    edge = mpc_layer(measured, *args, ControllerParams(), layer)
    ring = ring_of(target)
    assert published.pattern.sum() <= 0.05 * target.mask.sum()
    assert edge.pattern[target.mask & (ring >= 2) & (ring <= 4)].all()
    assert edge.pattern[target.mask & (ring == 1)].mean() >= 0.9  # (the outer corners drain two ways)
    assert not edge.pattern[target.mask & (ring > 4)].any() and not edge.pattern[~target.mask].any()
    assert edge.level_mm == published.level_mm == pytest.approx((layer + 1) * 0.8 * DROP.layer_mm)
    assert edge.reference_mm[target.outer_edge] == pytest.approx(edge.level_mm + 8.0 * DROP.layer_mm)


def test_bad_lead_settings_are_refused_by_name():
    for ctrl, name in ((ControllerParams(edge_lead=-1.0), "controller.edge_lead"),
                       (ControllerParams(edge_lead=float("nan")), "controller.edge_lead"),
                       (ControllerParams(edge_rings=-1), "controller.edge_rings")):
        with pytest.raises(JettingError) as err:
            validate_controller(ctrl)
        assert err.value.field == name


def test_the_edge_aware_target_holds_the_early_gain():
    """A 3 mm square with a 1 mm hole, 6 % nozzle spread, 80 layers: from layer 60 on the
    edge-aware MPC's Sa is >= 10 % lower than the published MPC's, its edge collapse lower,
    and both far below open loop (the full case: tests/bench/test_bench_jetting.py)."""
    def run(**ctrl):
        return simulate(JettingParams(layers=80, target=TargetSpec(size_mm=3.0, hole_mm=1.0),
                                      plant=PlantParams(nozzle_spread=0.06, seed=3),
                                      controller=ControllerParams(**ctrl)))

    open_loop, published, edge = run(kind="open_loop"), run(edge_lead=0.0), run()
    for o, p, e in list(zip(open_loop.layers, published.layers, edge.layers))[59:]:
        assert e.metrics.sa_um <= 0.9 * p.metrics.sa_um, e.layer
        assert e.metrics.edge_collapse_um < p.metrics.edge_collapse_um < o.metrics.edge_collapse_um
        assert o.metrics.sa_um >= 2.0 * e.metrics.sa_um
    # the lead brings the edges up; the part still rises at its reference level (fill per layer)
    m = edge.final.metrics
    assert m.mean_height_um == pytest.approx(m.target_height_um, rel=0.03)
    assert published.final.metrics.mean_height_um < m.mean_height_um
