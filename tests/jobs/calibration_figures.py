"""Recovery and repeatability of calibrate_probe / calibrate_nozzle through the API on the
physics mock of tests/jobs/test_calibration_jobs.py (ball 0.5 mm, pre-travel 15 um +- 2 um,
1 um noise, T1 at (12.3, -4.1, -8.7) known as (12, -4, -8.5), sphere and pad ~0.3 mm off
their nominal places).  Not a test: the figures of the calibration note.

    PYTHONPATH=$PWD python -m tests.jobs.calibration_figures [runs] [drift_mm_per_min]
"""
import pathlib
import sys
import tempfile

import numpy as np
from fastapi.testclient import TestClient

from app.main import create_app
from app.platform.config import load_settings
from tests.conftest import KEYS
from tests.jobs import test_calibration_jobs as T

if __name__ == "__main__":
    runs = int(sys.argv[1]) if len(sys.argv) > 1 else 4
    drift = float(sys.argv[2]) if len(sys.argv) > 2 else 0.0
    d = tempfile.mkdtemp()
    s = load_settings({}, data_dir=pathlib.Path(d) / "data", viewer=False,
                      api_keys=",".join(f"{k}:{r}" for r, k in KEYS.items()))
    with TestClient(create_app(s)) as c:
        m = T.physics_machine(c, physics=f"{T.PHYSICS}&drift_mm_per_min={drift}")
        rs, ps, os_ = [], [], []
        for _ in range(runs):
            p = T.calibrate(c, "calibrate_probe", {"machine_id": m["id"]})["result"]
            n = T.calibrate(c, "calibrate_nozzle", {"machine_id": m["id"], "tool": 1})["result"]
            rs.append(p["ball_radius_mm"])
            ps.append(p["pretravel"]["p0_mm"])
            os_.append(n["offset_mm"])
            print(f"r={p['ball_radius_mm'] * 1e3:.2f} um (std {p['std']['ball_radius_mm'] * 1e3:.2f})  "
                  f"p0={p['pretravel']['p0_mm'] * 1e3:.2f} um (std {p['std']['p0_mm'] * 1e3:.2f})  "
                  f"T1={[round(v, 5) for v in n['offset_mm']]} (std um {[round(v * 1e3, 2) for v in n['std_mm']]})  "
                  f"touches {p['touches']}+{n['touches']}")
        rs, ps, os_ = np.array(rs), np.array(ps), np.array(os_)
        print(f"radius error max {np.abs(rs - 0.5).max() * 1e3:.2f} um, spread {np.ptp(rs) * 1e3:.2f} um")
        print(f"pre-travel error max {np.abs(ps - 0.015).max() * 1e3:.2f} um, spread {np.ptp(ps) * 1e3:.2f} um")
        err = np.abs(os_ - np.array(T.TOOL1_MM)).max(axis=0) * 1e3
        print(f"T1 offset error max x/y/z {err.round(2).tolist()} um, spread "
              f"{(np.ptp(os_, axis=0) * 1e3).round(2).tolist()} um")
