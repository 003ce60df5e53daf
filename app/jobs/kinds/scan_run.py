"""Job ``scan_run``: measure the traces' region with the laser height sensor instead of touching.

Plans scan passes (:func:`app.probing.scan_plan.plan_scans`: passes along the traces or
rasters over the part's nominal top, per tile the cheaper in machine time), drives them on
the machine with the sensor (:mod:`app.jobs.sensor_runs`), turns the stored readings into
deviations with the sensor's calibration (:mod:`app.reconstruction.scan_samples`; on a
``linuxcnc://`` machine the controller samples the sensor with its joints, elsewhere the
sensor is read over ``sensor_port``: :func:`app.jobs.sensor_runs.open_scanner`), fits the
field by the inducing-point solve (:mod:`app.reconstruction.scan_field`), touches
``verify_count`` verification points with the probe where the fitted field is least certain
and checks the field there (:func:`app.reconstruction.scan_field.verify_touches`).  Artifact
``samples.npz``: every sample's x, y (the spot), z (the surface), t (s after its pass's
start) and valid, and the pass it belongs to.  Result: the plan's machine time (cost
model), the field check and each trace's largest predicted deviation and bound.

Artifacts ``pass-NNNN.npz`` (each finished pass's rows and fit points) let a run resume:
when the link drops (or the server dies) the job becomes ``interrupted`` with the finished
passes counted in ``program_state``; an operator's resume re-homes, reads the finished
passes back and drives the interrupted pass again from its start (a pass is idempotent),
then the rest.  Any other failure stops the job (nothing moves afterwards).
"""

from __future__ import annotations

import io
import math
from typing import Any

import numpy as np
from pydantic import Field
from sqlmodel import Session

from app.calibration.sensor import SensorCalibration
from app.errors import InvalidInput
from app.jobs.context import JobContext
from app.jobs.inputs import nominal_of
from app.jobs.machine_jobs import (interrupt, refuse_if_machine_busy, rehomed_machine, resume_request,
                                   stopped_by_operator)
from app.jobs.registry import JobParams, job_kind
from app.jobs.sensor_runs import open_scanner
from app.machines import hardware_errors, profile_of
from app.probing.deviation_prior import DeviationPrior, Sites, path_sites
from app.probing.scan_cost import MotionCost, touch_time
from app.probing.scan_plan import plan_scans
from app.reconstruction.scan_field import fit_scan_field, verify_touches
from app.reconstruction.scan_samples import block_average, carriage_deviations
from hardware.errors import HardwareError, LinkError


class ScanRunParams(JobParams):
    machine_id: str
    trace_ids: list[str] = Field(min_length=1, max_length=5000)
    sensor_port: str | None = Field(None, max_length=500, description=(
        "the sensor's link: lkg://NAME (the mock), /dev/ttyUSB1, socket://host:port; not used on a linuxcnc:// "
        "machine (the controller samples the sensor with its joints)"))
    sensor_rate_hz: float = Field(2000.0, gt=0, le=100_000, description="the sensor controller's sampling rate "
                                  "(a linuxcnc:// machine samples once per servo period)")
    calibration: dict[str, Any] = Field(description="the sensor's calibration: offset_mm [x, y, z], scale, "
                                        "time_offset_s, slope_bias_mm (app.calibration.sensor.SensorCalibration)")
    mode: str = Field("mixed", pattern="^(mixed|traces|raster)$")
    spacing_mm: float = Field(5.0, gt=0, le=100, description="raster line spacing")
    scan_speed_mm_s: float = Field(100.0, gt=0, le=1000)
    block: int = Field(5, ge=1, le=1000, description="samples averaged per fitted point")
    deviation_amplitude_mm: float = Field(0.2, gt=0, le=10)
    deviation_wavelength_mm: float = Field(20.0, gt=0, le=1000)
    sensor_sigma_mm: float = Field(0.0005, gt=0, le=1)
    coverage: float = Field(3.0, gt=0, le=10)
    probe_sigma_mm: float = Field(0.001, gt=0, le=1, description="the probe's repeatability (verification touches)")
    verify_count: int = Field(5, ge=0, le=50)


