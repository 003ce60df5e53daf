"""Touches of one deviation field drawn from a known prior (for the learning tests and bench)."""

from __future__ import annotations

import numpy as np

from app.probing.deviation_prior import DeviationPrior, Sites, prior_covariance


def draw(prior: DeviationPrior, n: int, seed: int, pairs: int = 0) -> tuple[Sites, np.ndarray, np.ndarray]:
    """n touches (n - pairs random over 40 x 30 mm, ``pairs`` of them touched again 0.2 mm
    away) of one field drawn from ``prior`` with its noise: (sites, centre (2,), dz (n,) mm)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([0.0, 0.0], [40.0, 30.0], (n - pairs, 2))
    xy = np.concatenate([xy, xy[:pairs] + [0.2, 0.0]])
    sites = Sites(xy, rng.normal(0.0, 0.05, (n, 2)))
    center = xy.mean(axis=0)
    k = prior_covariance(prior, sites, sites, center) + prior.sigma_mm ** 2 * np.eye(n)
    return sites, center, np.linalg.cholesky(k) @ rng.normal(size=n)
