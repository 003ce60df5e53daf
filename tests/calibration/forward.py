"""An independent forward model of a touch probe and nozzles on analytic geometry (tests only).

Written from the SPEC16 conventions, not from app.calibration: a reading is the ball centre
at trigger; the ball first touches when its centre reaches the offset surface, then travels
delta(n) further along the move (plus noise along the move).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class TrueProbe:
    r: float = 0.5
    p0: float = 0.015
    a: float = 0.0          # lobing cos(3 phi) amplitude
    b: float = 0.0          # lobing sin(3 phi) amplitude
    scatter: float = 0.0    # pre-travel sd per touch
    noise: float = 0.0      # reading noise along the move

    def delta(self, n, rng):
        rho = math.hypot(n[0], n[1])
        phi = math.atan2(n[1], n[0])
        extra = rng.normal(0, self.scatter) + rng.normal(0, self.noise) if rng is not None else 0.0
        return self.p0 + rho * (self.a * math.cos(3 * phi) + self.b * math.sin(3 * phi)) + extra


def sphere_reading(start, target, centre, radius, probe: TrueProbe, rng=None):
    """Ball centre at trigger for a straight move start -> target against a sphere (None: a miss)."""
    s0, c = np.asarray(start, float), np.asarray(centre, float)
    d = np.subtract(target, start)
    length = np.linalg.norm(d)
    d = d / length
    rho = radius + probe.r
    w = s0 - c
    b = w @ d
    disc = b * b - (w @ w - rho * rho)
    if disc < 0:
        return None
    s = -b - math.sqrt(disc)
    if s < 0 or s > length:
        return None
    q = s0 + s * d
    n = (q - c) / rho
    return q + probe.delta(n, rng) * d


def plane_reading(x0, y0, h0, slope_deg, azimuth_deg, probe: TrueProbe, rng=None):
    """Vertical touch at (x0, y0) on the plane through (x0, y0, h0) rising at slope_deg toward azimuth+180."""
    t, a = math.radians(slope_deg), math.radians(azimuth_deg)
    n = np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])
    # the ball centre sits r along n from the tangent point; its height over the station: h0 + r / n_z
    z = h0 + probe.r / n[2] - probe.delta(n, rng)
    return np.array([x0, y0, z]), n


def cylinder_gap(point, axis_xy, radius, tip_z):
    """Distance from a point to a vertical solid cylinder (axis axis_xy, radius, from tip_z upward)."""
    h = math.hypot(point[0] - axis_xy[0], point[1] - axis_xy[1])
    radial = max(h - radius, 0.0)
    if point[2] >= tip_z:
        return radial
    return math.hypot(radial, tip_z - point[2])


def nozzle_side_reading(start, target, offset, diameter, centre, sphere_radius, noise=0.0, rng=None):
    """Carriage position when the nozzle body (tip = carriage + offset) first touches the sphere (bisection)."""
    start, target, offset = (np.asarray(v, float) for v in (start, target, offset))

    def gap(s):
        tip = start + s * (target - start) + offset
        return cylinder_gap(centre, tip[:2], diameter / 2, tip[2]) - sphere_radius

    lo, hi = 0.0, 1.0
    assert gap(lo) > 0 > gap(hi), "the move does not reach the sphere"
    for _ in range(200):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if gap(mid) > 0 else (lo, mid)
    d = (target - start) / np.linalg.norm(target - start)
    extra = rng.normal(0, noise) if rng is not None else 0.0
    return start + lo * (target - start) + extra * d


def nozzle_pad_reading(start, offset, pad_z, noise=0.0, rng=None):
    """Carriage position when the flat end (tip = carriage + offset) reaches a flat pad at pad_z (vertical move)."""
    extra = rng.normal(0, noise) if rng is not None else 0.0
    return np.array([start[0], start[1], pad_z - offset[2] - extra])
