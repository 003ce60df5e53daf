"""Test helper: read five-axis G1 lines back from program text (independent of app code)."""

from __future__ import annotations

import re

import numpy as np

_WORD = re.compile(r"([XYZACF])(-?\d+(?:\.\d+)?)")


def g1_rows(text: str) -> np.ndarray:
    """(k, 6) X Y Z A C F of every G1 line in program order (an approach G1 included);
    NaN where a word is absent."""
    rows = []
    for line in text.splitlines():
        if line.startswith("G1 "):
            words = dict(_WORD.findall(line))
            rows.append([float(words.get(k, "nan")) for k in "XYZACF"])
    return np.array(rows)
