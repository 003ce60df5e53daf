"""A machine's current calibration: the latest succeeded ``calibrate_probe`` job, per
nozzle the latest succeeded ``calibrate_nozzle`` job and the latest ``calibrate_sensor`` job, with what an operator must
know about them (``flags``): too old, a re-check that disagrees with the calibration before it,
a nozzle calibrated against an earlier probe calibration (a nozzle's Z offset rests on the
probe's ball radius and pre-travel).

Not a job kind: the calibration kinds and every job that uses a calibration (probe runs,
compensation, prints) import it.  Values are mm and seconds inside; the API summary
(:func:`calibration_summary`) reports standard deviations in micrometres (``_um``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from app.api.machine_schemas import Profile
from app.calibration import NozzleCalibration, ProbeCalibration, disagreements
from app.domain.errors import InvalidInput
from app.jobs.results.calibration import CalibrateNozzleResult, CalibrateProbeResult, CalibrateSensorResult
from app.platform.models import Job, Machine

if TYPE_CHECKING:
    from app.runtime.reads import JobReads

KINDS = ("calibrate_probe", "calibrate_nozzle", "calibrate_sensor")


@dataclass
class MachineCalibration:
    """What a machine is calibrated with now (None / empty where it is not).

    ``probe_at`` / ``nozzle_at``: when the calibration job finished (UTC).  ``flags``: one
    readable sentence per problem, e.g. "probe calibration is 30.1 h old (max 24 h)"."""

    probe: ProbeCalibration | None = None
    probe_job_id: str | None = None
    probe_at: datetime | None = None
    nozzles: dict[int, NozzleCalibration] = field(default_factory=dict)
    nozzle_job_ids: dict[int, str] = field(default_factory=dict)
    nozzle_at: dict[int, datetime] = field(default_factory=dict)
    flags: list[str] = field(default_factory=list)
    max_age_h: float = 24.0
    probe_result: CalibrateProbeResult | None = None  # the probe job's stored result (agreement, readings)
    nozzle_results: dict[int, CalibrateNozzleResult] = field(default_factory=dict)
    sensor: CalibrateSensorResult | None = None  # the height sensor's (calibrate_sensor), if any
    sensor_job_id: str | None = None
    sensor_at: datetime | None = None
    now: datetime = field(default_factory=lambda: datetime.now(UTC))

    def age_h(self, at: datetime | None) -> float | None:
        return None if at is None else (self.now - _utc(at)).total_seconds() / 3600.0

    def stale(self, at: datetime | None) -> bool:
        age = self.age_h(at)
        return age is not None and age > self.max_age_h


def _utc(moment: datetime) -> datetime:
    return moment if moment.tzinfo is not None else moment.replace(tzinfo=UTC)


def _done_at(job: Job) -> datetime:
    return _utc(job.finished_at or job.created_at)


def machine_profile(row: Machine) -> Profile:
    """The stored profile of ``row`` (profiles stored without them get the defaults;
    keys this service does not know are left to the hardware layer)."""
    known = {k: v for k, v in (row.profile or {}).items() if k in Profile.model_fields}
    try:
        return Profile.model_validate(known)
    except ValidationError as exc:
        where = ".".join(str(p) for p in exc.errors()[0]["loc"])
        raise InvalidInput(f"machine {row.id!r} has a stored profile this service cannot read at profile.{where}: "
                           f"{exc.errors()[0]['msg']}", field=f"profile.{where}", value=row.id) from exc


def _latest_ids(reads: JobReads, machine_id: str) -> dict[tuple[str, int | None], str]:
    """{(kind, tool or None): job id} of the newest succeeded calibration job of each kind
    and tool of ``machine_id`` (reads ids and times only, not the stored results)."""
    rows = reads.succeeded_on_machine(machine_id, KINDS)
    latest: dict[tuple[str, int | None], tuple[datetime, str]] = {}
    for job_id, kind, params, finished, created in rows:
        key = (kind, int(params["tool"]) if kind == "calibrate_nozzle" else None)
        at = _utc(finished or created)
        if key not in latest or at > latest[key][0]:
            latest[key] = (at, job_id)
    return {key: job_id for key, (_at, job_id) in latest.items()}


def latest_calibration_job(reads: JobReads, machine_id: str, kind: str, tool: int | None = None) -> Job | None:
    """The newest succeeded ``kind`` job of the machine (of nozzle ``tool``), or None."""
    job_id = _latest_ids(reads, machine_id).get((kind, tool if kind == "calibrate_nozzle" else None))
    return None if job_id is None else reads.find_job(job_id)


def current_calibration(reads: JobReads, machine_id: str, *, now: datetime | None = None) -> MachineCalibration:
    """The machine's current calibration with its flags (NotFound for an unknown machine)."""
    row = reads.machine(machine_id, field="machine_id")
    profile = machine_profile(row)
    cal = MachineCalibration(max_age_h=float(profile.calibration_max_age_h),
                             now=_utc(now) if now is not None else datetime.now(UTC))
    for (kind, tool), job_id in _latest_ids(reads, machine_id).items():
        job = reads.find_job(job_id)
        if job is None:  # deleted meanwhile
            continue
        if kind == "calibrate_probe":
            cal.probe_result = CalibrateProbeResult.of(job)
            cal.probe, cal.probe_job_id, cal.probe_at = cal.probe_result.calibration(), job_id, _done_at(job)
        elif kind == "calibrate_sensor":
            cal.sensor, cal.sensor_job_id, cal.sensor_at = CalibrateSensorResult.of(job), job_id, _done_at(job)
        elif tool is not None:
            nozzle = CalibrateNozzleResult.of(job)
            cal.nozzles[tool], cal.nozzle_job_ids[tool] = nozzle.calibration(), job_id
            cal.nozzle_at[tool], cal.nozzle_results[tool] = _done_at(job), nozzle
    cal.nozzles = dict(sorted(cal.nozzles.items()))
    cal.flags = _flags(cal)
    return cal


