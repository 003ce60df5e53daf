import io

import numpy as np
import pytest
from PIL import Image

from app.jetting.errors import JettingError
from app.jetting.params import DropParams, TargetSpec
from app.jetting.targets import (
    rings_grid_cells,
    target_from_mask,
    target_from_png,
    target_from_rings,
    target_from_spec,
    target_pad_cells,
    target_shape,
)
from app.platform.problems import http_status

DROP = DropParams()


def png(mask):
    out = io.BytesIO()
    Image.fromarray(np.asarray(mask, dtype=np.uint8) * 255).save(out, format="PNG")
    return out.getvalue()


def test_seed_square_with_hole_cells_and_edges():
    t = target_from_spec(TargetSpec(size_mm=10, hole_mm=4), DROP)
    n_out = int(10 / DROP.pitch_mm)  # 118 whole cells of 84.7 um
    hole = TargetSpec(size_mm=10, hole_mm=4).hole_mm / DROP.pitch_mm
    assert t.mask.sum() == pytest.approx(n_out**2 - hole**2, abs=4 * hole + 4)
    assert t.outer_edge.sum() == 4 * n_out - 4
    assert 4 * int(hole) - 4 <= t.hole_edge.sum() <= 4 * int(hole) + 8
    assert not (t.interior & (t.outer_edge | t.hole_edge)).any()
    assert not t.mask[0].any() and not t.mask[:, -1].any()  # margin around the part


def test_rings_area_matches_shapely_area():
    theta = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    disc = np.c_[3 * np.cos(theta), 3 * np.sin(theta)]
    t = target_from_rings([disc, disc / 3], DROP)
    area = t.mask.sum() * DROP.pitch_mm**2
    exact = np.pi * (9 - 1)
    assert area == pytest.approx(exact, rel=0.02)
    assert t.hole_edge.any()


def test_png_mask_round_trip():
    mask = np.zeros((30, 40), dtype=bool)
    mask[5:25, 8:30] = True
    mask[10:15, 12:20] = False
    t = target_from_png(png(mask), DROP)
    rows, cols = np.nonzero(t.mask)
    np.testing.assert_array_equal(t.mask[rows.min():rows.max() + 1, cols.min():cols.max() + 1],
                                  mask[5:25, 8:30])


@pytest.mark.parametrize("data, field", [
    (b"", "target.mask"),
    (b"not an image", "target.mask"),
])
def test_bad_mask_bytes(data, field):
    with pytest.raises(JettingError) as err:
        target_from_png(data, DROP)
    assert err.value.field == field and http_status(err.value)[0] == 422


def test_all_black_mask_is_rejected():
    with pytest.raises(JettingError) as err:
        target_from_png(png(np.zeros((10, 10))), DROP)
    assert err.value.field == "target.mask"


def test_drop_larger_than_part_is_rejected():
    with pytest.raises(JettingError) as err:
        target_from_mask(np.ones((2, 30), dtype=bool), DropParams(drop_diameter_um=200))
    assert err.value.field == "drop.drop_diameter_um" and err.value.value == 200


def test_resolution_over_the_cell_limit_is_rejected_before_allocation():
    with pytest.raises(JettingError) as err:
        target_from_spec(TargetSpec(size_mm=50, hole_mm=0), DropParams(dpi=100_000))
    assert err.value.field == "drop.dpi"


def test_bad_rings():
    with pytest.raises(JettingError):
        target_from_rings([np.array([[0, 0], [1, 1]])], DROP)
    with pytest.raises(JettingError):
        target_from_rings([], DROP)


@pytest.mark.parametrize(("dpi", "diameter_um", "margin_mm"), [
    (300.0, 60.0, 0.25), (300.0, 60.0, 0.0), (600.0, 200.0, 0.05), (150.0, 300.0, 2.0)])
def test_target_shape_is_the_shape_target_from_mask_builds(dpi: float, diameter_um: float, margin_mm: float) -> None:
    drop = DropParams(dpi=dpi, drop_diameter_um=diameter_um)
    mask = np.zeros((40, 30), dtype=bool)
    mask[5:31, 3:25] = True  # a 26 x 22 cell part inside an empty border, which is cropped
    pad = target_pad_cells(drop, margin_mm)
    assert pad >= int(np.ceil(margin_mm / drop.pitch_mm))
    assert pad >= int(np.ceil(drop.radius_mm / drop.pitch_mm + 0.5)) + 2  # kernel radius + 3
    assert target_from_mask(mask, drop, margin_mm).shape == target_shape((26, 22), drop, margin_mm)
    assert target_shape((26, 22), drop, margin_mm) == (26 + 2 * pad, 22 + 2 * pad)


def test_rings_grid_cells_is_the_grid_target_from_rings_rasterises() -> None:
    p = DROP.pitch_mm
    assert rings_grid_cells((10 * p, 4.5 * p), p) == (10, 5)
    assert rings_grid_cells((0.0, 0.1 * p), p) == (1, 1)
    ring = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 2.0], [0.0, 2.0]])
    nx, ny = rings_grid_cells((3.0, 2.0), p)
    built = target_from_rings([ring], DROP, 0.25).shape
    bound = target_shape((ny, nx), DROP, 0.25)  # rows are y
    # the grid bounds the target; a last cell whose centre falls outside the rings is cropped
    assert bound[0] - 1 <= built[0] <= bound[0] and bound[1] - 1 <= built[1] <= bound[1]
