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
