"""``halsampler -t`` rows to scan samples (no simulator needed): sequence gaps, overruns,
values paired with the row of their exposure, repeats, values from before the first row, and
rows sampled while the sensor's component wrote a value; and the component's order of writes."""

from __future__ import annotations

import numpy as np
import pytest

from hardware.linuxcnc.hal_scan import HalScanError, parse_rows
from hardware.linuxcnc.sensor_hal import publish


def _line(seq: int, x: float, reading: float, valid: int, clock: int, exposed: int,
          exposed_before: int | None = None) -> str:
    before = exposed if exposed_before is None else exposed_before
    return (f"{seq} {x:.6f} 3.000000 12.000000 {before:.6f} {reading:.6f} {valid} {clock:.6f} "
            f"{exposed:.6f} \n")


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


def test_a_row_sampled_while_the_component_wrote_a_value_is_dropped():
    """The component writes ``exposed`` -1, the value, then its count; a sampler held between
    its channels under load read the old value with the new count (seen under load: one value
    of 905 off by a period's travel, 2 um at 2 mm/s).  Its two reads of ``exposed`` differ."""
    lines = [_line(0, 1.0, 0.5, 1, 100, 100)]
    lines += [_line(1, 2.0, 0.5, 1, 101, 101, exposed_before=100)]  # the old value, the new count
    lines += [_line(2, 3.0, 0.7, 1, 102, 101)]                      # the new value, whole
    lines += [_line(3, 4.0, 0.7, 1, 103, -1, exposed_before=-1)]    # mid-write: no count yet
    lines += [_line(4, 5.0, 0.9, 1, 104, 103, exposed_before=-1)]   # the write began after the first read
    lines += [_line(5, 6.0, 0.9, 1, 105, 104)]
    samples = parse_rows(lines, 0.001)
    assert np.allclose(samples.t, [0.0, 0.001, 0.004])
    assert np.allclose(samples.xyz[:, 0], [1.0, 2.0, 5.0])  # each value with the joints of its exposure
    assert list(samples.reading) == [0.5, 0.7, 0.9]
    assert np.allclose(samples.lag_s, [0.0, 0.001, 0.001])


def test_the_component_marks_a_value_unfinished_until_its_count_is_written():
    writes: list[tuple[str, object]] = []

    class Pins(dict):
        def __setitem__(self, name, value):  # type: ignore[no-untyped-def]
            writes.append((name, value))
            super().__setitem__(name, value)

    pins = Pins()
    publish(pins, 1.25, 4711.0, 5.0)
    assert writes == [("exposed", -1.0), ("reading", 1.25), ("valid", True), ("exposed", 4711.0)]
    writes.clear()
    publish(pins, float("nan"), 4712.0, 5.0)  # no value: valid false, the count still last
    assert writes == [("exposed", -1.0), ("reading", 0.0), ("valid", False), ("exposed", 4712.0)]
