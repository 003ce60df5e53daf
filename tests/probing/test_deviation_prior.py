"""Deviation prior: band-limited kernel, first-order placement basis, kriging posterior."""

import math

import numpy as np
import pytest

from app.geometry.traces import as_trace_polyline
from app.platform.problems import http_status
from app.probing.deviation_prior import (
    DeviationPrior,
    PriorError,
    Sites,
    fit_posterior,
    jinc_kernel,
    path_center,
    path_gradient,
    path_sites,
    placement_basis,
    prior_covariance,
)
from app.probing.selection import PlanParams
from app.reference.s1 import as_made, centred_placement, nominal_gradient, nominal_path, s1_traces


def test_jinc_is_the_disk_spectrum_average_of_plane_waves():
    # 2 J1(k0 r)/(k0 r) = mean of cos(k . r) over the disk |k| <= k0 (polar midpoint rule)
    lam = 15.0
    k0 = 2 * math.pi / lam
    rho = (np.arange(400) + 0.5) / 400 * k0
    phi = (np.arange(256) + 0.5) / 256 * 2 * math.pi
    kx = (rho[:, None] * np.cos(phi)).ravel()
    ky = (rho[:, None] * np.sin(phi)).ravel()
    w = np.repeat(rho, len(phi))
    for r in (0.0, 1.0, 4.0, 9.5, 22.0):
        for ang in (0.0, 1.1):
            d = r * np.array([math.cos(ang), math.sin(ang)])
            ref = np.sum(w * np.cos(kx * d[0] + ky * d[1])) / np.sum(w)
            got = jinc_kernel(np.zeros((1, 2)), d[None, :], lam)[0, 0]
            assert got == pytest.approx(ref, abs=1e-4)


def _dense_jinc(a, b, lam):
    """The kernel in one piece by scipy's j1: 2 J1(x) / x, x = 2 pi |a - b| / lam, 1 - x^2/8 near 0."""
    from scipy.special import j1
    x = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1]) * (2 * math.pi / lam)
    out = 2.0 * j1(x)
    small = x < 1e-6
    out[~small] /= x[~small]
    out[small] = 1.0 - x[small] ** 2 / 8.0
    return out


@pytest.mark.parametrize("block", [1, 7, 40, 41, 10 ** 6])
def test_jinc_kernel_in_row_blocks_is_the_one_block_kernel_bit_for_bit_and_scipys_within_1e_14(block):
    # blocks of one row, of a few rows (not dividing m), of whole and more than all rows;
    # coincident and near-coincident points: 1 and just under it
    rng = np.random.default_rng(8)
    a = rng.uniform(0, 60, (23, 2))
    b = np.concatenate([rng.uniform(0, 60, (37, 2)), a[:3], a[3:4] + 1e-9])
    got = jinc_kernel(a, b, 15.0, block_elements=block)
    assert got.shape == (23, 41) and np.array_equal(got, jinc_kernel(a, b, 15.0, block_elements=10 ** 6))
    assert np.abs(got - _dense_jinc(a, b, 15.0)).max() < 1e-14
    assert np.all(np.diagonal(got[:3, 37:40]) == 1.0) and 1.0 - 1e-15 < got[3, 40] <= 1.0
    assert jinc_kernel(a[:0], b, 15.0, block_elements=block).shape == (0, 41)
    assert jinc_kernel(a, b[:0], 15.0, block_elements=block).shape == (23, 0)


def test_prior_covariance_is_positive_semidefinite():
    rng = np.random.default_rng(3)
    sites = Sites(rng.uniform(0, 40, (60, 2)), rng.normal(0, 0.5, (60, 2)))
    k = prior_covariance(DeviationPrior(), sites, sites, np.array([20.0, 20.0]))
    assert np.allclose(k, k.T)
    assert np.linalg.eigvalsh(k).min() > -1e-12 * np.abs(k).max()


