"""True surfaces the height-model tests and the bed-mesh bench probe: a curved part and a
bowed board (heights in mm over x, y in mm; arrays of any matching shape)."""

from __future__ import annotations

import numpy as np


def dome(x, y):  # type: ignore[no-untyped-def]
    """A 13 mm elliptic dome with 0.15 mm waviness over 60 x 40 mm (mm)."""
    base = 13.0 * np.sqrt(np.clip(1 - ((x - 30) / 45) ** 2 - ((y - 20) / 32) ** 2, 0, None))
    return base + 0.15 * np.sin(2 * np.pi * x / 17) * np.cos(2 * np.pi * y / 13)


def bow(x, y):  # type: ignore[no-untyped-def]
    """A 100 x 80 mm, 1.6 mm board bowed 0.4 mm along x (less at the y edges) and twisted 0.1 mm (mm)."""
    u, v = (x - 50) / 50, (y - 40) / 40
    return 1.6 + 0.4 * (1 - u * u) * (1 - 0.3 * v * v) + 0.1 * u * v
