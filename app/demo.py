"""``conforma demo``: the height-compensation paper's experiment, reproduced on the mock printer.

Loads the S1 reference part (40 mm x 60 mm, NURBS free-form top) and its nine traces, a
mock machine whose true part carries a smooth machining error and a placement offset,
runs the closed loop (probe plan -> probe run -> reconstruct -> compensate), prints the
nominal and the compensated program of every trace on the mock, and prints a table like
the paper's Table 1 from what the mock really deposited: standoff error before/after,
predicted line width mean/std before/after, probes used.
"""

from __future__ import annotations

import argparse
import sys
import time

from sqlmodel import Session

from app.api.schemas import TraceCreate
from app.gcode.writer import DEFAULT_DIALECT
from app.machines.dispenser import machine_dispense
from app.parts.intake import export_mesh
from app.parts.storage import store_part
from app.parts.traces import build_trace
from app.platform.config import Settings
from app.platform.db import migrate
from app.platform.models import COMPLETED_STATES, TERMINAL_STATES, Job, Machine, new_id, utcnow
from app.platform.ownership import MachineOwnerLock
from app.reference.evaluation import Table1Row, format_table
from app.reference.s1 import as_made, s1_mesh, s1_traces
from app.runtime.engine import QUEUES, Runtime


def _numbers(spec: str) -> list[int]:
    out: list[int] = []
    for item in spec.split(","):
        lo, _, hi = item.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    if not out or min(out) < 1 or max(out) > 9:
        raise ValueError(f"traces must be within 1..9, got {spec!r}")
    return out


def run_demo(settings: Settings, args: argparse.Namespace, out=sys.stdout) -> list[Table1Row]:
    numbers = _numbers(args.traces)
    migrate(settings)
    runtime = Runtime(settings)
    owner = MachineOwnerLock(settings.data_dir)
    served = not owner.acquire()
    if served:  # a running server owns this data directory's machines: it runs the demo's jobs
        print(f"a Conforma server (pid {owner.holder_pid()}) runs on {settings.data_dir}: "
              "the demo's jobs run there and show on its pages", file=out)
    else:
        runtime.start_workers(QUEUES)
    try:
        truth = as_made(seed=args.seed, amplitude_mm=args.amplitude_mm)
        limit = int(settings.max_unzipped_mb * 2**20)
        with Session(runtime.engine, expire_on_commit=False) as session:
            part = store_part(session, runtime.blobs, runtime.meshes,
                              export_mesh(s1_mesh(grid_mm=args.grid_mm), "stl"), "stl", "S1 reference part", limit)
            real = store_part(session, runtime.blobs, runtime.meshes,
                              export_mesh(truth.mesh(grid_mm=args.grid_mm), "stl"), "stl",
                              f"S1 as made (seed {args.seed}, +-{args.amplitude_mm} mm)", limit)
            session.flush()
            traces = [build_trace(runtime.meshes, part, TraceCreate.model_validate(s1_traces()[n - 1].to_api()))
                      for n in numbers]
            on, off = machine_dispense(DEFAULT_DIALECT)  # a machine's dispenser unless its profile names one
            machine = Machine(
                id=new_id("mach"), name="S1 demo mock", port="mock://", dialect=DEFAULT_DIALECT,
                profile={"dispense_on": on, "dispense_off": off},
                mock={"true_part_id": real.id, "placement": {"dz": args.dz_mm},
                      "probe_noise_mm": args.noise_um / 1000.0, "faults": {"seed": args.seed}},
                created_at=utcnow())
            session.add_all([*traces, machine])
            session.commit()
        print(f"part {part.id}, true part {real.id}, mock machine {machine.id}, traces {numbers}", file=out)
        job = runtime.submit("closed_loop", {
            "part_id": part.id, "trace_ids": [t.id for t in traces], "machine_id": machine.id,
            "probe": {"method": args.planner}, "sigma_mm": args.noise_um / 1000.0, "evaluate": True})
        started = time.monotonic()
        last = None
        while True:
            with Session(runtime.engine) as session:
                current = session.get(Job, job.id)
            if current is None:
                print(f"closed loop {job.id} was deleted", file=out)
                raise SystemExit(1)
            if current.message != last:
                print(f"  [{time.monotonic() - started:6.1f} s] {current.progress:4.0%} {current.message}", file=out)
                last = current.message
            if current.status in TERMINAL_STATES:
                break
            time.sleep(0.2)
        if current.status not in COMPLETED_STATES:
            print(f"closed loop {current.status}: {(current.error or {}).get('detail')}", file=out)
            raise SystemExit(1)
        rows = [Table1Row(**{k: v for k, v in row.items() if k in Table1Row.__dataclass_fields__})
                for row in (current.result or {})["table"]]
        for row, number in zip(rows, numbers):
            object.__setattr__(row, "trace", number)
        print("\nThe published Table 1, simulated (um; 'before' = nominal program, 'after' = compensated):", file=out)
        print(format_table(rows), file=out)
        print(f"\nclosed-loop job {job.id} (children: GET /api/v1/jobs?parent_id={job.id}); "
              f"data in {settings.data_dir}; `conforma serve` shows it at http://{settings.host}:{settings.port}/",
              file=out)
        return rows
    finally:
        runtime.stop()
        owner.release()
