"""Recovery figures of the calibration on the mock (for the notes; not a test).

    PYTHONPATH=$PWD python -m tests.calibration.figures

Six seeds of the issue's physics (ball 0.5 mm, pre-travel 15 um +- 2 um, lobing 3 um, 1 um
noise, 1 um/min drift, T1 offset (12.3, -4.1, -8.7), touch-off 0.5 um, sphere and pad 0.4 mm
off their nominal places), qualification with the drift fit, then T1's offset; errors in um.
"""

from __future__ import annotations

import numpy as np

from app.calibration import (
    fit_nozzle_offset,
    fit_qualification,
    plan_nozzle_calibration,
    plan_qualification,
    plan_times,
)
from hardware.mock.world import get_world
from tests.calibration import test_on_the_mock as t


def once(seed: int, dense: bool):
    with t.mock_machine("marlin", seed) as m:
        m.move(z=t.TRAVEL_Z)
        start, c0 = m.position(), get_world(m.world_name).stats.machine_time_s
        touches = plan_qualification(t.SPHERE_NOMINAL, t.SPHERE_D, t.R, t.PAD_NOMINAL,
                                     **(dict(per_ring=12, equator=24) if dense else {}))
        readings, _ = t.run(m, touches, [0] * len(touches))
        times = plan_times(touches, readings, travel_z=t.TRAVEL_Z, travel_feed=3000.0, probe_feed=100.0,
                           start_mm=start) + c0
        cal = fit_qualification(touches, readings, t.SPHERE_D, times_s=times)
        blind = fit_qualification(touches, readings, t.SPHERE_D)
        plan = plan_nozzle_calibration(cal, (12.0, -4.0, -8.5), t.NOZZLE_D, t.SPHERE_D, t.PAD_NOMINAL,
                                       **(dict(pad_touches=10, side_touches=4) if dense else dict(pad_touches=4)))
        nr, _ = t.run(m, plan, [0 if x.kind == "pad" else 1 for x in plan])
        nozzle = fit_nozzle_offset(1, plan, nr, cal, t.NOZZLE_D, t.SPHERE_D)
        return cal, blind, nozzle, len(touches), times[-1] - times[0]


def main() -> None:
    for dense in (False, True):
        rows = []
        for seed in range(1, 7):
            cal, blind, nz, n, duration = once(seed, dense)
            rows.append([(cal.ball_radius_mm - t.R) * 1e3, (cal.pretravel.p0_mm - t.P0) * 1e3,
                         (cal.pretravel.cos3_mm - t.LOBE) * 1e3, (blind.ball_radius_mm - t.R) * 1e3,
                         *(np.subtract(nz.offset_mm, t.OFFSET) * 1e3), cal.std["ball_radius_mm"] * 1e3,
                         *(np.array(nz.std_mm) * 1e3)])
        rows = np.array(rows)
        label = ("qualification per_ring=12 equator=24; nozzle pad_touches=10 side_touches=4" if dense
                 else "qualification defaults; nozzle pad_touches=4 side_touches=2")
        print(f"{label}: {n} qualification touches, {duration:.0f} s machine time")
        print("  error um: r  p0  cos3  r(no drift fit)  ox  oy  oz | reported std: r  ox  oy  oz")
        for row in rows:
            print("  " + " ".join(f"{v:6.2f}" for v in row))
        print("  max |error|", " ".join(f"{v:5.2f}" for v in np.abs(rows[:, :7]).max(axis=0)),
              "| spread over seeds: r", f"{np.ptp(rows[:, 0]):.2f}",
              "o", " ".join(f"{v:.2f}" for v in np.ptp(rows[:, 4:7], axis=0)))


if __name__ == "__main__":
    main()
