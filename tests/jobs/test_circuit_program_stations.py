"""circuit_program's stations: a joint loop's one probe run counts once, not once per trace."""

from __future__ import annotations

from app.jobs.kinds.circuit_program import station_runs
from app.jobs.results.loop import LoopTrace


def test_a_joint_loops_stations_count_once():
    def entry(trace, run):
        return LoopTrace(trace_id=trace, probe_plan="p", probe_run=run, reconstruct="r", compensate="c", probes=5,
                         deviation_max_mm=0.0)

    joint = {f"t{k}": entry(f"t{k}", "run_joint") for k in range(50)}
    assert station_runs(joint, list(joint)) == ["run_joint"]
    apart = {f"t{k}": entry(f"t{k}", f"run{k % 3}") for k in range(6)}
    assert station_runs(apart, list(apart)) == ["run0", "run1", "run2"]
