"""A scan's checked field as bytes (an NPZ) and back, bit for bit.

``scan_run`` stores the field it fitted to its samples and the verification touches it made
(artifact ``field.npz``); ``reconstruct`` (``scan_run_job_id``) reads it back and rebuilds
the traces from it as from a touch field.  Members: the prior's fields (``prior_<name>``),
``center`` (2,), the inducing sites ``inducing_xy`` / ``inducing_grad`` (m, 2), ``alpha``
(m,), ``theta`` (6,), ``low`` (m, m), the posterior precision's Cholesky factor ``factor``
(m + 6, m + 6) and ``factor_lower``, the fitted points ``xy`` / ``grad`` (n, 2), ``dz``
(n,), ``kept`` (n,), the verification touches ``v_xy`` (k, 2), ``v_trace``, ``v_measured``,
``v_predicted``, ``v_sd``, ``v_limit`` (k,), ``v_noise_limit`` (1,), and the check's
``coverage``, ``target_mm``, ``touch_sigma_mm``.

Pure: numpy.  Units: mm.
"""

from __future__ import annotations

import io
import math
from dataclasses import fields
from typing import Any

import numpy as np

from app.probing.deviation_prior import DeviationPrior, Sites
from app.reconstruction.field_trust import Verification
from app.reconstruction.preprocess import ReconstructionError
from app.reconstruction.scan_field import ScanFieldCheck, ScanFieldFit, SparsePosterior

PRIOR_FIELDS = tuple(f.name for f in fields(DeviationPrior))


def scan_check_npz(check: ScanFieldCheck) -> bytes:
    """``check`` (its fit a :class:`ScanFieldFit`) as NPZ bytes (see the module doc)."""
    fit = check.fit
    post = fit.posterior
    assert isinstance(post, SparsePosterior)
    v = check.verification
    k = 0 if v is None else len(v.xy)
    arrays: dict[str, Any] = {f"prior_{name}": np.array([getattr(post.prior, name)], dtype=float)
                              for name in PRIOR_FIELDS}
    arrays |= {"center": post.center, "inducing_xy": post.probes.xy, "inducing_grad": post.probes.grad,
               "alpha": post.alpha, "theta": post.theta, "low": post.low, "factor": post.factor[0],
               "factor_lower": np.array([bool(post.factor[1])]), "xy": fit.stations.xy, "grad": fit.stations.grad,
               "dz": fit.dz, "kept": fit.kept,
               "v_xy": np.zeros((0, 2)) if v is None else v.xy, "v_trace": np.zeros(k, int) if v is None else v.trace,
               "has_verification": np.array([v is not None]),
               "coverage": np.array([check.coverage]), "target_mm": np.array([check.target_mm]),
               "touch_sigma_mm": np.array([check.touch_sigma_mm])}
    for name in ("measured", "predicted", "sd", "limit"):
        arrays[f"v_{name}"] = np.zeros(0) if v is None else getattr(v, f"{name}_mm")
    arrays["v_noise_limit"] = np.array([0.0 if v is None else v.noise_limit_mm])
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


def scan_check_from_npz(data: bytes) -> ScanFieldCheck:
    """The check stored by :func:`scan_check_npz` (ReconstructionError, 422, when the bytes
    are not one)."""
    try:
        z = np.load(io.BytesIO(data))
        prior = DeviationPrior(**{name: float(z[f"prior_{name}"][0]) for name in PRIOR_FIELDS})
        post = SparsePosterior(prior, z["center"], Sites(z["inducing_xy"], z["inducing_grad"]), z["alpha"],
                               (z["factor"], bool(z["factor_lower"][0])), theta=z["theta"], low=z["low"])
        n = len(z["dz"])
        kept = z["kept"].astype(bool)
        fit = ScanFieldFit(post, Sites(z["xy"], z["grad"]), z["dz"], kept,
                           tuple(int(i) for i in np.flatnonzero(~kept)), np.full(n, -1), np.full(n, math.nan))
        verification = None
        if bool(z["has_verification"][0]):
            verification = Verification(z["v_xy"].reshape(-1, 2), z["v_trace"].astype(int), z["v_measured"],
                                        z["v_predicted"], z["v_sd"], z["v_limit"], float(z["v_noise_limit"][0]))
        return ScanFieldCheck(fit, None, verification, float(z["coverage"][0]), float(z["target_mm"][0]),
                              touch_sigma_mm=float(z["touch_sigma_mm"][0]))
    except (KeyError, ValueError, OSError) as exc:
        raise ReconstructionError(f"not a stored scan field: {exc}", field="field.npz") from None
