"""Constant-feed interpolation of a NURBS curve at the servo period (patent S3, step 5).

At each servo period T the path advances ``ds = v T``.  The parameter update is the
patent's second-order Taylor expansion of u(s)::

    u_(i+1) = u_i + ds / |p'(u_i)| - ds^2 (p'(u_i) . p''(u_i)) / (2 |p'(u_i)|^4)

(and the first-order update drops the last term).  The *feed fluctuation* is the relative
deviation of the true arc length travelled in each full period from ``ds`` (the arc length
is integrated with Gauss-Legendre quadrature, independent of the update formula).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from app.five_axis.errors import DegenerateTraceError
from app.geometry.nurbs import NurbsCurve

__all__ = ["ServoSchedule", "FeedFluctuation", "interpolate_parameters", "feed_fluctuation",
           "segment_arc_lengths"]

_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(8)


@dataclass(frozen=True)
class ServoSchedule:
    """Parameters visited at each servo period.

    u: (n,) parameter values, u[0] = start, u[-1] = end of the curve's domain.
    step_mm: the nominal distance per period ds = v T (mm).
    order: 1 or 2 (Taylor order of the update).
    """

    u: npt.NDArray[np.float64]
    step_mm: float
    order: int


@dataclass(frozen=True)
class FeedFluctuation:
    """Relative feed error over the full periods of a schedule (dimensionless).

    max_rel: max |ds_i - ds| / ds; rms_rel: RMS of the same; last_step_mm: length of the
    final (partial) period, excluded from the statistics; steps: number of full periods.
    """

    max_rel: float
    rms_rel: float
    last_step_mm: float
    steps: int


def interpolate_parameters(curve: NurbsCurve, feed_mm_s: float, period_s: float,
                           order: Literal[1, 2] = 2, max_steps: int = 2_000_000) -> ServoSchedule:
    """Parameters u_i of a constant-feed traverse of ``curve`` with the Taylor update.

    feed_mm_s: path speed v (mm/s); period_s: servo period T (s).  The last step is
    clipped to the domain end.  Raises DegenerateTraceError if p'(u) vanishes.
    """
    if not (feed_mm_s > 0 and period_s > 0):
        raise DegenerateTraceError("feed and servo period must be positive", field="params",
                                   value={"feed_mm_s": feed_mm_s, "period_s": period_s})
    if order not in (1, 2):
        raise ValueError("order must be 1 or 2")
    ds = feed_mm_s * period_s
    u0, u1 = curve.domain
    length = curve.arc_length()
    expected = int(np.ceil(length / ds)) + 2
    if expected > max_steps:
        raise DegenerateTraceError(
            f"{expected} servo periods exceed the limit {max_steps}; raise the feed or period",
            field="params.period_s", value=period_s)
    u_values = [u0]
    u = u0
    for _ in range(4 * expected + 16):
        d = curve.derivatives(u, 2)
        d1, d2 = d[1][0], d[2][0]
        speed2 = float(d1 @ d1)
        if speed2 <= 0.0:
            raise DegenerateTraceError("the trace has a zero tangent (|p'(u)| = 0)",
                                       field="trace", value=u)
        du = ds / np.sqrt(speed2)
        if order == 2:
            du -= ds * ds * float(d1 @ d2) / (2.0 * speed2 * speed2)
        if du <= 0:
            raise DegenerateTraceError("parameter update did not advance", field="trace",
                                       value=u)
        u = u + du
        if u >= u1:
            u_values.append(u1)
            break
        u_values.append(u)
    else:
        raise DegenerateTraceError("interpolation did not reach the end of the trace",
                                   field="trace", value=u)
    return ServoSchedule(u=np.asarray(u_values), step_mm=ds, order=order)


def segment_arc_lengths(curve: NurbsCurve, u: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Arc length (mm) between consecutive parameters u (n,) -> (n-1,), 8-point Gauss per
    interval (intervals are a servo period long, far below a knot span)."""
    lo, hi = u[:-1], u[1:]
    half = 0.5 * (hi - lo)
    nodes = (0.5 * (hi + lo))[:, None] + half[:, None] * _GAUSS_X[None, :]
    speed = np.linalg.norm(curve.derivatives(nodes.ravel(), 1)[1], axis=1).reshape(nodes.shape)
    lengths: npt.NDArray[np.float64] = half * (speed @ _GAUSS_W)
    return lengths


def feed_fluctuation(curve: NurbsCurve, schedule: ServoSchedule) -> FeedFluctuation:
    """Measured feed error of a schedule (see :class:`FeedFluctuation`)."""
    seg = segment_arc_lengths(curve, schedule.u)
    full = seg[:-1]
    if full.size == 0:
        return FeedFluctuation(0.0, 0.0, float(seg[-1]) if seg.size else 0.0, 0)
    rel = (full - schedule.step_mm) / schedule.step_mm
    return FeedFluctuation(max_rel=float(np.abs(rel).max()),
                           rms_rel=float(np.sqrt(np.mean(rel * rel))),
                           last_step_mm=float(seg[-1]), steps=int(full.size))
