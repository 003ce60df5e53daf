"""Probe qualification on the reference sphere: plan the touches, fit radius and pre-travel.

Plan (``plan_qualification``), from the NOMINAL sphere and pad places (the true ones may
differ by up to ``approach_mm`` in any direction):

* "cap" touches: vertical moves down onto the sphere, contact polar angles ``cap_rings_deg``
  (ring 0 deg = one touch at the top, made twice), ``per_ring`` azimuths evenly spaced per
  ring, in a palindromic order (up the rings, the equator, down the rings) so that a linear
  drift is centred on every ring alike;
* "equator" touches: horizontal radial moves toward the centre at the nominal centre height,
  ``equator`` azimuths evenly spaced (offset half a step from the cap azimuths);
* "pad" touches: vertical moves onto the pad centre, spread 0.5 mm apart along x, first
  and again last (so that a Z drift during the qualification shows, see below).

Every start lies at least ``approach_mm`` outside the ball-swept sphere (radius R + r) even
when the sphere is up to ``place_tolerance_mm`` off its nominal place, so the caller
may reach it by going up to a clearance height, across, then down; every move reaches
``overtravel_mm`` past the latest possible contact.  Consecutive pad spots and equator
touches and the touches of one pass round a cap ring are ``local`` (``Touch.local``): the
next start is reached by a hop at the start height (the hop's chord keeps at least half the
approach clear of the sphere wherever within ``place_tolerance_mm`` it is).

Fit (``fit_qualification``): a reading P (ball centre at trigger) of a move in direction d
is ``delta(n)`` past first contact, where the contact ball centre lies on the sphere of
radius R + r about the sphere centre c and n = unit(contact centre - c):

    residual_i = |P_i - delta(n_i) d_i - c| - (R + r),   delta(n) = p0 + sin(theta)(a cos 3phi + b sin 3phi)

solved by ``scipy.optimize.least_squares`` for c (3), r, p0 (and a, b with ``lobing``), each
residual divided by |n_i . d_i| (the reading scatters along the move, so a radial miss of e
is a miss of e / cos along it: the weighted fit is the maximum-likelihood one and its std honest).
Vertical cap touches at several polar angles fix R + r through the curvature of the reading
surface (their pre-travel only shifts it along z, like c_z); horizontal equator touches fix
R + r - delta.  Together they separate r from p0 (caps alone cannot: the fit refuses).
Standard deviations come from the Jacobian: cov = (J^T J)^-1 * sum(res^2) / (m - p).

Drift: Z drifts (actual = commanded + e(t)), so a reading taken at machine time t is low by
e(t).  Over a qualification of a few minutes that trend would bend the caps' curvature (the
rings are touched one after the other) and bias r and p0 by microns.  Given the touches'
machine times ``times_s``, the fit adds a linear drift rate k (mm/s): every reading is
raised by k (t - t_0) (t_0 = the first touch), with k fixed mostly by the pad touches at
both ends; ``pad_reading_z_mm`` and the centre then refer to the drift at t_0.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from app.calibration.errors import CalibrationError
from app.calibration.model import PretravelModel, ProbeCalibration, Touch, _vec3

__all__ = ["plan_qualification", "fit_qualification", "check_readings", "OFF_LINE_MM", "ABSURD_MM"]

OFF_LINE_MM = 0.25     # a reading farther than this from its move's straight line is not a reading of it
ABSURD_MM = 2.0        # a sphere reading farther than this from the sphere of the others is refused
OUTLIER_MM = 0.05      # after the fit: a residual beyond this is a bad touch (dust, a bounce), not scatter
PAD_SPACING_MM = 0.5
_LM_TOL = 1e-15        # the final Levenberg-Marquardt fit's xtol / ftol / gtol (converge to round-off)
_SINGULAR_SV_REL = 1e-9  # the fit is singular when its Jacobian's smallest / largest singular value is below this
PARAMS = ("centre_x_mm", "centre_y_mm", "centre_z_mm", "ball_radius_mm", "p0_mm", "cos3_mm", "sin3_mm")


def _positive(value: float, name: str, *, zero_ok: bool = False) -> float:
    v = float(value)
    if not math.isfinite(v) or v < 0 or (v == 0 and not zero_ok):
        raise CalibrationError(f"{name} must be a finite number {'>=' if zero_ok else '>'} 0", field=name, value=value)
    return v


def plan_qualification(sphere_centre_mm: npt.ArrayLike, sphere_diameter_mm: float, ball_radius_mm: float,
                       pad_centre_mm: npt.ArrayLike | None, *, cap_rings_deg: Sequence[float] = (0, 20, 35, 50, 60),
                       per_ring: int = 8, equator: int = 16, pad_touches: int = 3, approach_mm: float = 1.0,
                       overtravel_mm: float = 1.0, place_tolerance_mm: float = 0.5) -> tuple[Touch, ...]:
    """Touches in machine coordinates (mm): the pad, caps up the rings (even azimuths), the
    equator, caps down the rings (odd azimuths, the top again), the pad again.

    sphere_centre_mm (3,), pad_centre_mm (3,) (top face centre) or None: nominal places.
    ball_radius_mm: nominal stylus ball radius.  place_tolerance_mm: how far the true
    sphere / pad may sit from its nominal place: every start is safe and every move
    still meets the artifact within it.  approach_mm: free travel before the earliest
    possible contact.  overtravel_mm: travel past the latest possible contact before the
    move counts as a miss.  A cap ring so steep that a sphere ``place_tolerance_mm`` off
    could be missed is refused (field ``cap_rings_deg``).
    """
    c = np.array(_vec3(sphere_centre_mm, "sphere_centre_mm"))
    big_r = _positive(sphere_diameter_mm, "sphere_diameter_mm") / 2
    r = _positive(ball_radius_mm, "ball_radius_mm", zero_ok=True)
    approach = _positive(approach_mm, "approach_mm")
    over = _positive(overtravel_mm, "overtravel_mm")
    u = _positive(place_tolerance_mm, "place_tolerance_mm", zero_ok=True)
    if per_ring < 3 or equator < 7:
        raise CalibrationError("need per_ring >= 3 and equator >= 7 (the 3-lobe term needs 7 azimuths)",
                               field="equator" if equator < 7 else "per_ring", value=min(per_ring, equator))
    rings = [float(a) for a in cap_rings_deg]
    if len(rings) < 2 or any(not 0 <= a <= 75 for a in rings):
        raise CalibrationError("cap_rings_deg: at least two polar angles in [0, 75] deg (the curvature fixes r)",
                               field="cap_rings_deg", value=rings)
    rho_s = big_r + r                                  # the ball-centre sphere
    steep = [a for a in rings if rho_s * math.sin(math.radians(a)) + u >= rho_s * 0.98]
    if steep:
        raise CalibrationError(f"cap ring at {steep[0]:g} deg could miss a sphere {u:g} mm off its nominal place",
                               field="cap_rings_deg", value=steep)
    touches: list[Touch] = []
    pads: list[Touch] = []
    if pad_centre_mm is not None:
        pad = np.array(_vec3(pad_centre_mm, "pad_centre_mm"))
        for k in range(int(pad_touches)):
            x = pad[0] + (k - (pad_touches - 1) / 2) * PAD_SPACING_MM
            pads.append(Touch((x, pad[1], pad[2] + r + u + approach), (x, pad[1], pad[2] + r - u - over), "pad",
                              local=k > 0))      # the next spot along the pad, at the same height
    touches.extend(pads)
    top = c[2] + rho_s
    ring_touches: list[list[Touch]] = []
    for ring_deg in rings:
        theta = math.radians(ring_deg)
        count = 1 if ring_deg == 0 else int(per_ring)
        rho = rho_s * math.sin(theta)                  # station distance from the axis
        # highest contact when the sphere is u closer, lowest when u farther; and u higher / lower
        high = top if rho <= u else c[2] + math.sqrt(max(rho_s ** 2 - (rho - u) ** 2, 0.0))
        low = c[2] + math.sqrt(max(rho_s ** 2 - (rho + u) ** 2, 0.0))
        ring_touches.append([])
        for k in range(count):
            phi = 2 * math.pi * k / count
            x, y = c[0] + rho * math.cos(phi), c[1] + rho * math.sin(phi)
            ring_touches[-1].append(Touch((x, y, high + u + approach), (x, y, low - u - over), "cap"))
    # palindromic order: up the rings (every other azimuth), the equator, down the rings (the
    # rest; a single top touch is repeated) -- every ring's touches are centred on the same
    # time, so a linear drift does not bend the curvature that fixes r
    def hop_clear(ring_deg: float, count: int, stride: int) -> bool:
        """A straight hop between stations ``stride`` azimuth steps apart on the ring, at the start
        height, keeps half the approach above the highest the ball-centre sphere can be there."""
        rho = rho_s * math.sin(math.radians(ring_deg))
        mid = max(rho * math.cos(math.pi * stride / count) - u, 0.0)
        start_z = (top if rho <= u else c[2] + math.sqrt(max(rho_s ** 2 - (rho - u) ** 2, 0.0))) + u + approach
        return bool(start_z - (c[2] + u + math.sqrt(max(rho_s ** 2 - mid ** 2, 0.0))) >= approach / 2)

    def ring_pass(ring: list[Touch], ring_deg: float, half: int) -> list[Touch]:
        """Every other station of the ring, from station ``half`` (0 or 1)."""
        local = len(ring) > 2 and bool(hop_clear(ring_deg, len(ring), 2))
        return [replace(t, local=local and k > 0) for k, t in enumerate(ring[half::2])]

    for ring, ring_deg in zip(ring_touches, rings, strict=True):
        touches.extend(ring_pass(ring, ring_deg, 0))
    # from one equator start straight to the next: the chord's middle stays half the approach
    # outside the farthest the ball-centre sphere can reach
    hop = bool((rho_s + u + approach) * math.cos(math.pi / equator) >= rho_s + u + approach / 2)
    for k in range(int(equator)):
        phi = 2 * math.pi * (k + 0.5) / equator
        e = np.array([math.cos(phi), math.sin(phi), 0.0])
        touches.append(Touch(tuple(c + (rho_s + u + approach) * e), tuple(c + (rho_s - u - over) * e), "equator",
                             local=hop and k > 0))
    for ring, ring_deg in reversed(list(zip(ring_touches, rings, strict=True))):
        touches.extend(ring_pass(ring, ring_deg, 1) if len(ring) > 1 else ring)
    touches.extend(pads)          # the pad again at the end: with touch times, a Z drift is measured
    return tuple(touches)


def check_readings(touches: Sequence[Touch], readings: npt.ArrayLike, *,
                   project: bool = True) -> npt.NDArray[np.float64]:
    """Validate readings (n, 3) against their touches: finite, on the move's line, between start and target.

    Returns them projected onto their moves' lines (``project``): the carriage moves along the
    commanded line, so a reading's offset from it is the firmware's report rounding (Marlin
    ``M114 D`` and grbl ``PRB`` print 1 um), which the projection removes.  Left in, the rounding
    of a ring of stations that happen to share a rounding direction biases r by a micron.
    """
    p = np.asarray(readings, dtype=float)
    if p.ndim != 2 or p.shape != (len(touches), 3):
        raise CalibrationError(f"readings must have shape ({len(touches)}, 3), one per touch", field="readings",
                               value=list(p.shape))
    for i, (t, q) in enumerate(zip(touches, p, strict=True)):
        if not np.isfinite(q).all():
            raise CalibrationError(f"readings[{i}] is not finite", field=f"readings[{i}]", value=q)
        s = np.asarray(t.start_mm)
        length = float(np.linalg.norm(np.subtract(t.target_mm, s)))
        along = float(np.dot(q - s, t.direction))
        off = float(np.linalg.norm(q - s - along * t.direction))
        if off > OFF_LINE_MM or along < -OFF_LINE_MM or along > length + OFF_LINE_MM:
            raise CalibrationError(f"readings[{i}] ({t.kind} touch) is {off:.3f} mm off its move and "
                                   f"{along:.3f} mm along it (length {length:.3f} mm): not a reading of that touch",
                                   field=f"readings[{i}]", value=q)
    if not project:
        return p
    return np.array([np.asarray(t.start_mm) + float(np.dot(q - t.start_mm, t.direction)) * t.direction
                     for t, q in zip(touches, p, strict=True)])


def _normals_delta(p: npt.NDArray[np.float64], d: npt.NDArray[np.float64], c: npt.NDArray[np.float64],
                   model: npt.NDArray[np.float64], lobing: bool
                   ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Contact normals (m, 3) and pre-travel (m,) by fixed-point iteration n = unit(P - delta(n) d - c)."""
    delta = np.full(len(p), model[0])
    for _ in range(4 if lobing else 1):
        v = p - delta[:, None] * d - c
        n = v / np.linalg.norm(v, axis=1)[:, None]
        if lobing:
            rho = np.hypot(n[:, 0], n[:, 1])
            phi = np.arctan2(n[:, 1], n[:, 0])
            delta = model[0] + rho * (model[1] * np.cos(3 * phi) + model[2] * np.sin(3 * phi))
    return n, delta