def _flags(cal: MachineCalibration) -> list[str]:
    flags: list[str] = []
    if cal.probe is not None:
        if cal.stale(cal.probe_at):
            flags.append(f"probe calibration is {_age_text(cal.age_h(cal.probe_at))} old (max {cal.max_age_h:g} h)")
        flags += _disagreement_flags("probe", cal.probe_result)
    if cal.sensor is not None and cal.stale(cal.sensor_at):
        flags.append(f"height sensor calibration is {_age_text(cal.age_h(cal.sensor_at))} old "
                     f"(max {cal.max_age_h:g} h)")
    for tool in sorted(cal.nozzles):
        at = cal.nozzle_at[tool]
        if cal.stale(at):
            flags.append(f"nozzle T{tool} calibration is {_age_text(cal.age_h(at))} old (max {cal.max_age_h:g} h)")
        result = cal.nozzle_results[tool]
        flags += _disagreement_flags(f"nozzle T{tool}", result)
        used = result.probe_job_id
        if cal.probe_job_id is not None and used != cal.probe_job_id and \
                (used is not None or cal.probe_at is None or cal.probe_at > at):
            flags.append(f"nozzle T{tool} was calibrated against probe calibration {used} but the probe was "
                         f"re-calibrated since ({cal.probe_job_id}): re-calibrate T{tool} (its Z offset rests on "
                         "the probe's ball radius and pre-travel)")
    return flags


def _age_text(hours: float | None) -> str:
    """"30.1 h", "12 min", "40 s"."""
    hours = hours or 0.0
    if hours >= 1:
        return f"{hours:.1f} h"
    return f"{hours * 60:.0f} min" if hours * 60 >= 1 else f"{hours * 3600:.0f} s"


def _disagreement_flags(what: str, result: CalibrateProbeResult | CalibrateNozzleResult | None) -> list[str]:
    if result is None or not result.agreement.disagrees:
        return []
    agreement = result.agreement
    changes = ", ".join(f"{name} by {agreement.differences_mm.get(name, float('nan')) * 1000:+.1f} um"
                        for name in agreement.disagrees)
    return [f"{what} re-check disagrees with the calibration before it (job {agreement.previous_job_id}): "
            f"{changes}"]


# ---- named values and their uncertainties (what agreement compares) -------------------------
def probe_values(cal: ProbeCalibration) -> tuple[dict[str, float], dict[str, float]]:
    """({name: value mm}, {name: std mm}) of a probe calibration's physical parameters."""
    values = {"ball_radius_mm": cal.ball_radius_mm, "pretravel_mm": cal.pretravel.p0_mm,
              "lobing_cos3_mm": cal.pretravel.cos3_mm, "lobing_sin3_mm": cal.pretravel.sin3_mm}
    std = {name: _std_of(cal.std, name) for name in values}
    return values, std


def _std_of(std: dict[str, float], name: str) -> float:
    """The standard deviation of ``name`` from a core ``std`` dict (keys with or without
    the ``_mm`` suffix; the core's pre-travel names); 0 when the core gives none."""
    aliases = {"pretravel_mm": ("pretravel_mm", "pretravel_p0_mm", "p0_mm", "pretravel", "p0"),
               "lobing_cos3_mm": ("lobing_cos3_mm", "cos3_mm", "pretravel_cos3_mm", "cos3"),
               "lobing_sin3_mm": ("lobing_sin3_mm", "sin3_mm", "pretravel_sin3_mm", "sin3"),
               "ball_radius_mm": ("ball_radius_mm", "ball_radius", "radius_mm", "r")}
    for key in aliases.get(name, (name,)):
        if key in std and std[key] is not None and math.isfinite(std[key]):
            return float(std[key])
    return 0.0


