"""Job ``scan_run``: measure the traces' region with the laser height sensor instead of touching.

Plans scan passes (:func:`app.probing.scan_plan.plan_scans`: passes along the traces or
rasters over the part's nominal top, per tile the cheaper in machine time), drives them on
the machine with the sensor, each pass stored as it is made (:mod:`app.jobs.scan_passes`; on a
``linuxcnc://`` machine the controller samples the sensor with its joints, elsewhere the
sensor is read over ``sensor_port``: :func:`app.jobs.sensor_runs.open_scanner`),
turns the readings into deviations with the sensor's calibration (given, or the machine's
stored one: :mod:`app.jobs.sensor_calibration`; :mod:`app.reconstruction.scan_samples`),
fits the field by the inducing-point solve (:mod:`app.reconstruction.scan_field`), touches
up to ``gap_touches`` trace points the samples left too uncertain for the target (the sensor
dropped out on steep flanks or dark spots) and fits again, then touches ``verify_count``
verification points where the field is least certain and checks it there
(:func:`app.reconstruction.scan_field.verify_touches`).  Artifacts: ``samples.npz`` (every
sample's x, y (the spot), z (the surface), t (s after its pass's start), valid and pass
index), ``field.npz`` (the checked field, :mod:`app.reconstruction.scan_field_store`: what
``reconstruct`` with ``scan_run_job_id`` rebuilds the traces from) and ``pass.<k>.npz``.
Result: the plan's machine time (cost model), the field check (its bound over every trace,
the verification) and each trace's bound and largest deviation.

A dropped link interrupts the job (it waits for an operator; a resume keeps the stored
passes and continues at the next one); another failure stops it (nothing moves afterwards).
"""

from __future__ import annotations

import io
import math
from typing import Any

import numpy as np
from pydantic import Field

from app.calibration.correct import surface_heights
from app.jobs.inputs import nominal_of
from app.jobs.probe_correction import machine_probe
from app.jobs.scan_passes import interrupting, scan_passes
from app.jobs.sensor_calibration import scan_calibration
from app.jobs.sensor_runs import require_sensor_port
from app.machines.live import profile_of
from app.probing.deviation_prior import DeviationPrior, Sites, path_sites
from app.probing.scan_cost import MotionCost, touch_order, touch_time
from app.probing.scan_plan import plan_scans
from app.reconstruction.field_trust import trace_bound, with_bound
from app.reconstruction.scan_field import ScanFieldCheck, fit_scan_field, gap_sites, verify_touches
from app.reconstruction.scan_field_store import scan_check_npz
from app.reconstruction.scan_samples import block_average, carriage_deviations
from app.runtime.context import JobContext
from app.runtime.machine_queue import refuse_if_machine_busy
from app.runtime.reads import JobReads
from app.runtime.registry import JobParams, job_kind


class ScanRunParams(JobParams):
    machine_id: str
    trace_ids: list[str] = Field(min_length=1, max_length=5000)
    sensor_port: str | None = Field(None, max_length=500, description=(
        "the sensor's link: lkg://NAME (the mock), /dev/ttyUSB1, socket://host:port; not used on a linuxcnc:// "
        "machine (the controller samples the sensor with its joints)"))
    sensor_rate_hz: float = Field(2000.0, gt=0, le=100_000, description="the sensor controller's sampling rate "
                                  "(a linuxcnc:// machine samples once per servo period)")
    calibration: dict[str, Any] | None = Field(None, description="the sensor's calibration: offset_mm [x, y, z], "
                                               "scale, time_offset_s, slope_bias_mm (app.calibration.sensor."
                                               "SensorCalibration); default: the machine's stored one (the newest "
                                               "calibrate_sensor job)")
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
    gap_touches: int = Field(20, ge=0, le=200, description="at most this many probe touches where the samples left "
                             "the field too uncertain for the target (the sensor dropped out on steep flanks or dark "
                             "spots), made before the field is fitted again and verified")
    target_error_mm: float = Field(0.005, gt=0, le=1, description="the bound the field must reach over every trace "
                                   "(a larger one asks for attention: scan finer)")


