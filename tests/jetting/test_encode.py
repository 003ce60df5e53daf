import io

import numpy as np
from PIL import Image

from app.jetting.encode import (
    npz_arrays,
    npz_bytes,
    pattern_png,
    png_pattern,
)


def test_png_is_one_bit_and_round_trips():
    rng = np.random.default_rng(0)
    pattern = rng.random((37, 53)) > 0.5
    data = pattern_png(pattern, dpi=300)
    image = Image.open(io.BytesIO(data))
    assert image.mode == "1" and image.size == (53, 37)
    np.testing.assert_array_equal(png_pattern(data), pattern)
    assert pattern_png(pattern, dpi=300) == data  # deterministic bytes


def test_npz_round_trip():
    arrays = {"patterns": np.zeros((3, 4, 5), dtype=bool), "heights": np.arange(20.0).reshape(4, 5)}
    back = npz_arrays(npz_bytes(**arrays))
    assert set(back) == set(arrays)
    for name, value in arrays.items():
        np.testing.assert_array_equal(back[name], value)
        assert back[name].dtype == value.dtype


def test_npz_bytes_are_reproducible_and_simulation_artifacts_round_trip():
    import time

    from app.jetting import JettingParams, TargetSpec, simulate

    first = npz_bytes(a=np.arange(5))
    time.sleep(1.1)  # zip timestamps have 2 s resolution; a clock-based one would differ
    assert npz_bytes(a=np.arange(5)) == first
    result = simulate(JettingParams(layers=3, target=TargetSpec(size_mm=1.5, hole_mm=0.5)))
    patterns = npz_arrays(result.patterns_npz())
    np.testing.assert_array_equal(patterns["patterns"], result.patterns)
    heights = npz_arrays(result.heights_npz())
    np.testing.assert_array_equal(heights["final"], result.final_heights)
    summary = result.summary()
    assert len(summary["layers"]) == 3 and summary["final"]["layer"] == 3
