"""Nozzle offset calibration: the documented, testable procedure (tip = carriage + offset, mm).

The probe (T0) defines machine coordinates (its ball centre).  A nozzle's tip is at
carriage + o; o is known only roughly (nominal, +-0.2 mm) until measured here.  The nozzle
closes a contact when its metal body touches a conductive reference artifact (the pad, the
sphere), with no pre-travel (touch-off scatter only).  The nozzle body is a vertical
flat-ended cylinder of outer diameter D with its tip at the bottom.

Z, on the reference pad (``pad_touches`` spots on a 2-D grid 0.5 mm apart around the pad centre,
``pad_grid``; the pad is a flat square, e.g. 20 mm):
  1. the probe (T0) touches each spot vertically: the pad surface in the probe frame is
     ``pad_z = mean(z_read) + delta(+Z) - r`` (the calibrated pre-travel and radius);
  2. the nozzle touches the SAME spots (carriage placed with the nominal offset so that its
     tip is over the spot), flat end down: at contact tip_z = pad_z, so
     ``o_z = pad_z - mean(carriage z at contact)``.
  Touching the same spots cancels pad flatness; the touches run in four blocks, the probe on
  the first half of the spots, the nozzle on the first half, the nozzle on the second half,
  the probe on the second half (P N N P: three tool changes), so the probe's and the nozzle's
  touches have the same mean time and a linear Z drift cancels between their means whatever
  each tool's touch takes.  Within a block the next spot is reached by a hop at the start
  height (``Touch.local``).
  Uncertainty: o_z's variance is var(p0 - r) (the qualification) + s_p^2 / N + s_n^2 / N for N
  spots, s_p and s_n a probe and a nozzle touch's scatter: with the mock's 2 um pre-travel
  scatter, 1 um noise and 1 um reports (s_p 2.26 um, s_n 1.04 um) and the default qualification
  (sd(p0 - r) ~0.17 um), N = 144 gives 0.27 um (24 spots gave 0.6 um).

XY, on the reference sphere (centre c known in the probe frame from the qualification):
  3. the nozzle, tip ~0.3 R below the sphere's centre height (so its cylindrical side meets
     the sphere's equator at horizontal distance R + D/2 from c), approaches horizontally from
     +X, -X, +Y and -Y (``side_touches`` each), aimed at c with the nominal offset;
  4. opposite touches are symmetric about c: the tip x at the +X and -X contacts is
     ``c_x +- sqrt((R + D/2)^2 - e_y^2)`` (e_y = the y error of the aim), so the midpoint
     of the two carriage readings is c_x - o_x whatever R, D and e_y are:
     ``o_x = c_x - (mean(x_+) + mean(x_-)) / 2`` and likewise o_y.
  With ``side_touches`` = n per side the touch term is s_n / 2 * sqrt(2 / n): 0.21 um for n = 12,
  in quadrature with the sphere centre's ~0.1 um.
The calibration job runs this plan twice: once with one spot and one touch per side at the
full ``clearance_mm`` (the nominal offset is known to +-0.2 mm), then the full plan from the
located offset and pad height with a short approach (0.3 mm).
Standard deviations: the spread of the repeated touches (pooled per group) propagated to the
means, in quadrature with the probe calibration's uncertainty (sphere centre for XY; for Z
the std of p0 - r from the qualification's covariance).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
import numpy.typing as npt

from app.calibration.errors import CalibrationError
from app.calibration.model import NozzleCalibration, ProbeCalibration, Touch, _vec3
from app.calibration.qualify import PAD_SPACING_MM, check_readings

__all__ = ["plan_nozzle_calibration", "fit_nozzle_offset", "pad_grid", "TIP_BELOW_EQUATOR", "SIDES"]

TIP_BELOW_EQUATOR = 0.3          # tip height below the sphere centre, in sphere radii
OVERTRAVEL_MM = 1.0
#: a side touch's unit direction may have components this large off its x or y axis
_OFF_AXIS_SLACK = 1e-6
SIDES = {"+x": (1.0, 0.0), "-x": (-1.0, 0.0), "+y": (0.0, 1.0), "-y": (0.0, -1.0)}


def _positive(value: float, name: str) -> float:
    v = float(value)
    if not math.isfinite(v) or v <= 0:
        raise CalibrationError(f"{name} must be a finite number > 0", field=name, value=value)
    return v


def pad_grid(count: int) -> tuple[int, int]:
    """Columns and rows of the square-ish grid of ``count`` pad spots (``PAD_SPACING_MM`` apart)."""
    cols = max(1, math.ceil(math.sqrt(count)))
    return cols, math.ceil(count / cols)


def _pad_spots(pad: npt.NDArray[np.float64], count: int) -> list[tuple[float, float]]:
    """``count`` spots on a 2-D grid centred on the pad, row by row in serpentine order."""
    cols, rows = pad_grid(count)
    spots = []
    for k in range(count):
        row, col = divmod(k, cols)
        if row % 2:
            col = cols - 1 - col
        spots.append((pad[0] + (col - (cols - 1) / 2) * PAD_SPACING_MM,
                     pad[1] + (row - (rows - 1) / 2) * PAD_SPACING_MM))
    return spots


def plan_nozzle_calibration(probe: ProbeCalibration, nominal_offset_mm: npt.ArrayLike, outer_diameter_mm: float,
                            sphere_diameter_mm: float, pad_centre_mm: npt.ArrayLike, *, pad_touches: int = 3,
                            side_touches: int = 2, clearance_mm: float = 2.0,
                            pad_z_mm: float | None = None) -> tuple[Touch, ...]:
    """Touches in carriage coordinates (mm): the pad spots in four blocks, "pad" (probe T0) on
    the first half, "nozzle_pad" on the first half, "nozzle_pad" on the second half, "pad" on
    the second half (P N N P), then the "nozzle_side" touches (+X, -X, +Y, -Y).

    probe: the current probe qualification (its sphere centre places the side touches; its
    pad reading, when there is one, the pad heights).  nominal_offset_mm (3,): the nozzle's
    nominal offset (or one located by a first, coarse run).  pad_centre_mm (3,): the pad's
    nominal top-face centre.  pad_touches: spots on a 2-D grid (``pad_grid``), each touched
    by the probe and by the nozzle.  clearance_mm: free travel before every expected contact;
    it must exceed the offset's uncertainty (and the pad height's, with the drift since it was
    measured).  pad_z_mm: the pad surface in the probe frame when known better than from
    ``probe`` (a located run).  Side starts are ``clearance_mm`` outside the sphere (body
    edge to sphere) so the caller may reach them going up, across, then down.  Within a block
    and along a side the touches after the first are ``local`` (a hop near the artifact).
    """
    o = np.array(_vec3(nominal_offset_mm, "nominal_offset_mm"))
    half_d = _positive(outer_diameter_mm, "outer_diameter_mm") / 2
    big_r = _positive(sphere_diameter_mm, "sphere_diameter_mm") / 2
    gap = _positive(clearance_mm, "clearance_mm")
    if pad_touches < 1 or side_touches < 1:
        raise CalibrationError("need at least one pad touch and one side touch per direction",
                               field="pad_touches" if pad_touches < 1 else "side_touches",
                               value=min(pad_touches, side_touches))
    pad = np.array(_vec3(pad_centre_mm, "pad_centre_mm"))
    surface = probe.pad_surface_z_mm() if pad_z_mm is None else float(pad_z_mm)
    pad_z = pad[2] if surface is None else surface
    r = probe.ball_radius_mm
    spots = _pad_spots(pad, int(pad_touches))
    half = (len(spots) + 1) // 2

    def probe_touch(x: float, y: float, local: bool) -> Touch:
        return Touch((x, y, pad_z + r + gap), (x, y, pad_z + r - OVERTRAVEL_MM), "pad", local=local)

    def nozzle_touch(x: float, y: float, local: bool) -> Touch:
        start = np.array([x, y, pad_z + gap]) - o      # the tip over the spot: carriage = tip - o
        return Touch(tuple(start), tuple(start - (0, 0, gap + OVERTRAVEL_MM)), "nozzle_pad", local=local)

    # P N N P blocks: the probe's and the nozzle's touches have the same mean time (a linear drift
    # cancels) and the same spots (the pad's flatness cancels)
    touches: list[Touch] = []
    for block, make in ((spots[:half], probe_touch), (spots[:half], nozzle_touch), (spots[half:], nozzle_touch),
                        (spots[half:], probe_touch)):
        touches.extend(make(x, y, k > 0) for k, (x, y) in enumerate(block))
    c = np.array(probe.sphere_centre_mm)
    tip_z = c[2] - TIP_BELOW_EQUATOR * big_r
    for ux, uy in SIDES.values():
        u = np.array([ux, uy, 0.0])
        for k in range(int(side_touches)):
            tip_start = c + (big_r + half_d + gap) * u
            tip_target = c + (big_r + half_d - OVERTRAVEL_MM) * u
            tip_start[2] = tip_target[2] = tip_z
            touches.append(Touch(tuple(tip_start - o), tuple(tip_target - o), "nozzle_side", local=k > 0))
    return tuple(touches)


def _side_of(t: Touch) -> str:
    d = t.direction
    axis = int(np.argmax(np.abs(d[:2])))
    if abs(d[2]) > _OFF_AXIS_SLACK or abs(d[1 - axis]) > _OFF_AXIS_SLACK:
        raise CalibrationError("a nozzle_side touch must move horizontally along x or y", field="touches",
                               value=t.to_dict())
    # approaching from +X moves toward -X
    return ("+" if d[axis] < 0 else "-") + "xy"[axis]


def _pooled_var(groups: list[npt.NDArray[np.float64]]) -> float:
    """Pooled variance of repeated readings (0 when no group has a repeat)."""
    dof = sum(len(g) - 1 for g in groups)
    if dof <= 0:
        return 0.0
    return float(sum(((g - g.mean()) ** 2).sum() for g in groups) / dof)


def fit_nozzle_offset(tool: int, touches: Iterable[Touch], readings: npt.ArrayLike, probe: ProbeCalibration,
                      outer_diameter_mm: float,
                      sphere_diameter_mm: float) -> NozzleCalibration:
    """The nozzle's offset o (tip = carriage + o) from a ``plan_nozzle_calibration`` run (mm).

    readings (n, 3): carriage position at each trigger, one per touch.  Without "pad" probe
    touches the probe calibration's own pad reading is the pad reference (drift since the
    qualification then enters o_z).  Raises CalibrationError naming a reading off its move,
    a missing side, or a pair of side touches inconsistent with the body and sphere sizes.
    """
    touches = tuple(touches)
    p = check_readings(touches, readings)
    half_d = _positive(outer_diameter_mm, "outer_diameter_mm") / 2
    big_r = _positive(sphere_diameter_mm, "sphere_diameter_mm") / 2
    kinds = np.array([t.kind for t in touches])
    probe_pad, nozzle_pad = np.flatnonzero(kinds == "pad"), np.flatnonzero(kinds == "nozzle_pad")
    if len(nozzle_pad) == 0:
        raise CalibrationError("no nozzle_pad touch: the Z offset needs the nozzle on the pad", field="touches")
    delta_up = float(probe.pretravel.at([[0.0, 0.0, 1.0]])[0])
    if "p0_minus_radius_mm" in probe.std:
        var_probe_z = probe.std["p0_minus_radius_mm"] ** 2
    else:   # taken as independent: an overestimate (r and p0 correlate positively)
        var_probe_z = probe.std.get("ball_radius_mm", 0.0) ** 2 + probe.std.get("p0_mm", 0.0) ** 2
    if len(probe_pad):
        pad_z = float(p[probe_pad, 2].mean()) + delta_up - probe.ball_radius_mm
    elif (surface := probe.pad_surface_z_mm()) is not None:
        pad_z = surface
        var_probe_z += probe.std.get("pad_reading_z_mm", 0.0) ** 2
    else:
        raise CalibrationError("no probe pad reading: touch the pad with the probe too", field="touches")
    nz = p[nozzle_pad, 2]
    o_z = pad_z - float(nz.mean())
    # the probe's and the nozzle's touches scatter differently: each group's own variance when it has
    # repeats, else the pooled one
    pooled = _pooled_var([p[probe_pad, 2], nz]) if len(probe_pad) else _pooled_var([nz])
    var_z = var_probe_z
    for group in ([p[probe_pad, 2]] if len(probe_pad) else []) + [nz]:
        var_z += (_pooled_var([group]) if len(group) > 2 else pooled) / len(group)
    sides: dict[str, list[int]] = {k: [] for k in SIDES}
    for i in np.flatnonzero(kinds == "nozzle_side"):
        sides[_side_of(touches[i])].append(int(i))
    missing = [k for k, v in sides.items() if not v]
    if missing:
        raise CalibrationError(f"nozzle side touches missing from {', '.join(missing)}: XY needs opposite pairs",
                               field="touches", value=missing)
    c = np.array(probe.sphere_centre_mm)
    offset_xy, var_xy = [], []
    for axis, name in enumerate("xy"):
        plus, minus = p[sides[f"+{name}"], axis], p[sides[f"-{name}"], axis]
        span = float(plus.mean() - minus.mean())
        if abs(span / 2 - (big_r + half_d)) > 0.5 * (big_r + half_d) or span <= 0:
            first = int(sides[f"+{name}"][0])
            raise CalibrationError(f"nozzle side touches along {name} are {span:.3f} mm apart; a body of "
                                   f"{2 * half_d:.3f} mm on a {2 * big_r:.3f} mm sphere gives about "
                                   f"{2 * (big_r + half_d):.3f} mm", field=f"readings[{first}]", value=p[first])
        offset_xy.append(float(c[axis] - (plus.mean() + minus.mean()) / 2))
        s2 = _pooled_var([plus, minus])
        var_xy.append(s2 / 4 * (1 / len(plus) + 1 / len(minus)) + probe.std.get(f"centre_{name}_mm", 0.0) ** 2)
    std = (math.sqrt(var_xy[0]), math.sqrt(var_xy[1]), math.sqrt(var_z))
    used = len(probe_pad) + len(nozzle_pad) + sum(len(v) for v in sides.values())
    return NozzleCalibration(tool=int(tool), offset_mm=(offset_xy[0], offset_xy[1], o_z), std_mm=std,
                             outer_diameter_mm=2 * half_d, touches=used)
