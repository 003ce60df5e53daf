"""The published point-count formula as printed, including its documented inconsistency."""

import math

import pytest
from scipy.stats import norm

from app.domain.errors import InvalidInput
from app.probing.point_count import PointCountError, seed_point_count


def test_known_value():
    # K = 0.5 -> (1+K)/(1-K) = 3; gamma = 0.95 -> Z = 1.644854
    r = seed_point_count(0.5, 0.95)
    assert r.z_gamma == pytest.approx(1.6448536269514722, rel=1e-12)
    assert r.n_exact == pytest.approx(0.5 * (3 * 1.6448536269514722) ** 2, rel=1e-12)
    assert r.count == 13  # ceil(12.175...)


@pytest.mark.parametrize("k", [0.1, 0.5, 0.9, 1.33, 2.0, 5.0])
@pytest.mark.parametrize("gamma", [0.9, 0.99])
def test_both_printed_forms_agree(k, gamma):
    z = norm.ppf(gamma)
    second_form = 0.5 * ((2 / (1 - k) - 1) * z) ** 2
    assert seed_point_count(k, gamma).n_exact == pytest.approx(second_form, rel=1e-12)


def test_documented_inconsistency_n_grows_with_k_below_one():
    """The paper's text says N falls as K grows; the printed formula rises for 0<K<1."""
    ns = [seed_point_count(k, 0.95).n_exact for k in (0.2, 0.4, 0.6, 0.8)]
    assert ns == sorted(ns) and ns[-1] > 10 * ns[0]
    assert seed_point_count(0.6, 0.95).dn_dk > 0
    # only beyond the pole at K = 1 does it fall, towards Z^2 / 2
    above = [seed_point_count(k, 0.95).n_exact for k in (1.5, 2.0, 4.0, 100.0)]
    assert above == sorted(above, reverse=True)
    assert above[-1] == pytest.approx(0.5 * norm.ppf(0.95) ** 2 * (101 / 99) ** 2)
    assert seed_point_count(2.0, 0.95).dn_dk < 0


def test_derivative_matches_finite_difference():
    k, h = 0.7, 1e-6
    fd = (seed_point_count(k + h, 0.9).n_exact - seed_point_count(k - h, 0.9).n_exact) / (2 * h)
    assert seed_point_count(k, 0.9).dn_dk == pytest.approx(fd, rel=1e-6)


@pytest.mark.parametrize("k,gamma", [(1.0, 0.9), (0.0, 0.9), (-1, 0.9), (math.nan, 0.9),
                                     (0.5, 0.0), (0.5, 1.0), (0.5, 1.5)])
def test_bad_inputs(k, gamma):
    with pytest.raises(PointCountError) as info:
        seed_point_count(k, gamma)
    assert isinstance(info.value, InvalidInput)
    assert info.value.field in ("capability_k", "confidence")
