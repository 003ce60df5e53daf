"""Job ``calibrate_sensor``: the laser height sensor's time offset, offset, scale and tilt bias.

Runs the three procedures of :mod:`app.calibration.sensor` on the machine's reference
artifacts (:func:`app.jobs.sensor_runs.calibrate_sensor`): still readings over the pad at
heights across the range (scale, z offset), passes across the pad's edge both ways (time
offset), a serpentine raster over the datum sphere's cap (lateral offset, tilt bias).  The
pad's top height and the sphere's centre come from the machine's current probe calibration
(``calibrate_probe``: the pad surface and the qualified sphere centre in the probe frame);
without one the probe touches the pad's centre once and the sphere is taken at the profile's
nominal place (exact for an ideal probe only: the result's ``references.source`` says which).
The sensor is read over ``sensor_port``, or on a ``linuxcnc://`` machine by the controller
sampling it with the joints (:func:`app.jobs.sensor_runs.open_scanner`; no port).

The result (:class:`app.jobs.results.calibration.CalibrateSensorResult`) is the stored
calibration: ``scan_run`` and ``closed_loop`` (measuring by scan) use the machine's newest
one unless a calibration is given (:mod:`app.jobs.sensor_calibration`).  A failure stops
the job (nothing moves afterwards); it is run again whole.
"""

from __future__ import annotations

from pydantic import Field

from app.domain.errors import InvalidInput
from app.jobs.calibration import current_calibration, machine_profile
from app.jobs.calibration_touch import travel_height
from app.jobs.results.calibration import CalibrateSensorResult
from app.jobs.sensor_runs import CalibrationSetup, calibrate_sensor, open_scanner, require_sensor_port
from app.machines.live import hardware_errors
from app.runtime.context import JobContext
from app.runtime.machine_queue import connected_machine, refuse_if_machine_busy
from app.runtime.reads import JobReads
from app.runtime.registry import JobParams, job_kind

PAD_TOUCH_FROM_MM = 2.0  # without a probe calibration: the pad touch starts this far above its nominal top


class CalibrateSensorParams(JobParams):
    machine_id: str
    sensor_port: str | None = Field(None, max_length=500, description=(
        "the sensor's link: lkg://NAME (the mock), /dev/ttyUSB1, socket://host:port; not used on a linuxcnc:// "
        "machine (the controller samples the sensor with its joints)"))
    sensor_rate_hz: float = Field(2000.0, gt=0, le=100_000, description="the sensor controller's sampling rate "
                                  "(a linuxcnc:// machine samples once per servo period)")
    nominal_offset_mm: list[float] = Field(min_length=3, max_length=3, description="the sensor's spot and zero "
                                           "relative to the carriage as mounted [x, y, z] mm (known to a few 0.1 mm)")
    range_mm: float = Field(5.0, gt=0, le=100, description="the sensor's half measuring range, mm")
    edge_passes: int = Field(4, ge=1, le=20, description="passes across the pad's edge each way")
    still_heights: int = Field(9, ge=3, le=50, description="heights of the still readings over the pad")
    sphere_lines: int = Field(9, ge=3, le=50, description="raster lines over the sphere's cap")


def _check(params: CalibrateSensorParams, reads: JobReads) -> None:
    row = reads.machine(params.machine_id, field="params.machine_id")
    require_sensor_port(params.machine_id, row.port, params.sensor_port, "params.sensor_port")
    profile = machine_profile(row)
    for name in ("pad", "sphere"):
        if profile.reference is None or getattr(profile.reference, name) is None:
            raise InvalidInput(f"machine {params.machine_id!r} has no reference {name} in its profile "
                               f"(profile.reference.{name}): the sensor is calibrated on the pad and sphere",
                               field=f"profile.reference.{name}", value=params.machine_id)
    refuse_if_machine_busy(params.machine_id, reads)


@job_kind("calibrate_sensor", CalibrateSensorParams, queue="machine", check=_check,
          references=lambda p: [("machine", p.machine_id)])
def run(ctx: JobContext, params: CalibrateSensorParams) -> dict:
    """Calibrate the height sensor on the reference pad and sphere (module docstring)."""
    profile = machine_profile(ctx.machine(params.machine_id))
    pad, sphere = profile.reference.pad, profile.reference.sphere  # type: ignore[union-attr]
    assert pad is not None and sphere is not None  # _check
    with ctx.reads() as reads:
        probe = current_calibration(reads, params.machine_id)
    o = [float(v) for v in params.nominal_offset_mm]
    machine = connected_machine(ctx, params.machine_id)
    with ctx.lease(params.machine_id), hardware_errors():
        travel = travel_height(profile, 0.0 if probe.probe is None else probe.probe.ball_radius_mm) \
            + max(0.0, -o[2]) + params.range_mm
        pad_z = None if probe.probe is None else probe.probe.pad_surface_z_mm()
        if pad_z is None:
            ctx.progress(0.02, "touching the pad's centre")
            machine.move(z=travel)
            top = float(pad.centre_mm[2])
            pad_z = machine.probe(float(pad.centre_mm[0]), float(pad.centre_mm[1]), z_start=top + PAD_TOUCH_FROM_MM,
                                  z_min=top - PAD_TOUCH_FROM_MM).z
            machine.move(z=travel)
        centre = tuple(probe.probe.sphere_centre_mm) if probe.probe is not None else tuple(sphere.centre_mm)
        setup = CalibrationSetup((float(pad.centre_mm[0]), float(pad.centre_mm[1]), float(pad_z)), float(pad.size_mm),
                                 (float(centre[0]), float(centre[1]), float(centre[2])), float(sphere.diameter_mm) / 2,
                                 (o[0], o[1], o[2]), params.range_mm, travel_z=travel,
                                 edge_passes=params.edge_passes, still_heights=params.still_heights,
                                 sphere_lines=params.sphere_lines)
        ctx.progress(0.05, "calibrating the sensor on the pad and the sphere")
        scanner = open_scanner(machine, params.sensor_port, params.sensor_rate_hz)
        try:
            calibration, report = calibrate_sensor(machine, scanner, setup)
        finally:
            scanner.close()
    source = "probe calibration" if probe.probe is not None else "pad touched once, sphere at its nominal place"
    return CalibrateSensorResult.written({
        **calibration.to_dict(), "sensor_port": params.sensor_port, "sensor_rate_hz": params.sensor_rate_hz,
        "references": {"source": source, "probe_job_id": probe.probe_job_id, "pad_top_z_mm": float(pad_z),
                       "sphere_centre_mm": [float(c) for c in centre]},
        "report": report})
