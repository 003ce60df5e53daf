"""Measured points for a surface fit: the CSV parser and the pre-fit checks."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.reconstruction.surface_fit import SurfaceFitError, SurfaceFitParams
from app.reconstruction.surface_fit.points import check_points, parse_points_csv, points_needed


def test_csv_with_header_comments_and_mixed_separators() -> None:
    text = "x, y, z\n# probe run 3\n\n0, 0, 1.5\n1;0;2.5\n 0 1\t-3e-1 \n"
    np.testing.assert_array_equal(parse_points_csv(text), [[0, 0, 1.5], [1, 0, 2.5], [0, 1, -0.3]])


@pytest.mark.parametrize(("text", "needle"), [
    ("x,y,z\n1,2,3\n1,2\n", "line 3"),
    ("1,2,nan\n", "finite"),
    ("1,2,3\nx,y,z\n", "line 2"),          # a header only before the first point
    ("x,y,z\nu,v,w\n", "line 2"),          # and only one
    ("# nothing\n\n", "no points"),
    ("1,2,3,4\n", "line 1"),
])
def test_bad_csv_names_the_line_and_the_field(text: str, needle: str) -> None:
    with pytest.raises(SurfaceFitError, match=needle) as info:
        parse_points_csv(text)
    assert info.value.field == "points_csv"


def test_csv_point_limit() -> None:
    text = "".join(f"{i}, 0, 0\n" for i in range(4))
    assert parse_points_csv(text, max_points=4).shape == (4, 3)
    with pytest.raises(SurfaceFitError, match="more than 3 points"):
        parse_points_csv(text, max_points=3)


@settings(max_examples=300, deadline=None)
@given(st.text())
def test_arbitrary_text_parses_or_raises_the_typed_error(text: str) -> None:
    try:
        points = parse_points_csv(text, max_points=50)
    except SurfaceFitError as exc:
        assert exc.field == "points_csv"
    else:
        assert points.ndim == 2 and points.shape[1] == 3 and 1 <= points.shape[0] <= 50
        assert np.isfinite(points).all()


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(finite, finite, finite), min_size=1, max_size=30),
       st.sampled_from([", ", ";", " ", "\t", " ; "]), st.booleans())
def test_round_trip_of_formatted_points(rows: list[tuple[float, float, float]], sep: str, header: bool) -> None:
    text = ("x,y,z\n" if header else "") + "\n".join(sep.join(repr(v) for v in row) for row in rows)
    np.testing.assert_array_equal(parse_points_csv(text), np.array(rows, dtype=float))


def _grid_points(n: int) -> np.ndarray:
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float), indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), (x * y).ravel()])


def test_points_needed_counts_the_patch_unknowns() -> None:
    assert points_needed(SurfaceFitParams(degree=3, remove_bad_points=False)) == 16
    assert points_needed(SurfaceFitParams(degree=3, remove_bad_points=True)) == 32
    assert points_needed(SurfaceFitParams(degree=1, remove_bad_points=False)) == 4


def test_enough_spread_points_pass() -> None:
    check_points(_grid_points(6), SurfaceFitParams(degree=3, remove_bad_points=True))  # 36 >= 32


def test_too_few_distinct_positions() -> None:
    points = np.vstack([_grid_points(4)] * 3)  # 48 points, 16 positions
    check_points(points, SurfaceFitParams(degree=3, remove_bad_points=False))
    with pytest.raises(SurfaceFitError, match="16 distinct .* at least 32") as info:
        check_points(points, SurfaceFitParams(degree=3, remove_bad_points=True))
    assert info.value.field == "points"


def test_points_on_one_line_span_no_area() -> None:
    t = np.linspace(0.0, 10.0, 40)
    points = np.column_stack([t, 2.0 * t + 1.0, np.sin(t)])
    with pytest.raises(SurfaceFitError, match="one line") as info:
        check_points(points, SurfaceFitParams(degree=3))
    assert info.value.field == "points"


def test_repeated_positions_cannot_be_resampled() -> None:
    points = np.vstack([_grid_points(6), [[0.0, 0.0, 9.0]]])
    check_points(points, SurfaceFitParams(degree=3))
    with pytest.raises(SurfaceFitError, match="1 points repeat") as info:
        check_points(points, SurfaceFitParams(degree=3, resample_shape=(6, 6)))
    assert info.value.field == "points"


@pytest.mark.parametrize("points", [np.zeros((0, 3)), np.zeros((5, 2)), np.array([[0.0, 0.0, np.inf]])])
def test_malformed_arrays_are_the_typed_error(points: np.ndarray) -> None:
    with pytest.raises(SurfaceFitError) as info:
        check_points(points, SurfaceFitParams())
    assert info.value.field == "points"
