import numpy as np
import pytest

from app.jetting.metrics import surface_metrics
from app.jetting.params import DropParams
from app.jetting.targets import target_from_mask


def test_flat_part_has_zero_roughness_and_no_collapse():
    target = target_from_mask(np.ones((20, 20), dtype=bool), DropParams())
    m = surface_metrics(target.mask * 0.1, target, 0.1)
    assert m.sa_um == m.sz_um == m.rmse_um == 0.0
    assert m.edge_collapse_um == 0.0 and m.mean_height_um == pytest.approx(100.0)


def test_analytic_two_level_surface_and_edge_drop():
    target = target_from_mask(np.ones((20, 20), dtype=bool), DropParams())
    h = target.mask * 0.1
    h[target.outer_edge] = 0.09  # the rim is 10 um low
    m = surface_metrics(h, target, 0.1)
    n, k = target.mask.sum(), target.outer_edge.sum()
    p = k / n  # fraction of low cells: deviations are (1-p)*10 and p*10 um
    assert m.sa_um == pytest.approx(2 * p * (1 - p) * 10.0)
    assert m.rmse_um == pytest.approx(np.sqrt(p * (1 - p)) * 10.0)
    assert m.sz_um == pytest.approx(10.0)
    assert m.edge_collapse_outer_um == pytest.approx(10.0)
    assert m.edge_collapse_hole_um == 0.0
