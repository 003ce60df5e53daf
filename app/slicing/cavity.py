"""The multi-cavity slicing paper's cavity measures of one section: the discriminant theta and mu (step 9).

Shared by the layer builder (:mod:`app.slicing.layers`) and the planners
(:mod:`app.slicing.adaptive`), so neither has to import the other's module at run time."""

from __future__ import annotations

import math

from app.slicing.rings import SectionStats


def theta(sigma: float, sigma0: float, rule: str) -> int:
    """The published discriminant theta: 1 when the section is cavity-rich, else 0.

    ``rule="indicator"``: sigma >= sigma0.  ``rule="printed"``: int(ln(sigma - sigma0 + 55)
    / 4) evaluated literally (0 when the logarithm's argument is not positive).
    """
    if rule == "indicator":
        return 1 if sigma >= sigma0 else 0
    arg = sigma - sigma0 + 55.0
    return int(math.log(arg) / 4.0) if arg > 0 else 0


def cavity_mu(st: SectionStats, sigma0: float, theta_rule: str) -> float:
    """mu = theta * (1/n) * sum(A_in) / A_out (0 without inner rings); ``sigma0`` and
    ``theta_rule`` as in :class:`~app.slicing.layers.SliceParams`."""
    if st.inner_ring_count == 0:
        return 0.0
    return theta(st.sigma, sigma0, theta_rule) * st.mean_inner_ratio