def nozzle_values(cal: NozzleCalibration) -> tuple[dict[str, float], dict[str, float]]:
    """({offset_x_mm, offset_y_mm, offset_z_mm}, their std mm) of a nozzle calibration."""
    names = ("offset_x_mm", "offset_y_mm", "offset_z_mm")
    return ({n: float(v) for n, v in zip(names, cal.offset_mm, strict=True)},
            {n: float(s) for n, s in zip(names, cal.std_mm, strict=True)})


def agreement(previous: Job | None, values: dict[str, float], std: dict[str, float]) -> dict[str, Any]:
    """How a new calibration compares with ``previous`` (a succeeded job of the same
    machine, kind and tool): ``{previous_job_id, differences_mm: {name: new - old},
    disagrees: [names beyond 3 sigma of the combined uncertainty + 2 um]}``."""
    if previous is None:
        return {"previous_job_id": None, "differences_mm": {}, "disagrees": []}
    if previous.kind == "calibrate_probe":
        old, old_std = probe_values(CalibrateProbeResult.of(previous).calibration())
    else:
        old, old_std = nozzle_values(CalibrateNozzleResult.of(previous).calibration())
    bad = disagreements(old, values, old_std, std)
    return {"previous_job_id": previous.id, "differences_mm": {k: values[k] - old[k] for k in values if k in old},
            "disagrees": sorted(bad)}


def require_probe_calibration(reads: JobReads, machine_id: str) -> MachineCalibration:
    """The machine's calibration; 422 when it has no probe calibration yet."""
    cal = current_calibration(reads, machine_id)
    if cal.probe is None:
        raise InvalidInput(f"machine {machine_id!r} has no probe calibration: calibrate the probe first "
                           "(job calibrate_probe)", field="params.machine_id", value=machine_id)
    return cal


# ---- the operator's summary (GET /machines/{id}/calibration) --------------------------------
def _um(value_mm: float | None) -> float | None:
    return None if value_mm is None else round(float(value_mm) * 1000.0, 3)


def calibration_summary(machine_id: str, cal: MachineCalibration, profile: Profile) -> dict[str, Any]:
    """Values in mm, standard deviations and residuals in um (``_um``), ages in hours,
    the job ids and flags; every nozzle of the profile (``calibrated: false`` when not)."""
    probe = None
    if cal.probe is not None:
        values, std = probe_values(cal.probe)
        probe = {"job_id": cal.probe_job_id, "calibrated_at": cal.probe_at, "age_h": cal.age_h(cal.probe_at),
                 "stale": cal.stale(cal.probe_at), **values, **{f"{k[:-3]}_std_um": _um(v) for k, v in std.items()},
                 "sphere_centre_mm": list(cal.probe.sphere_centre_mm), "pad_reading_z_mm": cal.probe.pad_reading_z_mm,
                 "residual_rms_um": _um(cal.probe.residual_rms_mm), "touches": cal.probe.touches,
                 "disagrees": list(cal.probe_result.agreement.disagrees) if cal.probe_result is not None else []}
    nozzles = []
    for nozzle in (profile.tools.nozzles if profile.tools is not None else []):
        entry: dict[str, Any] = {"tool": nozzle.tool, "name": nozzle.name,
                                 "outer_diameter_mm": nozzle.outer_diameter_mm,
                                 "nominal_offset_mm": list(nozzle.offset_mm), "calibrated": nozzle.tool in cal.nozzles}
        if nozzle.tool in cal.nozzles:
            found, at, result = cal.nozzles[nozzle.tool], cal.nozzle_at[nozzle.tool], cal.nozzle_results[nozzle.tool]
            entry.update(job_id=cal.nozzle_job_ids[nozzle.tool], calibrated_at=at, age_h=cal.age_h(at),
                         stale=cal.stale(at), offset_mm=list(found.offset_mm),
                         offset_std_um=[_um(s) for s in found.std_mm],
                         nominal_difference_mm=[c - n for c, n in zip(found.offset_mm, nozzle.offset_mm, strict=True)],
                         probe_job_id=result.probe_job_id, touches=found.touches,
                         disagrees=list(result.agreement.disagrees))
        nozzles.append(entry)
    sensor = None
    if cal.sensor is not None:
        stored = cal.sensor
        sensor = {"job_id": cal.sensor_job_id, "calibrated_at": cal.sensor_at, "age_h": cal.age_h(cal.sensor_at),
                  "stale": cal.stale(cal.sensor_at), "sensor_port": stored.sensor_port, "offset_mm": stored.offset_mm,
                  "scale": stored.scale, "time_offset_s": stored.time_offset_s, "slope_bias_mm": stored.slope_bias_mm}
    return {"machine_id": machine_id, "max_age_h": cal.max_age_h, "probe": probe, "nozzles": nozzles,
            "sensor": sensor, "flags": list(cal.flags)}