def _check(params: ScanRunParams, reads: JobReads) -> None:
    row = reads.machine(params.machine_id, field="params.machine_id")
    require_sensor_port(params.machine_id, row.port, params.sensor_port, "params.sensor_port")
    scan_calibration(reads, params.machine_id, params.calibration)
    refuse_if_machine_busy(params.machine_id, reads)


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


def _touch(machine: Any, profile: Any, height: Any, slope: Any, xy: np.ndarray, probe: Any) -> np.ndarray:
    """Probe touches at xy (k, 2): the measured deviation (k,) mm from the nominal top; with a
    calibrated probe (``probe``: :class:`app.jobs.probe_correction.MachineProbe`) each reading
    is corrected for the ball radius and the pre-travel along the nominal normal, as a
    probe run's are (no drift correction)."""
    nominal = height(xy)
    if not len(xy):
        return np.zeros(0)
    got = [machine.probe(float(x), float(y), z_start=float(h) + profile.clearance_z,
                         z_min=float(h) - profile.clearance_z) for (x, y), h in zip(xy, nominal)]
    readings = np.array([[r.x, r.y, r.z] for r in got], dtype=float)
    if probe is None:
        return readings[:, 2] - nominal
    g = np.asarray(slope(xy), dtype=float)
    normals = np.column_stack([-g, np.ones(len(g))])
    out: np.ndarray = surface_heights(readings, normals / np.linalg.norm(normals, axis=1, keepdims=True),
                                      probe.calibration).z_mm - nominal
    return out


@job_kind("scan_run", ScanRunParams, queue="machine", check=_check,
          references=lambda p: [("machine", p.machine_id), *(("trace", t) for t in p.trace_ids)])
