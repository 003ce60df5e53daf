"""Job ``probe_run``: execute a probe plan on a machine and record the measured points.

Recovery: when the link drops mid-run (or the server dies) the job becomes ``interrupted``
with the points measured so far in ``program_state``; an operator's resume re-homes and
touches the interrupted point again — a touch is idempotent, and every point before it
was already recorded.  A probe that finds no surface fails the job with a 422 naming
the point; no measured points are stored from a failed run.

On a machine with a probe calibration (``calibrate_probe``) the probe (T0) is selected
first and each point keeps its raw ``reading`` (the ball centre at trigger), its estimated
machine time ``t_s`` and its ``measured`` station-equivalent surface point: the reading
corrected along the station's nominal normal for the ball radius and the calibrated
pre-travel, and for Z drift.  Drift: when the calibration has a pad reading and the
machine profile a reference pad, the pad is touched first, again before every touch that
comes ``drift_interval_s`` (estimated machine time) after the last pad touch, and last;
the readings between two pad visits are shifted by the pad's change since calibration,
interpolated in estimated machine time (:mod:`app.calibration.drift`); a visit is
PAD_TOUCHES touches, averaged.  ``corrections`` switches each part
off (ablation).  Without a calibration nothing changes: ``measured`` is the reading.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import Field

from app.calibration import DriftTrack, drift_offsets, retouch_schedule, touch_times
from app.jobs.probe_correction import (
    PAD_CLEARANCE_MM,
    PAD_OVERTRAVEL_MM,
    Corrections,
    MachineProbe,
    corrected_heights,
    machine_probe,
    station_normals,
)
from app.jobs.results.models import ProbePlanResult, ProbeRunResult
from app.machines.live import profile_of, translate
from app.runtime.context import JobContext
from app.runtime.machine_queue import (
    interrupt,
    refuse_if_machine_busy,
    rehomed_machine,
    resume_request,
    stopped_by_operator,
)
from app.runtime.reads import JobReads
from app.runtime.registry import JobParams, job_kind
from hardware.errors import HardwareError, LinkError

PAD = -1  # the op index of a pad visit
PAD_TOUCHES = 3  # touches per pad visit, averaged (the pad reading's noise is shared by every point near it)


class ProbeRunParams(JobParams):
    plan_job_id: str = Field(description="a succeeded probe_plan job")
    machine_id: str
    probe_feed_mm_min: float | None = Field(None, gt=0, le=10_000, description="default: the plan's")
    corrections: Corrections = Field(
        default_factory=Corrections, description="on a machine with a probe calibration: which corrections the "
        "measured points get (all by default; false switches one off, for the ablation bench)")
    drift_interval_s: float = Field(120.0, gt=0, le=86_400, description="drift correction: the reference pad is "
                                    "re-touched when this much estimated machine time passed since its last touch")


def _check(params: ProbeRunParams, reads: JobReads) -> None:
    refuse_if_machine_busy(params.machine_id, reads)


class TouchSequence:
    """The touches of a calibrated run in order: ``ops`` (m,) record index or PAD, their
    start heights ``start_z`` (m,) mm and estimated machine times ``t_s`` (m,) s."""

    def __init__(self, records: list[dict], probe: MachineProbe | None, drift: bool, interval_s: float,
                 travel_feed: float, probe_feed: float, start: tuple[float, float, float]) -> None:
        xyz = np.array([r["nominal"] for r in records], dtype=float)
        safe = np.array([r["safe_z_mm"] for r in records], dtype=float)
        target = np.array([r["target_z_mm"] for r in records], dtype=float)
        ball = probe.calibration.ball_radius_mm if probe is not None else 0.0
        contact = xyz + [0.0, 0.0, ball]  # the ball centre meets a flat top r above it
        self.pad = probe.pad_mm if probe is not None and drift else None
        high = float(safe.max()) if self.pad is None else max(float(safe.max()), self.pad[2] + PAD_CLEARANCE_MM)
        self.high_z = high
        start_mm = np.asarray(start, dtype=float)
        ops = list(range(len(records)))
        if self.pad is not None:
            before = set(retouch_schedule(touch_times(contact, safe, target, travel_feed, probe_feed, start_mm),
                                          interval_s))
            ops = [o for i in range(len(records)) for o in ([PAD, i] if i in before else [i])]
            ops += [PAD] if len(records) in before else []
        self.ops = ops
        pad = None if self.pad is None else np.array(self.pad) + [0.0, 0.0, ball]
        self.start_z = np.array([high if o == PAD or (k > 0 and ops[k - 1] == PAD) else safe[o]
                                 for k, o in enumerate(ops)], dtype=float)
        # every touch in order (a pad visit is PAD_TOUCHES touches); an op's time is its touches' mean
        owner = np.repeat(np.arange(len(ops)), [PAD_TOUCHES if o == PAD else 1 for o in ops])
        pts = np.array([pad if ops[k] == PAD else contact[ops[k]] for k in owner], dtype=float)
        low = np.array([self.pad[2] - PAD_OVERTRAVEL_MM if ops[k] == PAD else target[ops[k]]  # type: ignore[index]
                        for k in owner])
        each = touch_times(pts, self.start_z[owner], low, travel_feed, probe_feed, start_mm)
        self.t_s = np.bincount(owner, weights=each, minlength=len(ops)) / np.bincount(owner, minlength=len(ops))


@job_kind("probe_run", ProbeRunParams, queue="machine", check=_check,
          references=lambda p: [("job", p.plan_job_id), ("machine", p.machine_id)])
def run(ctx: JobContext, params: ProbeRunParams) -> dict:
    """Touch every planned point (travel at its safe height, probe down to its target)."""
    plan = ctx.job(params.plan_job_id, kind="probe_plan", field="params.plan_job_id")
    records = ProbePlanResult.of(plan).records
    feed = params.probe_feed_mm_min or plan.params.get("probe_feed_mm_min", 100.0)
    probe = machine_probe(ctx, params.machine_id)
    drift = probe is not None and params.corrections.drift and probe.pad_mm is not None \
        and probe.calibration.pad_reading_z_mm is not None
    resume = resume_request(ctx)
    points: list[dict] = list((resume or {}).get("points", []))
    track: dict[str, list[float]] = dict((resume or {}).get("drift") or {"times_s": [], "pad_z_mm": []})
    state: dict = {"total": len(records), "executed": len(points), "points": points, "drift": track,
                   "ops_done": int((resume or {}).get("ops_done", len(points))),
                   "resumes": (resume or {}).get("resumes", 0)}
    machine = rehomed_machine(ctx, params.machine_id, resume, state)
    profile = profile_of(ctx.machine(params.machine_id))
    sequence = TouchSequence(records, probe, drift, params.drift_interval_s, profile.travel_feed_mm_min, feed,
                             (0.0, 0.0, profile.clearance_z))

    def touch(x: float, y: float, z_start: float, z_min: float) -> Any:
        try:
            if machine.link_lost:  # the link dropped after the previous touch
                raise LinkError("link lost", field="port")
            return machine.probe(x, y, z_start=z_start, z_min=z_min, feed_mm_min=feed)
        except LinkError as exc:  # a touch is idempotent: a resume touches this point again
            raise interrupt(ctx, machine, exc, state) from exc
        except HardwareError as exc:
            if stopped_by_operator(ctx, machine):
                raise interrupt(ctx, machine, exc, state) from exc
            raise translate(exc) from exc

    with ctx.lease(params.machine_id):
        if probe is not None:
            try:
                machine.select_tool(0)
            except HardwareError as exc:
                failure = interrupt(ctx, machine, exc, state) if isinstance(exc, LinkError) else translate(exc)
                raise failure from exc
        from_pad = False  # a resume's extra pad visit: the next station is reached from the high travel height
        if drift and resume is not None and 0 < state["ops_done"] < len(sequence.ops):
            _touch_pad(touch, sequence, track, float(sequence.t_s[state["ops_done"]]) - 1e-3)
            from_pad = True
        for k in range(state["ops_done"], len(sequence.ops)):
            index = sequence.ops[k]
            if index == PAD:
                _touch_pad(touch, sequence, track, float(sequence.t_s[k]))
            else:
                record = records[index]
                x, y, z_nominal = record["nominal"]
                start_z = sequence.high_z if from_pad else float(sequence.start_z[k])
                from_pad = False
                reading = touch(x, y, start_z, record["target_z_mm"])
                row: dict[str, Any] = {"index": index, "nominal": [x, y, z_nominal],
                                       "measured": [reading.x, reading.y, reading.z],
                                       "deviation_mm": reading.z - z_nominal}
                if probe is not None:
                    row.update(reading=[reading.x, reading.y, reading.z], t_s=float(sequence.t_s[k]),
                               normal=record.get("normal"))
                points.append(row)
                state["executed"] = len(points)
                ctx.progress(len(points) / len(records), f"probed {len(points)}/{len(records)}")
            state["ops_done"] = k + 1
            ctx.save_program_state(state)
    result: dict[str, Any] = {"points": points, "resumes": state["resumes"]}
    if probe is not None:
        result["calibration"] = _correct(points, probe, params, track if drift else None)
    deviations = np.array([p["deviation_mm"] for p in points])
    result["stats"] = {"count": len(points), "max_abs_mm": float(np.abs(deviations).max()),
                       "mean_mm": float(deviations.mean()), "rms_mm": float(np.sqrt(np.mean(deviations ** 2)))}
    return ProbeRunResult.written(result)


def _touch_pad(touch: Any, sequence: TouchSequence, track: dict[str, list[float]], t_s: float) -> None:
    """Touch the reference pad's centre vertically from above every travel height,
    PAD_TOUCHES times; record the mean reading at the visit's estimated time."""
    x, y, z = sequence.pad  # type: ignore[misc]
    readings = [touch(x, y, sequence.high_z, z - PAD_OVERTRAVEL_MM).z for _ in range(PAD_TOUCHES)]
    track["times_s"].append(t_s)
    track["pad_z_mm"].append(float(np.mean(readings)))


