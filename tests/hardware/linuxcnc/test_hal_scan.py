"""``halsampler -t`` rows to scan samples (no simulator needed): sequence gaps, overruns,
the component's first fresh value, valid flags."""

from __future__ import annotations

import numpy as np
import pytest

from hardware.linuxcnc.hal_scan import HalScanError, parse_rows


def _line(seq: int, x: float, reading: float, valid: int, updates: int) -> str:
    return f"{seq} {x:.6f} 3.000000 12.000000 {reading:.6f} {valid} {updates} \n"


def test_rows_become_samples_from_the_first_fresh_value():
    lines = ["overrun\n"]  # a new halsampler session: the sampler's numbers went on
    lines += [_line(40 + k, 1.0, 0.0, 0, 7) for k in range(3)]  # the component not yet awake
    lines += [_line(43 + k, 1.0 + k, 0.5 + k, int(k != 2), 8 + k) for k in range(5)]
    samples = parse_rows(lines, 0.001)
    assert np.allclose(samples.t, np.arange(5) * 0.001)
    assert np.allclose(samples.xyz[:, 0], 1.0 + np.arange(5)) and np.allclose(samples.xyz[:, 1:], [3.0, 12.0])
    assert np.allclose(samples.reading[[0, 1, 3, 4]], [0.5, 1.5, 3.5, 4.5]) and np.isnan(samples.reading[2])


@pytest.mark.parametrize("lines", [
    [_line(0, 1.0, 0.0, 1, 1), _line(1, 1.0, 0.0, 1, 2), _line(3, 1.0, 0.0, 1, 3)],  # a gap
    [_line(0, 1.0, 0.0, 1, 1), "overrun\n", _line(5, 1.0, 0.0, 1, 2)],               # an overrun mid-pass
    [],                                                                              # nothing sampled
])
def test_lost_samples_are_an_error(lines):
    with pytest.raises(HalScanError):
        parse_rows(lines, 0.001)