def run(ctx: JobContext, params: ScanRunParams) -> dict:
    """Scan the traces' region, fit the field, verify it with probe touches."""
    traces = [ctx.trace(t) for t in params.trace_ids]
    paths = [nominal_of(t) for t in traces]
    height, slope = _top(ctx.mesh(traces[0].part_id))
    with ctx.reads() as reads:
        calibration, calibration_source = scan_calibration(reads, params.machine_id, params.calibration)
    profile = profile_of(ctx.machine(params.machine_id))
    cost = MotionCost(travel_mm_s=profile.travel_feed_mm_min / 60.0, probe_mm_s=profile.probe_feed_mm_min / 60.0,
                      scan_mm_s=params.scan_speed_mm_s)
    every = np.concatenate([p.points[:, :2] for p in paths])
    lo, hi = every.min(axis=0) - 1.0, every.max(axis=0) + 1.0
    plan = plan_scans(paths, height, (lo[0], lo[1], hi[0], hi[1]), cost, params.spacing_mm, mode=params.mode)
    travel_z = float(max(np.nanmax(height(every)), max(float(p.points[:, 2].max()) for p in paths))) \
        - calibration.offset_mm[2] + profile.clearance_z
    rows: list[np.ndarray] = []
    xy_fit, dz_fit = [], []
    waypoints = [p.carriage(calibration.offset_mm) for p in plan.passes]
    probe = machine_probe(ctx, params.machine_id)
    scanned, machine, state = scan_passes(ctx, params.machine_id, params.sensor_port, params.sensor_rate_hz,
                                          waypoints, [p.hop for p in plan.passes], cost.scan_mm_s, travel_z,
                                          calibration.time_offset_s, probe is not None)
    for k, one in enumerate(scanned):
        ok = np.isfinite(one.values)
        z = np.where(ok, calibration.surface_z(one.carriage, np.nan_to_num(one.values)), np.nan)
        rows.append(np.column_stack([calibration.spot_xy(one.carriage), z, one.stamps, ok, np.full(len(ok), k)]))
        got_xy, got_dz = carriage_deviations(one.carriage, one.values, calibration, height, slope)
        got_xy, got_dz = block_average(got_xy, got_dz, params.block)
        xy_fit.append(got_xy)
        dz_fit.append(got_dz)
    with ctx.lease(params.machine_id), interrupting(ctx, machine, state):
        machine.move(z=travel_z)
        if probe is not None:
            machine.select_tool(0)  # the calibrated probe touches
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
        gaps, _ = gap_sites(fit, paths, params.coverage, params.target_error_mm, params.gap_touches)
        gaps = gaps.take(touch_order(gaps.xy, plan.passes[-1].spot[-1, :2]))  # from where the scan ended
        if len(gaps.xy):  # the sensor left holes (steep flanks, dark spots): touch them and fit again
            ctx.progress(0.88, f"touching {len(gaps.xy)} points the sensor could not see")
            xy, dz = (np.concatenate([xy, gaps.xy]),
                      np.concatenate([dz, _touch(machine, profile, height, slope, gaps.xy, probe)]))
            noise = np.concatenate([np.full(len(dz) - len(gaps.xy), prior.sigma_mm),
                                    np.full(len(gaps.xy), params.probe_sigma_mm)])
            fit = fit_scan_field(prior, Sites(xy, slope(xy)), dz, (lo + hi) / 2, slope, noise_mm=noise)
        sites = [path_sites(p, np.linspace(0.0, p.length_mm, 9)) for p in paths]
        trace_sd = [float(fit.posterior.sd(s).max()) for s in sites]
        query = Sites(np.concatenate([s.xy for s in sites]), np.concatenate([s.grad for s in sites]))
        owner = np.repeat(np.arange(len(paths)), 9)
        sd = fit.posterior.sd(query)
        picked = list(np.argsort(sd)[::-1][:params.verify_count])
        last = gaps.xy[-1] if len(gaps.xy) else plan.passes[-1].spot[-1, :2]
        picked = [picked[i] for i in touch_order(query.xy[picked], last)]  # the touches in a short tour
        vsites = query.take(np.array(picked, dtype=int))
        touched = _touch(machine, profile, height, slope, vsites.xy, probe)
    verification = verify_touches(fit, vsites, touched, owner[picked], params.coverage,
                                  params.probe_sigma_mm) if picked else None
    bounds = [trace_bound(fit, p, params.coverage) for p in paths]
    check = with_bound(ScanFieldCheck(fit, None, verification, params.coverage, params.target_error_mm,
                                      touch_sigma_mm=params.probe_sigma_mm), bounds)
    ctx.artifact("field.npz", scan_check_npz(check), "application/octet-stream",
                 {"fitted_points": int(len(dz)), "inducing": int(len(fit.posterior.alpha))})
    return {
        "passes": len(plan.passes), "tiles": plan.tiles, "scan_length_mm": plan.length_mm,
        "machine_s": {"scan": plan.scan_s, "links": plan.link_s,
                      "gap_touches": touch_time(cost, gaps.xy) if len(gaps.xy) else 0.0,
                      "verification": touch_time(cost, vsites.xy) if picked else 0.0},
        "samples": int(len(samples)), "valid": int(samples[:, 4].sum()), "fitted_points": int(len(dz)),
        "outliers": len(fit.outliers), "bound_mm": check.bound_mm, "gap_touches": int(len(gaps.xy)),
        "resumes": int(state["resumes"]), "calibration": calibration_source,
        "field_check": {k: v for k, v in check.as_dict().items() if k != "exclusions"},
        "verification": None if verification is None else {
            "max_abs_residual_mm": verification.max_abs_residual_mm, "within": bool(verification.within.all()),
            "residual_mm": verification.residual_mm.tolist(), "limit_mm": verification.limit_mm.tolist()},
        "traces": [{"trace_id": t.id, "bound_mm": b, "max_posterior_sd_mm": s,
                    "max_abs_deviation_mm": float(np.abs(fit.deviation(site)).max())}
                   for t, b, s, site in zip(traces, bounds, trace_sd, sites)],
    }