def _check(params: ScanRunParams, session: Session) -> None:
    try:
        SensorCalibration.from_dict(params.calibration)
    except (KeyError, TypeError, ValueError) as exc:
        raise InvalidInput(f"calibration: {exc}", field="params.calibration", value=str(params.calibration)[:80]) \
            from None
    refuse_if_machine_busy(params.machine_id, session)


def _top(mesh: Any) -> tuple[Any, Any]:
    """The part's nominal top as height(xy (n, 2)) -> (n,) and slope(xy) -> (n, 2) (vertical rays)."""
    top = float(mesh.bounds[1][2]) + 1.0

    def hits(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        z, g = np.full(len(xy), np.nan), np.zeros((len(xy), 2))
        tris, rays, where = mesh.ray.intersects_id(np.column_stack([xy, np.full(len(xy), top)]),
                                                   np.tile([0.0, 0.0, -1.0], (len(xy), 1)), multiple_hits=False,
                                                   return_locations=True)
        z[rays] = where[:, 2]
        n = mesh.face_normals[tris]
        g[rays] = -n[:, :2] / np.maximum(n[:, 2:3], 1e-6)
        return z, g

    return (lambda xy: hits(xy)[0]), (lambda xy: hits(xy)[1])


def _pass_name(k: int) -> str:
    return f"pass-{k:04d}.npz"


def _scanned_passes(ctx: JobContext, count: int) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """The rows (n, 6) and fit points (xy (m, 2), dz (m,)) of this job's first ``count``
    passes, from their artifacts (a resumed run)."""
    found = ctx.artifacts_of([(ctx.job_id, _pass_name(k)) for k in range(count)])
    rows, xy, dz = [], [], []
    for k in range(count):
        data = np.load(io.BytesIO(ctx.blob(found[(ctx.job_id, _pass_name(k))].sha256)))
        rows.append(data["rows"])
        xy.append(data["xy"])
        dz.append(data["dz"])
    return rows, xy, dz


@job_kind("scan_run", ScanRunParams, queue="machine", check=_check,
          references=lambda p: [("machine", p.machine_id), *(("trace", t) for t in p.trace_ids)])
def run(ctx: JobContext, params: ScanRunParams) -> dict:
    """Scan the traces' region, fit the field, verify it with probe touches."""
    traces = [ctx.trace(t) for t in params.trace_ids]
    paths = [nominal_of(t) for t in traces]
    height, slope = _top(ctx.mesh(traces[0].part_id))
    calibration = SensorCalibration.from_dict(params.calibration)
    profile = profile_of(ctx.machine(params.machine_id))
    cost = MotionCost(travel_mm_s=profile.travel_feed_mm_min / 60.0, probe_mm_s=profile.probe_feed_mm_min / 60.0,
                      scan_mm_s=params.scan_speed_mm_s)
    every = np.concatenate([p.points[:, :2] for p in paths])
    lo, hi = every.min(axis=0) - 1.0, every.max(axis=0) + 1.0
    plan = plan_scans(paths, height, (lo[0], lo[1], hi[0], hi[1]), cost, params.spacing_mm, mode=params.mode)
    travel_z = float(max(np.nanmax(height(every)), max(float(p.points[:, 2].max()) for p in paths))) \
        - calibration.offset_mm[2] + profile.clearance_z
    resume = resume_request(ctx)
    state: dict[str, Any] = {"total": len(plan.passes), "executed": int((resume or {}).get("executed", 0)),
                             "resumes": int((resume or {}).get("resumes", 0))}
    rows, xy_fit, dz_fit = _scanned_passes(ctx, state["executed"])
    machine = rehomed_machine(ctx, params.machine_id, resume, state)

    def guarded(action: Any, *args: Any, **kwargs: Any) -> Any:
        """``action(*args, **kwargs)`` on the machine; a lost link (or an operator's stop)
        interrupts the job."""
        try:
            return action(*args, **kwargs)
        except LinkError as exc:
            raise interrupt(ctx, machine, exc, state) from exc
        except HardwareError as exc:
            if stopped_by_operator(ctx, machine):
                raise interrupt(ctx, machine, exc, state) from exc
            raise

    with ctx.runtime.machines.lease(params.machine_id, ctx.job_id), hardware_errors():
        scanner = open_scanner(machine, params.sensor_port, params.sensor_rate_hz)
        first = state["executed"]
        try:
            for k in range(first, len(plan.passes)):
                w = plan.passes[k].carriage(calibration.offset_mm)
                hop = travel_z if plan.passes[k].hop or k == first else None  # a resumed run starts homed
                data = guarded(scanner.run, w, cost.scan_mm_s, hop, calibration.time_offset_s)
                ok = np.isfinite(data.values)
                z = np.where(ok, calibration.surface_z(data.carriage, np.nan_to_num(data.values)), np.nan)
                xy = calibration.spot_xy(data.carriage)
                rows.append(np.column_stack([xy, z, data.stamps, ok, np.full(len(ok), k)]))
                got_xy, got_dz = carriage_deviations(data.carriage, data.values, calibration, height, slope)
                got_xy, got_dz = block_average(got_xy, got_dz, params.block)
                xy_fit.append(got_xy)
                dz_fit.append(got_dz)
                buf = io.BytesIO()
                np.savez_compressed(buf, rows=rows[-1], xy=got_xy, dz=got_dz)
                ctx.artifact(_pass_name(k), buf.getvalue(), "application/octet-stream", {"samples": int(len(ok))})
                state["executed"] = k + 1
                ctx.runtime.store.save_program_state(ctx.claim, state)
                ctx.progress(0.8 * (k + 1) / len(plan.passes), f"scanned {k + 1}/{len(plan.passes)} passes")
            guarded(machine.move, z=travel_z)
        finally:
            scanner.close()
        samples = np.concatenate(rows)
        buf = io.BytesIO()
        np.savez_compressed(buf, x=samples[:, 0], y=samples[:, 1], z=samples[:, 2], t=samples[:, 3],
                            valid=samples[:, 4].astype(bool), pass_index=samples[:, 5].astype(int))
        ctx.artifact("samples.npz", buf.getvalue(), "application/octet-stream",
                     {"samples": int(len(samples)), "valid": int(samples[:, 4].sum())})
        ctx.progress(0.85, "fitting the field")
        prior = DeviationPrior(amplitude_mm=params.deviation_amplitude_mm,
                               wavelength_mm=params.deviation_wavelength_mm,
                               sigma_mm=params.sensor_sigma_mm / math.sqrt(params.block))
        xy, dz = np.concatenate(xy_fit), np.concatenate(dz_fit)
        fit = fit_scan_field(prior, Sites(xy, slope(xy)), dz, (lo + hi) / 2, slope)
        sites = [path_sites(p, np.linspace(0.0, p.length_mm, 9)) for p in paths]
        trace_sd = [float(fit.posterior.sd(s).max()) for s in sites]
        query = Sites(np.concatenate([s.xy for s in sites]), np.concatenate([s.grad for s in sites]))
        owner = np.repeat(np.arange(len(paths)), 9)
        sd = fit.posterior.sd(query)
        picked = list(np.argsort(sd)[::-1][:params.verify_count])
        vsites = query.take(np.array(picked, dtype=int))
        touched = [guarded(machine.probe, float(x), float(y), z_start=float(z_nom) + profile.clearance_z,
                           z_min=float(z_nom) - profile.clearance_z).z
                   for (x, y), z_nom in zip(vsites.xy, height(vsites.xy))]
    check = verify_touches(fit, vsites, np.asarray(touched) - height(vsites.xy), owner[picked], params.coverage,
                           params.probe_sigma_mm) if picked else None
    bound = params.coverage * max(trace_sd)
    return {
        "passes": len(plan.passes), "resumes": state["resumes"], "tiles": plan.tiles, "scan_length_mm": plan.length_mm,
        "machine_s": {"scan": plan.scan_s, "links": plan.link_s,
                      "verification": touch_time(cost, vsites.xy) if picked else 0.0},
        "samples": int(len(samples)), "valid": int(samples[:, 4].sum()), "fitted_points": int(len(dz)),
        "outliers": len(fit.outliers), "bound_mm": bound,
        "verification": None if check is None else {
            "max_abs_residual_mm": check.max_abs_residual_mm, "within": bool(check.within.all()),
            "residual_mm": check.residual_mm.tolist(), "limit_mm": check.limit_mm.tolist()},
        "traces": [{"trace_id": t.id, "bound_mm": params.coverage * s,
                    "max_abs_deviation_mm": float(np.abs(fit.deviation(site)).max())}
                   for t, s, site in zip(traces, trace_sd, sites)],
    }
