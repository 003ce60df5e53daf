"""The band-limited kernel's Bessel functions from tables: jinc(x) = 2 J1(x) / x and J0(x).

The field's kernel (:func:`app.probing.deviation_prior.jinc_kernel`) and the likelihood's
derivative in the wavelength (:mod:`app.reconstruction.field_learning`) evaluate these at
millions of arguments a plan; ``scipy.special.j1`` / ``j0`` (Cephes' rational
approximations) cost ~30 ns an argument.  Here each is the cubic Hermite interpolant on
the nodes x = k STEP, 0 <= x <= TABLE_END, of the function and its derivative there
(from scipy's j1 and j0: jinc' = -2 J2 / x with J2 = jinc - J0 by the Bessel recurrence,
-x / 4 near 0; J0' = -J1): a cell index, four table reads and a cubic, ~8 ns an argument.
STEP is a power of two, so the cell of x and its offset in it are exact.  Arguments at or
beyond TABLE_END (a field's x = 2 pi r / wavelength: 256 is r = 40 wavelengths) and
non-finite ones are scipy's own.

Error: a cubic Hermite interpolant is within h^4 / 384 max |f''''| of the function (h the
node step).  Both functions are averages of cos(x u) over |u| <= 1 (jinc: u the projection
of a point uniform on the unit disk; J0: u = cos of a uniform angle), so |f''''| <= E[u^4],
1/8 and 3/8: at most 4.8e-15 and 1.5e-14 at h = 1/512, beside the nodes' own rounding
(scipy's j1 and j0: a few ulp).  tests/probing/test_bessel_table.py checks the largest
absolute error against scipy over the whole table (<= 1e-12 asked; 5e-15 and 1.5e-14 found).

Pure: numpy/scipy.  x dimensionless, x >= 0.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache

import numpy as np
from scipy.special import j0, j1

STEP = 1.0 / 512.0      # node step in x (a power of two: x / STEP is exact)
TABLE_END = 256.0       # the tables cover 0 <= x < TABLE_END
SMALL_X = 1e-6          # below it jinc' is its series -x / 4 (J2 = jinc - J0 cancels)


class HermiteTable:
    """f on [0, ``end``) as the cubic Hermite interpolant of ``values`` and ``slopes`` (M + 1,)
    (f and f' at the nodes k ``step``, k = 0..M, M = end / step); ``exact(x)`` gives f where
    the table does not reach (x >= end, x < 0, NaN)."""

    def __init__(self, values: np.ndarray, slopes: np.ndarray, step: float,
                 exact: Callable[[np.ndarray], np.ndarray]) -> None:
        f0, f1 = values[:-1], values[1:]
        d0, d1 = slopes[:-1] * step, slopes[1:] * step   # per unit offset t in a cell
        # p(t) = c0 + t (c1 + t (c2 + t c3)), p(0) = f0, p(1) = f1, p'(0) = d0, p'(1) = d1
        self.c0 = np.ascontiguousarray(f0)
        self.c1 = np.ascontiguousarray(d0)
        self.c2 = 3.0 * (f1 - f0) - 2.0 * d0 - d1
        self.c3 = 2.0 * (f0 - f1) + d0 + d1
        self.cells = len(f0)
        self.last = float(np.nextafter(float(self.cells), 0.0))   # the largest u in the last cell
        self.scale = 1.0 / step
        self.exact = exact

    def __call__(self, x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """f (shape of ``x``) at ``x``; ``out``: an array of that shape to write into."""
        x = np.asarray(x, dtype=float)
        out = np.empty(x.shape) if out is None else out
        u = np.multiply(x, self.scale)                   # exact: the scale is a power of two
        outside = ~((u >= 0.0) & (u < self.cells))       # NaN too
        anywhere_outside = bool(outside.any())
        np.clip(u, 0.0, self.last, out=u)                # every cell index in range (fixed below)
        if anywhere_outside:
            u[outside] = 0.0                              # NaN's cell too
        cell = u.astype(np.intp)
        u -= cell                                         # the offset t in [0, 1)
        read = np.empty(x.shape)
        np.take(self.c3, cell, out=out)
        for c in (self.c2, self.c1, self.c0):
            out *= u
            out += np.take(c, cell, out=read)
        if anywhere_outside:
            out[outside] = self.exact(x[outside])
        return out


def _nodes() -> np.ndarray:
    """The tables' nodes x = k STEP, 0 <= x <= TABLE_END (M + 1,)."""
    return np.arange(int(TABLE_END / STEP) + 1) * STEP


def _jinc_exact(x: np.ndarray) -> np.ndarray:
    """2 J1(x) / x by scipy (x != 0; |x| for the sign: jinc is even)."""
    x = np.abs(x)
    out: np.ndarray = 2.0 * j1(x) / x
    return out


@cache
def jinc_table() -> HermiteTable:
    """The table of jinc(x) = 2 J1(x) / x (made once, at first use: 4 x 1 MiB of coefficients)."""
    x = _nodes()
    safe = np.where(x < SMALL_X, 1.0, x)
    values = np.where(x < SMALL_X, 1.0 - x * x / 8.0, 2.0 * j1(safe) / safe)
    slopes = np.where(x < SMALL_X, -x / 4.0, -2.0 * (values - j0(safe)) / safe)
    return HermiteTable(values, slopes, STEP, _jinc_exact)


@cache
def j0_table() -> HermiteTable:
    """The table of J0(x) (made once, at first use)."""
    x = _nodes()

    def exact(v: np.ndarray) -> np.ndarray:
        out: np.ndarray = j0(v)
        return out
    return HermiteTable(j0(x), -j1(x), STEP, exact)


def jinc(x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """jinc(x) = 2 J1(x) / x (1 at 0), shape of ``x`` (x >= 0), from :func:`jinc_table`."""
    return jinc_table()(x, out)


def bessel_j0(x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """J0(x), shape of ``x`` (x >= 0), from :func:`j0_table`."""
    return j0_table()(x, out)
