"""The exports' block formatter against printf, ring by ring."""

from __future__ import annotations

import numpy as np
import pytest

from app.slicing import ring_text
from app.slicing.ring_text import pairs_text, points_text, ring_texts


def _printf_points(ring: np.ndarray, decimals: int) -> str:
    """What printf writes for each number (``-0.000...`` written as zero)."""
    return ",".join("0." + "0" * decimals if abs(v) < 0.5 * 10.0 ** -decimals else f"{v:.{decimals}f}"
                    for v in ring.ravel().tolist())


def _rings(rng: np.random.Generator) -> list[np.ndarray]:
    rings = [rng.uniform(-500.0, 500.0, (rng.integers(3, 40), 2)) for _ in range(200)]
    rings.append(np.array([[1e-7, -4e-7], [-0.0, 0.0], [5.5e-6, -2.5e-6]]))  # zeros as written, halves
    rings.append(np.round(rng.uniform(-100.0, 100.0, (50, 2)), 6))  # already at the decimals
    rings.append(rng.integers(-1000, 1000, (30, 2)).astype(float) + 0.5e-6)  # exact ties in decimal
    return rings


@pytest.mark.parametrize("decimals", [3, 6])
@pytest.mark.parametrize("block", [7, 64, 65_536])
def test_ring_texts_are_printf_ring_by_ring(monkeypatch, decimals, block):
    monkeypatch.setattr(ring_text, "BLOCK_VALUES", block)  # rings split across blocks, and all in one
    rings = _rings(np.random.default_rng(decimals + block))
    rings = [*rings, *rings[:5], rings[0], rings[-1]]  # some arrays again (a prismatic stretch's shared rings)
    points = list(ring_texts(rings, decimals))
    pairs = list(ring_texts(rings, decimals, pairs=True))
    assert len(points) == len(pairs) == len(rings)
    for ring, text, paired in zip(rings, points, pairs):
        assert text == points_text(ring, decimals) == _printf_points(ring, decimals)
        assert paired == pairs_text(ring, decimals)
        assert paired == ",".join(f"[{xy}]" for xy in
                                  (",".join(p.split(",")) for p in
                                   (_printf_points(row[None, :], decimals) for row in ring)))


def test_a_negative_number_printf_writes_as_minus_zero_is_formatted_by_printf():
    ring = np.array([[-5e-7, 1.0], [2.0, 3.0], [4.0, 5.0]])  # |v| at half the last decimal: printf keeps '-'
    assert list(ring_texts([ring], 6)) == [points_text(ring, 6)]
    assert list(ring_texts([ring], 6, pairs=True)) == [pairs_text(ring, 6)]


def test_numbers_beyond_the_columns_range_are_formatted_by_printf():
    ring = np.array([[1e12, 1.0], [2.0, 3.0], [4.0, -5.0]])
    assert list(ring_texts([ring], 6)) == ["%.6f,%.6f,%.6f,%.6f,%.6f,%.6f" % (1e12, 1.0, 2.0, 3.0, 4.0, -5.0)]
