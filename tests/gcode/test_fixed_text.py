"""The numpy-built move lines are the f-string's text, number for number."""

from __future__ import annotations

import numpy as np
import pytest

from app.gcode.fixed_text import number_columns, scaled_integers, xye_lines
from app.gcode.writer import as_written


def _as_text(columns: np.ndarray) -> list[str]:
    return [bytes(row[row != 0]).decode() for row in columns]


@pytest.mark.parametrize("decimals", [0, 1, 4, 6])
def test_each_number_is_the_f_string(decimals):
    rng = np.random.default_rng(decimals)
    values = np.concatenate([rng.uniform(-400, 400, 2000), rng.uniform(-1e-3, 1e-3, 200),
                             10.0 ** rng.integers(-6, 7, 50),
                             [0.0, 0.5, 1.5, 2.5, -0.5, 0.125, 1e6 + 0.5, 123456.789, 9.99995, -9.99995]])
    want = [f"{v:.{decimals}f}" for v in values.tolist()]
    want = [t[1:] if t.startswith("-") and float(t) == 0.0 else t for t in want]   # never -0
    assert _as_text(number_columns(values, decimals)) == want


def test_halfway_values_round_as_printf_and_too_large_ones_are_refused():
    halves = np.array([0.00005, 0.00015, 2.00025, 1.23455, -7.00035])
    assert scaled_integers(halves, 4).tolist() == [int(f"{v:.4f}".replace(".", "")) for v in halves.tolist()]
    with pytest.raises(ValueError):
        scaled_integers(np.array([1.0, np.inf]), 4)
    with pytest.raises(ValueError):
        scaled_integers(np.array([1e15]), 4)


def test_move_lines_are_the_f_string_lines():
    rng = np.random.default_rng(2)
    x, y, e = (as_written(rng.uniform(lo, hi, 5000), 4) for lo, hi in ((-5, 300), (-300, 5), (0, 9000)))
    x[:3] = as_written(np.array([-0.00004, 0.00004, -0.0]), 4)
    want = [f"G1 X{a:.4f} Y{b:.4f} E{c:.4f}" for a, b, c in zip(x.tolist(), y.tolist(), e.tolist())]
    assert xye_lines(x, y, e, 4) == want
    assert "X-0.0000" not in "".join(want[:3])
    assert xye_lines(np.zeros(0), np.zeros(0), np.zeros(0), 4) == []
