"""`conforma demo` runs the closed loop on the mock and prints the published Table 1."""

from __future__ import annotations

import io

from app.cli import build_parser
from app.demo import run_demo


def test_demo_prints_table_one_with_compensated_traces_within_ten_microns(settings):
    args = build_parser().parse_args(["demo", "--traces", "2,5", "--grid-mm", "0.5"])
    out = io.StringIO()
    rows = run_demo(settings, args, out=out)
    text = out.getvalue()
    assert "Table 1" in text and "err max after" in text
    assert [r.trace for r in rows] == [2, 5]
    for row in rows:
        assert row.standoff_max_after_um <= 10.0
        assert row.standoff_max_before_um > 5 * row.standoff_max_after_um
        assert row.probes >= 4
