"""TracePolyline, the one trace polyline: validation, queries, and the stored JSON form
(``Trace.nominal``) read and written without change."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from app.geometry.errors import DegenerateGeometryError
from app.geometry.placement import Placement
from app.geometry.slope import check_slope
from app.geometry.traces import TracePolyline, TracePolylineError, as_trace_polyline, build_nominal_trace
from app.registration.registration import place_path
from tests.geometry.conftest import height_field_mesh

# a stored nominal as the service wrote it (before this type existed): rounded points and
# normals, the slope stretch and the slope summary
STORED = {
    "points": [[10.0, 4.0, 9.208333], [10.0, 4.1, 9.231125], [10.000001, 4.25, 9.262], [10.0, 6.0, 9.5]],
    "normals": [[-0.1, -0.2, 0.974679], [-0.1, -0.21, 0.972573], [-0.1, -0.2, 0.974679], [0.0, 0.0, 1.0]],
    "slope_stretch": 1.0123,
    "slope": {"max_slope_deg": 13.4, "at": [10.0, 4.1, 9.2311], "height_error_mm_per_xy_error": 0.238,
              "height_error_mm": 0.00238, "warnings": []},
}


def _old_stored_form(nominal, slope) -> dict:  # type: ignore[no-untyped-def]
    """What the trace records held before TracePolyline.to_dict (kept here as the format's reference)."""
    return {
        "points": [[round(float(v), 6) for v in p] for p in nominal.points],
        "normals": [[round(float(v), 6) for v in n] for n in nominal.normals],
        "slope_stretch": float(nominal.slope_stretch),
        "slope": slope.to_json(),
    }


def _same_stored(a: dict, b: dict) -> None:  # type: ignore[type-arg]
    """Equal stored forms: same keys, points / stretch / slope exact, normals to their 1e-6 rounding."""
    assert a.keys() == b.keys()
    assert a["points"] == b["points"] and a.get("slope_stretch") == b.get("slope_stretch")
    assert a.get("slope") == b.get("slope")
    if "normals" in a:
        np.testing.assert_allclose(a["normals"], b["normals"], rtol=0, atol=1.0000001e-6)


def test_a_stored_dict_round_trips() -> None:
    poly = TracePolyline.from_dict(STORED)
    back = poly.to_dict()
    _same_stored(back, STORED)
    assert back["normals"][0] == STORED["normals"][0] and back["normals"][3] == STORED["normals"][3]
    assert json.loads(json.dumps(back)) == back
    assert poly.slope_stretch == 1.0123 and poly.slope == STORED["slope"]
    np.testing.assert_allclose(np.linalg.norm(poly.normals, axis=1), 1.0, rtol=1e-12)  # read back as unit
    minimal = {"points": STORED["points"]}  # older rows carry points only
    assert TracePolyline.from_dict(minimal).to_dict() == minimal
    assert TracePolyline.from_dict(minimal).normals is None


def test_the_service_writes_the_same_json_as_before() -> None:
    mesh = height_field_mesh(lambda x, y: 5 + np.sin(x / 5) * np.cos(y / 9), 41, 61)
    g = {"type": "nurbs", "degree": 3, "control_points": [[10, 6], [15, 15], [5, 25], [12, 38]]}
    nominal = build_nominal_trace(mesh, g, "xy")
    slope = check_slope(nominal.points, nominal.normals)
    stored = replace(nominal, slope=slope.to_json()).to_dict()
    assert stored == _old_stored_form(nominal, slope)
    again = TracePolyline.from_dict(stored)
    _same_stored(again.to_dict(), stored)
    assert again.length_mm == pytest.approx(nominal.length_mm, abs=1e-5)
    np.testing.assert_allclose(again.points, nominal.points, atol=1e-6)


def test_from_points_validates_and_drops_duplicates() -> None:
    pts = np.array([[0.0, 0, 0], [0, 0, 0], [3, 4, 0], [3, 4, 12]])
    poly = TracePolyline.from_points(pts, np.tile([0.0, 0, 2], (4, 1)))
    assert len(poly.points) == 3 and poly.s.tolist() == [0.0, 5.0, 17.0] and poly.length_mm == 17.0
    np.testing.assert_allclose(poly.normals, np.tile([0.0, 0, 1], (3, 1)))
    assert poly.z_range == (0.0, 12.0)
    np.testing.assert_allclose(poly.at(np.array([2.5, 11.5])), [[1.5, 2.0, 0.0], [3.0, 4.0, 6.5]])
    assert poly.z_at(np.array([17.0])).tolist() == [12.0]
    proj = poly.project_xy(np.array([[3.0, 0.0]]))
    assert proj.s[0] == pytest.approx(9 / 5) and proj.distance_mm[0] == pytest.approx(12 / 5)
    assert TracePolyline.from_points(pts, normals=np.zeros((2, 3))).normals is None  # wrong shape: dropped
    for bad, field in (([[0, 0, 0]], "nominal.points"), ([[0, 0, 0], [0, 0, 0]], "nominal.points"),
                       ([[0, 0, 0], [1, np.nan, 0]], "nominal.points[1]"), ("abc", "nominal.points")):
        with pytest.raises(TracePolylineError) as info:
            TracePolyline.from_points(bad)
        assert info.value.field == field and isinstance(info.value, DegenerateGeometryError)
    with pytest.raises(TracePolylineError) as info:
        TracePolyline.from_dict({"normals": []})
    assert info.value.field == "trace.nominal.points"


def test_as_trace_polyline_takes_the_type_objects_with_points_and_arrays() -> None:
    poly = TracePolyline.from_dict(STORED)
    assert as_trace_polyline(poly) is poly
    np.testing.assert_allclose(as_trace_polyline(np.asarray(STORED["points"])).s, poly.s)

    class Duck:
        points = STORED["points"]
        normals = STORED["normals"]
    np.testing.assert_allclose(as_trace_polyline(Duck()).normals, poly.normals, rtol=0, atol=0)
    np.testing.assert_allclose(np.linalg.norm(as_trace_polyline(Duck()).normals, axis=1), 1.0, rtol=1e-12)


def test_a_placed_polyline_keeps_lengths_and_stretch() -> None:
    poly = TracePolyline.from_dict(STORED)
    pl = Placement.from_deg(1.0, -2.0, 0.5, 30.0, (10.0, 5.0))
    placed = place_path(poly, pl)
    np.testing.assert_allclose(placed.s, poly.s)
    np.testing.assert_allclose(placed.points, pl.apply(poly.points))
    np.testing.assert_allclose(placed.normals, pl.rotate(poly.normals))
    assert placed.slope_stretch == poly.slope_stretch


def test_the_stored_form_rounds_exactly_as_pythons_round():
    from app.geometry.tolerance import STORED_DECIMALS
    from app.geometry.traces import _rounded

    rng = np.random.default_rng(9)
    values = np.concatenate([rng.uniform(-400.0, 400.0, 3000), rng.normal(0.0, 1e-6, 300),
                             (np.arange(-600, 600) + 0.5) / 10 ** STORED_DECIMALS,  # ties, as near as doubles get
                             np.nextafter((np.arange(200) + 0.5) / 10 ** STORED_DECIMALS, 1.0),
                             [0.0, -0.0, 1e17, -3e16, 2.0 ** 53 / 1e6, 7.25, -7.25]]).reshape(-1, 3)
    expected = [[round(v, STORED_DECIMALS) for v in row] for row in values.tolist()]
    got = _rounded(values)
    assert got == expected
    assert [math.copysign(1.0, v) for row in got for v in row] == \
        [math.copysign(1.0, v) for row in expected for v in row]  # -0.0 stays -0.0
