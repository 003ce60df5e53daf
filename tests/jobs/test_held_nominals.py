"""A stored trace's placed nominal is parsed once per process and shared by the jobs after it."""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np
import pytest

from app.geometry.placement import Placement
from app.geometry.traces import TracePolyline
from app.jobs.held_nominals import HELD, held_bytes, held_polyline
from app.jobs.inputs import nominal_of, placed_nominal, placed_nominals
from app.parts.lru import ByteLru
from app.platform.models import Trace
from app.probing.deviation_prior import path_gradient
from app.reference.boards import board_path, board_traces, dome_part
from app.registration.registration import place_path


def _stored(path: TracePolyline, trace_id: str) -> Trace:
    """A trace record as the database returns it (id, created at, the stored nominal)."""
    return Trace(id=trace_id, part_id="part_x", name=trace_id, frame="part", geometry={}, standoff_mm=0.1,
                 length_mm=path.length_mm, z_min=0.0, z_max=1.0, nominal=path.to_dict(),
                 created_at=datetime(2026, 1, 1, tzinfo=UTC))


@pytest.fixture(scope="module")
def paths() -> list[TracePolyline]:
    part = dome_part()
    return [board_path(part, g, 0.05) for g in board_traces(part, 3)]


def test_a_stored_trace_is_parsed_once_and_its_slope_spline_kept(paths):
    trace = _stored(paths[0], "trace_held_once")
    placement = Placement(dx=1.5, dy=-2.0, dz=0.25, rz_rad=0.01)
    first = placed_nominal(trace, placement)
    again = placed_nominal(trace, placement)
    assert again is first                                      # the next job gets the same object
    expected = place_path(nominal_of(trace), placement)        # what a job parsed before
    np.testing.assert_array_equal(first.points, expected.points)
    np.testing.assert_array_equal(first.s, expected.s)
    np.testing.assert_array_equal(first.normals, expected.normals)
    s = np.linspace(0.0, first.length_mm, 7)
    np.testing.assert_array_equal(path_gradient(first, s), path_gradient(expected, s))
    with pytest.raises(ValueError):                            # no job can change what the next one reads
        first.points[0, 0] = 0.0
    unplaced = placed_nominal(trace, None)
    assert unplaced is not first and placed_nominal(trace, None) is unplaced
    np.testing.assert_array_equal(unplaced.points, nominal_of(trace).points)


def test_a_trace_stored_again_under_the_same_id_is_parsed_again(paths):
    old = _stored(paths[0], "trace_same_id")
    new = _stored(paths[1], "trace_same_id")
    new.created_at = datetime(2026, 1, 2, tzinfo=UTC)
    assert placed_nominal(old, None) is not placed_nominal(new, None)
    np.testing.assert_array_equal(placed_nominal(new, None).points, nominal_of(new).points)


def test_the_held_polylines_are_bounded_by_their_bytes(paths):
    held = ByteLru(max_bytes=2 * held_bytes(paths[0]))   # room for two polylines of this size
    made = []

    def make() -> TracePolyline:
        made.append(1)
        return TracePolyline.from_points(paths[0].points.copy())
    a = held_polyline("a", make, held)
    held_polyline("b", make, held)
    assert held_polyline("a", make, held) is a and len(made) == 2   # a hit, and "a" is now the most recent
    held_polyline("c", make, held)                                   # over the bound: "b" (least recent) goes
    assert len(held) == 2 and held.bytes == held.max_bytes
    assert held_polyline("a", make, held) is a and len(made) == 3
    held_polyline("b", make, held)
    assert len(made) == 4


def test_the_process_holder_is_bounded():
    assert HELD.max_bytes <= 64 * 2**20


class _Reads:
    """The job context's nominal reads: each call's ids, from the stored traces ``rows``."""

    def __init__(self, rows: list[Trace]) -> None:
        self.rows = {t.id: t for t in rows}
        self.calls: list[list[str]] = []

    def trace_nominals(self, trace_ids: list[str]) -> dict[str, dict]:
        self.calls.append(list(trace_ids))
        return {t: self.rows[t].nominal for t in trace_ids}


def _unread(trace: Trace) -> Trace:
    """``trace`` as read without its nominal (reading it would fail)."""
    return Trace(**{k: v for k, v in trace.model_dump().items() if k not in ("nominal", "source")})


def test_a_board_reads_in_one_query_only_the_nominals_the_process_does_not_hold(paths):
    rows = [_stored(p, f"trace_board_{i}") for i, p in enumerate(paths)]
    reads, held = _Reads(rows), ByteLru(2**20)
    placement = Placement(dx=0.5, dy=0.0, dz=0.0, rz_rad=0.0)
    first = placed_nominals(reads, [_unread(t) for t in rows[:2]], placement, held)
    assert reads.calls == [["trace_board_0", "trace_board_1"]]
    again = placed_nominals(reads, [_unread(t) for t in rows], placement, held)
    assert reads.calls[1:] == [["trace_board_2"]]                           # only the one not held
    assert again[0] is first[0] and again[1] is first[1]
    for row, path in zip(rows, again):
        np.testing.assert_array_equal(path.points, place_path(nominal_of(row), placement).points)
    placed_nominals(reads, [_unread(t) for t in rows], placement, held)
    assert len(reads.calls) == 2                                            # all held: no read


def test_a_nominal_let_go_while_a_board_is_read_is_read_again(paths):
    rows = [_stored(p, f"trace_evicted_{i}") for i, p in enumerate(paths)]
    reads = _Reads(rows)
    held = ByteLru(held_bytes(nominal_of(rows[0])) + 1)                     # room for about one
    placed_nominals(reads, [_unread(rows[0])], None, held)
    order = [rows[1], rows[2], rows[0]]                                     # trace 0 held at the look,
    out = placed_nominals(reads, [_unread(t) for t in order], None, held)  # let go by the two before it
    for row, path in zip(order, out):
        np.testing.assert_array_equal(path.points, nominal_of(row).points)
    assert reads.calls[1:] == [["trace_evicted_1", "trace_evicted_2"], ["trace_evicted_0"]]