def _correct(points: list[dict], probe: MachineProbe, params: ProbeRunParams,
             track: dict[str, list[float]] | None) -> dict[str, Any]:
    """Fill each point's ``measured``, ``drift_mm`` and ``correction_mm``; the result's
    ``calibration`` record."""
    readings = np.array([p["reading"] for p in points], dtype=float)
    times = np.array([p["t_s"] for p in points], dtype=float)
    normals = station_normals([p.get("normal") for p in points], len(points))
    drift_mm = np.zeros(len(points))
    if track is not None and track["times_s"]:
        order = np.argsort(track["times_s"], kind="stable")
        drift_track = DriftTrack(tuple(np.asarray(track["times_s"])[order]),
                                 tuple(np.asarray(track["pad_z_mm"])[order]))
        drift_mm = drift_offsets(drift_track, times, float(probe.calibration.pad_reading_z_mm))  # type: ignore[arg-type]
    z = corrected_heights(readings, normals, drift_mm, probe.calibration, params.corrections)
    for p, zi, di in zip(points, z, drift_mm):
        x, y, z_nominal = p["nominal"]
        p.update(measured=[x, y, float(zi)], drift_mm=float(di), correction_mm=float(zi - p["reading"][2]),
                 deviation_mm=float(zi - z_nominal))
    return {"probe_job_id": probe.job_id, "corrections": params.corrections.model_dump(),
            "probe": probe.calibration.to_dict(),
            "drift": None if track is None else {"times_s": track["times_s"], "pad_z_mm": track["pad_z_mm"],
                                                 "interval_s": params.drift_interval_s}}