def fit_qualification(touches: Sequence[Touch], readings: npt.ArrayLike, sphere_diameter_mm: float, *,
                      lobing: bool = True, outlier_mm: float = OUTLIER_MM,
                      times_s: npt.ArrayLike | None = None) -> ProbeCalibration:
    """Fit ball radius, pre-travel (and lobing) and the sphere centre from cap / equator / pad readings.

    touches: the plan (``plan_qualification`` or any vertical caps at >= 2 polar angles plus
    >= 3 horizontal equator touches).  readings (n, 3) mm: ball centre at trigger, one per touch.
    Raises CalibrationError naming the touch for a reading off its move, farther than
    ``ABSURD_MM`` from the sphere or (after the fit) more than ``outlier_mm`` off it, and for
    a plan that cannot separate r from p0.  times_s (n,): machine seconds of each touch
    (``touch_times`` or the machine's clock); given, a linear Z drift is fitted too
    (``ProbeCalibration.drift_mm_per_min``; needs pad touches at both ends or caps spread in time).
    """
    big_r = _positive(sphere_diameter_mm, "sphere_diameter_mm") / 2
    p_all = check_readings(touches, readings).copy()
    kinds = np.array([t.kind for t in touches])
    t_rel = _times(times_s, len(touches))
    sphere = np.flatnonzero((kinds == "cap") | (kinds == "equator"))
    n_par = 7 if lobing else 5
    if (kinds == "equator").sum() < (7 if lobing else 3) or (kinds == "cap").sum() < 3 or len(sphere) <= n_par:
        raise CalibrationError("qualification needs >= 3 cap touches and >= 3 equator touches (>= 7 with "
                               "lobing): caps alone cannot separate the ball radius from the pre-travel",
                               field="touches", value={k: int((kinds == k).sum()) for k in ("cap", "equator")})
    pad = np.flatnonzero(kinds == "pad")
    drift = t_rel is not None
    used = np.concatenate([sphere, pad]) if drift else sphere
    p = p_all[sphere]
    d = np.array([touches[int(i)].direction for i in sphere])
    # initial guess: algebraic sphere |P|^2 = 2 P.c + k
    a = np.column_stack([2 * p, np.ones(len(p))])
    sol, *_ = np.linalg.lstsq(a, (p ** 2).sum(axis=1), rcond=None)
    c0 = sol[:3]
    rho0 = math.sqrt(max(sol[3] + c0 @ c0, 0.0))
    dist = np.linalg.norm(p - c0, axis=1)
    far = np.abs(dist - np.median(dist)) > ABSURD_MM
    if far.any():
        i = int(sphere[np.flatnonzero(far)[0]])
        raise CalibrationError(f"readings[{i}] ({touches[i].kind} touch) is {abs(dist[far][0] - np.median(dist)):.3f}"
                               " mm off the sphere the other readings describe", field=f"readings[{i}]",
                               value=p_all[i])

    def residuals(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        c, r = x[:3], x[3]
        model = x[4:7] if lobing else np.array([x[4], 0.0, 0.0])
        q = p
        if t_rel is not None:   # raise every reading by the drift since t_0; the pad readings share one height
            q = p.copy()
            q[:, 2] += x[-2] * t_rel[sphere]
        n, delta = _normals_delta(q, d, c, model, lobing)
        # the scatter is along the move: divide the radial miss by cos(angle(n, -d)) to put it there
        res = (np.linalg.norm(q - delta[:, None] * d - c, axis=1) - (big_r + r)) / np.abs((n * d).sum(axis=1))
        if t_rel is not None:
            res = np.concatenate([res, p_all[pad, 2] + x[-2] * t_rel[pad] - x[-1]])
        out: npt.NDArray[np.float64] = res
        return out

    x0 = np.concatenate([c0, [rho0 - big_r, 0.0], [0.0, 0.0] if lobing else []])
    if drift:
        if len(pad) < 2:
            raise CalibrationError("fitting a drift needs at least two pad touches", field="times_s",
                                   value=int(len(pad)))
        n_par += 2
        x0 = np.concatenate([x0, [0.0, float(p_all[pad, 2].mean())]])
    # a robust pass first, so that one bad touch shows its own size instead of bending the fit
    robust = least_squares(residuals, x0, loss="soft_l1", f_scale=outlier_mm / 10, max_nfev=200 * n_par)
    worst = int(np.argmax(np.abs(robust.fun)))
    if abs(robust.fun[worst]) > outlier_mm:
        i = int(used[worst])
        raise CalibrationError(f"readings[{i}] ({touches[i].kind} touch) is {robust.fun[worst]:.3f} mm "
                               "(along its move) off what the other readings describe (a bad touch: dust or a bounce?)",
                               field=f"readings[{i}]", value=p_all[i])
    fit = least_squares(residuals, robust.x, method="lm", xtol=_LM_TOL, ftol=_LM_TOL, gtol=_LM_TOL,
                        max_nfev=200 * n_par)
    res = fit.fun
    jac = fit.jac
    sv = np.linalg.svd(jac, compute_uv=False)
    if sv[-1] < _SINGULAR_SV_REL * sv[0]:
        raise CalibrationError("the touches cannot separate the ball radius from the pre-travel (singular fit):"
                               " add equator touches and caps at several polar angles", field="touches",
                               value=len(sphere))
    dof = len(res) - n_par
    s2 = float(res @ res) / dof if dof > 0 else 0.0
    cov = np.linalg.inv(jac.T @ jac) * s2
    names = [*PARAMS[:5], *(PARAMS[5:] if lobing else ())]
    std = {name: float(math.sqrt(max(cov[k, k], 0.0))) for k, name in enumerate(names)}
    # delta(+Z) - r = p0 - r turns a vertical pad reading into the pad surface; r and p0 correlate
    std["p0_minus_radius_mm"] = float(math.sqrt(max(cov[4, 4] + cov[3, 3] - 2 * cov[3, 4], 0.0)))
    x = fit.x
    pad_z, rate = None, None
    if drift:
        pad_z = float(x[-1])
        rate = float(x[-2]) * 60.0
        std["pad_reading_z_mm"] = float(math.sqrt(max(cov[-1, -1], 0.0)))
        std["drift_mm_per_min"] = float(math.sqrt(max(cov[-2, -2], 0.0))) * 60.0
    elif len(pad):
        pad_z = float(p_all[pad, 2].mean())
        std["pad_reading_z_mm"] = float(p_all[pad, 2].std(ddof=1) / math.sqrt(len(pad))) if len(pad) > 1 else 0.0
    pretravel = PretravelModel(float(x[4]), float(x[5]) if lobing else 0.0, float(x[6]) if lobing else 0.0)
    return ProbeCalibration(ball_radius_mm=float(x[3]), pretravel=pretravel,
                            sphere_centre_mm=(float(x[0]), float(x[1]), float(x[2])), pad_reading_z_mm=pad_z,
                            std=std, residual_rms_mm=float(math.sqrt(np.mean(res[:len(sphere)] ** 2))),
                            touches=len(sphere) + len(pad), drift_mm_per_min=rate)


def _times(times_s: npt.ArrayLike | None, n: int) -> npt.NDArray[np.float64] | None:
    """Touch times relative to the first (n,) s, or None."""
    if times_s is None:
        return None
    t = np.asarray(times_s, dtype=float)
    if t.shape != (n,) or not np.isfinite(t).all():
        raise CalibrationError(f"times_s must be {n} finite machine times (s), one per touch", field="times_s",
                               value=list(t.shape))
    relative: npt.NDArray[np.float64] = t - t[0]
    return relative
