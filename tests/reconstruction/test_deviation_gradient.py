"""The reconstructed deviation's top-view gradient (the probe-normal iteration uses it)."""

import numpy as np

from app.probing.deviation_prior import DeviationPrior
from app.probing.field import plan_field
from app.probing.selection import PlanParams
from app.reconstruction.field import field_gradient, fit_field
from app.reconstruction.reconstruct import reconstruct
from app.reference.s1 import nominal_gradient, nominal_path, s1_traces


def test_along_trace_gradient_of_a_known_deviation():
    """dev(x, y) = a x + b y on the whole top: along a trace the profile is dev(s); the
    gradient's along-trace component is grad dev . u (u the top-view direction), the
    across part is zero by construction."""
    path = nominal_path(s1_traces()[7], 0.1)  # a NURBS trace
    a, b = 0.004, -0.007
    s = np.linspace(0, path.length_mm, 40)
    pts = path.at(s)
    pts[:, 2] += a * pts[:, 0] + b * pts[:, 1]
    rec = reconstruct(path, pts, "deviation", sigma_mm=0.0)
    q = path.at(s[3:-3])[:, :2]
    g = rec.deviation_gradient_xy(q)
    t = path.at(s[3:-3] + 0.01) - path.at(s[3:-3] - 0.01)
    u = t[:, :2] / np.linalg.norm(t[:, :2], axis=1, keepdims=True)
    along = np.sum(g * u, axis=1)
    across = g[:, 0] * -u[:, 1] + g[:, 1] * u[:, 0]
    assert np.abs(along - (a * u[:, 0] + b * u[:, 1])).max() < 2e-4
    assert np.abs(across).max() < 1e-4  # chord directions over +-0.05 vs +-0.01 mm on a curved trace


def test_field_gradient_of_a_fitted_plane():
    """A field fitted to a tilted-plane deviation has about that plane's gradient at its
    stations: along the traces (y here) within 1e-3, across them (x, three traces 8 mm
    apart) within 2.5e-3 — a normal off by 2.5 mrad moves a 0.5 mm ball's height
    correction by r tan(theta) 2.5e-3 < 0.7 um up to 45 deg."""
    paths = [nominal_path(s1_traces()[i], 0.1) for i in (0, 3, 6)]
    params = PlanParams(deviation_amplitude_mm=0.1, deviation_wavelength_mm=20.0)
    plan = plan_field(paths, params, "on_traces", None)
    a, b = 0.003, 0.002
    dz = a * plan.xy[:, 0] + b * plan.xy[:, 1]
    prior = DeviationPrior(**{**params.prior().__dict__, "sigma_mm": 1e-4})
    fit = fit_field(prior, plan.sites, plan.z, np.column_stack([plan.xy, plan.z + dz]), plan.center)
    g = field_gradient(fit, plan.sites, slope_at=nominal_gradient)
    err = np.abs(g - [a, b]).max(axis=0)
    assert err[1] < 1e-3 and err[0] < 2.5e-3, err
