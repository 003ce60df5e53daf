"""Small shared fixtures for the jetting tests: a QP on a little part with active flow."""

import numpy as np

from app.jetting.controller import build_qp
from app.jetting.flow import mobility_map
from app.jetting.kernel import drop_kernel
from app.jetting.params import ControllerParams, DropParams, FlowParams
from app.jetting.targets import target_from_mask


def small_qp(dpi=600.0, horizon=1, seed=0, model="transport", size=14, steps=2):
    drop = DropParams(dpi=dpi)
    mask = np.ones((size, size), dtype=bool)
    mask[5:8, 5:9] = False
    target = target_from_mask(mask, drop, margin_mm=0.1)
    rng = np.random.default_rng(seed)
    layer = 30
    heights = target.mask * (layer * drop.layer_mm * (0.8 + 0.1 * rng.random(target.shape)))
    flow = FlowParams(threshold_um=1.0, flow_steps=steps)
    ctrl = ControllerParams(horizon=horizon, model=model, r_weight=1e-2, q_weight=0.5, edge_lead=0.0)  # flat reference
    qp = build_qp(heights, target, 0.8 * target.mask, drop_kernel(drop), drop, flow,
                  mobility_map(np.zeros(target.shape), flow), ctrl, layer)
    return qp, target
