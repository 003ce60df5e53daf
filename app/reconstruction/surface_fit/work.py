"""Work of one surface fit with a control net, for cost estimates before the fit runs.

The least-squares fit (:func:`app.geometry.fitting.fit_surface`) solves either two 1-D
banded systems per direction (a full grid without penalty: "separable", O(grid) memory)
or the banded normal equations of all n_u n_v unknowns with the longer net direction
outermost (bandwidth ``degree * min(n_u, n_v) + degree``, LAPACK band storage
``(w + 1) N`` float64).  The residuals invert the fitted surface from a dense sample:
``max(4, 2 degree)`` parameters per knot span and direction
(:meth:`app.geometry.nurbs_surface.NurbsSurface.invert`).
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = ["FitWork", "work_estimate"]


class FitWork(NamedTuple):
    """unknowns: control points n_u n_v; bandwidth: of the normal matrix (0 when separable);
    band_bytes: its band storage, bytes (0 when separable); flops: of its banded Cholesky
    (~ N w^2; 0 when separable); inversion_samples: surface points sampled to invert it."""

    unknowns: float
    bandwidth: float
    band_bytes: float
    flops: float
    inversion_samples: float


def work_estimate(net: tuple[float, float], degree: int, separable: bool) -> FitWork:
    """Work of a fit with a control net (n_u, n_v) of ``degree`` in both directions.

    The net may be fractional (an estimate of the net a GCV search ends at); a direction
    with no more control points than the degree counts as one knot span.
    """
    unknowns = net[0] * net[1]
    per = max(4, 2 * degree)
    samples = (per * max(net[0] - degree, 1) + 1) * (per * max(net[1] - degree, 1) + 1)
    if separable:
        return FitWork(unknowns, 0.0, 0.0, 0.0, samples)
    width = degree * min(net) + degree
    return FitWork(unknowns, width, 8 * unknowns * (width + 1), unknowns * width**2, samples)