def test_placement_basis_is_the_first_order_height_change():
    # a placed part with no machining error: true - nominal = B @ (dz, dx, dy, rz, 0, 0)
    pl = centred_placement(dx=0.08, dy=-0.06, dz=0.03, rz_deg=0.15)
    part = as_made(5, amplitude_mm=1e-12, placement=pl)
    path = nominal_path(s1_traces()[4], 0.1)
    s = np.linspace(0, path.length_mm, 50)
    sites = path_sites(path, s)
    c = np.array([30.0, 20.0])  # the simulator rotates about the part centre
    coef = np.array([pl.dz, pl.dx, pl.dy, math.radians(pl.rz_deg), 0.0, 0.0])
    true_dz = part.true_height(sites.xy) - path.z_at(s)
    assert np.abs(placement_basis(sites, c) @ coef - true_dz).max() < 1e-3  # O(delta^2)
    assert np.ptp(true_dz) > 0.02  # and the effect itself is large


def test_gradient_from_normals_and_fallback():
    path = nominal_path(s1_traces()[7], 0.05)
    s = np.linspace(1, path.length_mm - 1, 20)
    g = path_gradient(path, s)
    assert np.abs(g - nominal_gradient(path.at(s)[:, :2])).max() < 2e-3
    bare = as_trace_polyline(path.points)  # no normals: only the along-trace slope
    gb = path_gradient(bare, s)
    tan = path.at(s + 0.01)[:, :2] - path.at(s - 0.01)[:, :2]
    tan /= np.linalg.norm(tan, axis=1, keepdims=True)
    assert np.abs(np.sum(gb * tan, 1) - np.sum(g * tan, 1)).max() < 5e-3


def test_posterior_matches_dense_formula_and_interpolates_without_noise():
    path = nominal_path(s1_traces()[2], 0.1)
    prior = DeviationPrior(amplitude_mm=0.15, wavelength_mm=15.0, sigma_mm=0.002)
    probes = path_sites(path, np.linspace(0, path.length_mm, 9))
    dz = np.sin(probes.xy[:, 1] / 5.0) * 0.05
    query = path_sites(path, np.linspace(0, path.length_mm, 33))
    c = path_center(path)
    post = fit_posterior(prior, probes, dz, center=c)
    k = prior_covariance(prior, probes, probes, c) + 0.002 ** 2 * np.eye(9)
    kq = prior_covariance(prior, query, probes, c)
    assert np.allclose(post.mean(query), kq @ np.linalg.solve(k, dz), atol=1e-12)
    var = np.diag(prior_covariance(prior, query, query, c)) - np.sum(
        kq * np.linalg.solve(k, kq.T).T, 1)
    assert np.allclose(post.sd(query), np.sqrt(var), atol=1e-9)
    exact = fit_posterior(DeviationPrior(amplitude_mm=0.15, wavelength_mm=15.0, sigma_mm=0.0),
                          probes, dz, center=c)
    assert np.abs(exact.mean(probes) - dz).max() < 1e-6
    assert exact.sd(probes).max() < 1e-5


def test_more_probes_never_raise_the_posterior_sd():
    path = nominal_path(s1_traces()[5], 0.1)
    prior = PlanParams(deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0).prior()
    query = path_sites(path, np.linspace(0, path.length_mm, 41))
    rng = np.random.default_rng(0)
    s = np.sort(rng.uniform(0, path.length_mm, 12))
    prev = np.inf * np.ones(41)
    for m in range(1, 13):
        sd = fit_posterior(prior, path_sites(path, s[:m]), np.zeros(m)).sd(query)
        assert np.all(sd <= prev + 1e-12)
        prev = sd


def test_bad_prior_is_a_typed_422():
    with pytest.raises(PriorError) as info:
        DeviationPrior(wavelength_mm=0.0)
    assert http_status(info.value)[0] == 422 and info.value.field == "wavelength_mm"
    with pytest.raises(PriorError) as info:
        PlanParams(placement_xy_mm=-1.0)
    assert info.value.field == "placement_xy_mm"


def test_a_paths_kept_centre_is_the_centre_from_scratch_and_not_the_callers_to_change():
    """path_center keeps each trace's centre: the first and every later call give, bit for
    bit, the mean of 65 points even in arc length (computed here independently), and
    changing a returned array changes no later answer."""
    path = as_trace_polyline(np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 1.0], [10.0, 20.0, 2.0]]))
    expected = path.at(np.linspace(0.0, path.length_mm, 65))[:, :2].mean(axis=0)
    first = path_center(path)
    assert np.array_equal(first, expected)
    first[:] = -1.0
    assert np.array_equal(path_center(path), expected)
