"""A field loop's verdict with three verification points over two straight traces (the
residual map's and the run report's tests)."""

from __future__ import annotations

import numpy as np

# two straight traces: a ramp along x at y = 5 (z = 1 + 0.1 x) and a flat one at y = 20 (z = 3)
NOMINALS = {"t-ramp": np.array([[0.0, 5.0, 1.0], [40.0, 5.0, 5.0]]),
            "t-flat": np.array([[0.0, 20.0, 3.0], [40.0, 20.0, 3.0]])}
VERDICT = {"worse_traces": ["t-flat"], "verification": [
    {"xy": [10.0, 5.0], "trace": 0, "measured_mm": 0.020, "predicted_mm": 0.018, "residual_mm": 0.002,
     "limit_mm": 0.006, "within": True, "worse": False},
    {"xy": [30.0, 5.0], "trace": 0, "measured_mm": -0.010, "predicted_mm": -0.004, "residual_mm": -0.006,
     "limit_mm": 0.005, "within": False, "worse": False},
    {"xy": [25.0, 20.0], "trace": 1, "measured_mm": 0.004, "predicted_mm": 0.012, "residual_mm": -0.008,
     "limit_mm": 0.010, "within": True, "worse": True}]}
