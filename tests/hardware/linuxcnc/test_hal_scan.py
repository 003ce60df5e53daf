"""``halsampler -t`` rows to scan samples (no simulator needed): sequence gaps, overruns,
values paired with the row of their exposure, repeats and values from before the first row."""

from __future__ import annotations

import numpy as np
import pytest

from hardware.linuxcnc.hal_scan import HalScanError, parse_rows


def _line(seq: int, x: float, reading: float, valid: int, clock: int, exposed: int) -> str:
    return f"{seq} {x:.6f} 3.000000 12.000000 {reading:.6f} {valid} {clock:.6f} {exposed:.6f} \n"


def test_each_value_is_paired_with_the_joints_of_its_exposure():
    lines = ["overrun\n"]  # a new halsampler session: the sampler's numbers went on
    lines += [_line(40, 1.0, 9.0, 1, 500, 300)]  # a value from before the session: dropped
    lines += [_line(41, 2.0, 0.5, 1, 501, 500)]  # exposed one row earlier
    lines += [_line(42, 3.0, 0.5, 1, 502, 500)]  # the same value again: dropped
    lines += [_line(43, 4.0, 1.5, 0, 503, 502)]  # no value (alarm)
    lines += [_line(44, 5.0, 2.5, 1, 504, 504)]
    samples = parse_rows(lines, 0.001)
    assert np.allclose(samples.t, [0.0, 0.002, 0.004])
    assert np.allclose(samples.xyz[:, 0], [1.0, 3.0, 5.0]) and np.allclose(samples.xyz[:, 1:], [3.0, 12.0])
    assert samples.reading[0] == 0.5 and np.isnan(samples.reading[1]) and samples.reading[2] == 2.5
    assert np.allclose(samples.lag_s, [0.001, 0.001, 0.0])


@pytest.mark.parametrize("lines", [
    [_line(0, 1.0, 0.0, 1, 1, 1), _line(1, 1.0, 0.0, 1, 2, 2), _line(3, 1.0, 0.0, 1, 4, 4)],  # a gap
    [_line(0, 1.0, 0.0, 1, 1, 1), "overrun\n", _line(5, 1.0, 0.0, 1, 6, 6)],                # an overrun mid-pass
    [],                                                                                     # nothing sampled
])
def test_lost_samples_are_an_error(lines):
    with pytest.raises(HalScanError):
        parse_rows(lines, 0.001)
