"""Layer-thickness planners: uniform, the published rules (area, multi-cavity), cusp.

Each planner takes a :class:`~app.slicing.layers.Sampler` (sections by height) and
:class:`~app.slicing.layers.SliceParams` and returns a :class:`LayerPlan` ``(layers, notes)``.

The multi-cavity slicing paper, steps 1-11 as published (``area`` mode = steps without step 9):
  3-4  slice at Z = z_min, store rings, A_i and the inner-ring count n;
  5    Z_step = l_max, Z' = Z + Z_step; stop when Z' > z_max;
  6    eps = |A_(i+1) - A_i| / A_i <= eps0 ? -> 9 : -> 7;
  7    Z_step -= l_min; if Z_step < l_min: Z_step = l_min, -> 10;
  8    slice at Z + Z_step, eps <= eps0 ? -> 9 : -> 7;
  9    theta, mu = theta * sigma / n of the current layer; mu0 <= mu <= mu1 -> Z_step = l_min,
       otherwise Z_step = l_max (literal, ``step9_resets_to_lmax``) or keep (default);
  10   Z' = Z + Z_step, store the rings at Z', A_i = A_(i+1), Z = Z', -> 5.
Deviation from the print, stated in ``notes``: the seed stops when Z + l_max > z_max and
leaves the top unsliced; we cap the step at the remaining height so the part is complete.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from app.geometry.tolerance import LENGTH_EPS_MM
from app.slicing.cavity import cavity_mu
from app.slicing.errors import SlicingError
from app.slicing.layers import Layer, Sampler, SliceParams, make_layer

_STEP_EPS = LENGTH_EPS_MM  # mm; float slack when comparing accumulated steps
#: a facet with |n_z| > 1 - this is horizontal (flat): its height is a snap level
_FLAT_NZ_SLACK = 1e-9
#: round-off slack (in bins) so that a slab ending exactly on a bin edge does not reach into the next bin
_BIN_ROUNDOFF = 1e-9


class LayerPlan(NamedTuple):
    """A planner's result: the layers bottom to top and remarks on how the rule was read."""

    layers: list[Layer]
    notes: list[str]


def _check_count(n: int, params: SliceParams) -> None:
    if n > params.max_layers:
        raise SlicingError(f"more than {params.max_layers} layers needed", field="params",
                           value=n)


def uniform_plan(height: float, layer_mm: float, remainder: str, z_tol: float) -> list[float]:
    """Slab thicknesses (mm) that stack to ``height`` with no sliver on top.

    ``remainder="distribute"``: n = round(height / layer_mm) (at least 1) equal slabs of
    height / n, within layer_mm / (2 n) of the nominal.  ``"merge"``: slabs of exactly
    ``layer_mm``; a remainder under half a layer joins the last slab (<= 1.5 x layer_mm),
    a larger one is a slab of its own (>= 0.5 x layer_mm).  A remainder below ``z_tol``
    is float noise and is dropped into the last slab either way.
    """
    if remainder == "distribute":
        n = max(1, round(height / layer_mm))
        return [height / n] * n
    full = int(math.floor((height + z_tol) / layer_mm))
    rest = height - full * layer_mm
    if full == 0:
        return [height]
    if rest < 0.5 * layer_mm:
        return [layer_mm] * (full - 1) + [layer_mm + rest]
    return [layer_mm] * full + [rest]


def uniform_layers(sampler: Sampler, params: SliceParams) -> LayerPlan:
    """Slabs of ``layer_mm`` with the remainder distributed or merged (no sliver), sampled
    mid-height."""
    z0, z1 = sampler.prepared.z_min, sampler.prepared.z_max
    plan = uniform_plan(z1 - z0, params.layer_mm, params.remainder, params.z_tol)
    _check_count(len(plan), params)
    bounds = z0 + np.concatenate([[0.0], np.cumsum(plan)])
    bounds[-1] = z1
    layers: list[Layer] = []
    prev: float | None = None
    for k in range(len(plan)):
        bottom, top = float(bounds[k]), float(bounds[k + 1])
        off = abs(top - bottom - params.layer_mm)
        reason = "uniform" if off < _STEP_EPS else (
            f"uniform: height / {len(plan)} layers (remainder distributed)" if params.remainder == "distribute"
            else "uniform (last layer: remainder merged)" if top - bottom > params.layer_mm
            else "uniform (last layer: remaining height >= half a layer)")
        lay = make_layer(k, bottom, top, 0.5 * (bottom + top), sampler, prev, reason, params)
        layers.append(lay)
        prev = lay.area
    notes: list[str] = []
    if len(plan) and abs(plan[-1] - params.layer_mm) > _STEP_EPS:
        notes.append(f"the part's height {z1 - z0:.6g} mm is not a multiple of {params.layer_mm} mm: "
                     + (f"{len(plan)} layers of {plan[0]:.6g} mm" if params.remainder == "distribute"
                        else f"last layer {plan[-1]:.6g} mm"))
    return LayerPlan(layers, notes)


def _no_sliver(z: float, step: float, z_max: float, params: SliceParams) -> float:
    """The slab top after ``z + step``: a rest under ``l_min`` above it is merged into this
    slab (or, when that would pass ``l_max``, the two are split evenly)."""
    rest = z_max - (z + step)
    if rest <= params.z_tol:
        return z_max
    if rest < params.l_min:
        return z_max if step + rest <= params.l_max + _STEP_EPS else z + 0.5 * (step + rest)
    return z + step


def area_layers(sampler: Sampler, params: SliceParams) -> LayerPlan:
    """The published area-deviation rule, plus step 9 (multi-cavity) in ``cavity`` mode."""
    z_min, z_max = sampler.prepared.z_min, sampler.prepared.z_max
    z = z_min
    _, st_i = sampler.section(z)
    if st_i.area <= 0:
        raise SlicingError(f"the section at z_min={z_min:.6g} mm has no area", field="mesh",
                           value=z_min)
    a_i = st_i.area
    layers: list[Layer] = []
    notes = ["the published rule stops when Z + l_max > z_max; the last step is capped at the "
             "remaining height instead so the whole part is sliced"]
    if params.mode == "cavity":
        notes.append(f"theta rule: {params.theta_rule}; step 9 "
                     + ("resets non-cavity steps to l_max (literal)" if
                        params.step9_resets_to_lmax else "keeps the area rule's step"))
    while z_max - z > params.z_tol:
        remaining = z_max - z
        step = min(params.l_max, remaining)                        # step 5
        _, st = sampler.section(z + step)
        eps = abs(st.area - a_i) / a_i
        reason = "eps <= eps0 at l_max" if step >= params.l_max - _STEP_EPS \
            else "eps <= eps0 at the remaining height"
        floor_hit = False
        while eps > params.eps0:                                    # steps 6-8
            step -= params.l_min                                    # step 7
            if step < params.l_min - _STEP_EPS:
                step = min(params.l_min, remaining)
                floor_hit = True
                reason = f"area change: eps {eps:.3g} > eps0 even at l_min"
                break
            _, st = sampler.section(z + step)                       # step 8
            eps = abs(st.area - a_i) / a_i
            reason = f"area change: eps {eps:.3g} <= eps0 at {step:.6g} mm"
        if not floor_hit and params.mode == "cavity":               # step 9
            mu = cavity_mu(st_i, params.sigma0, params.theta_rule)
            if params.mu0 <= mu <= params.mu1:
                step = min(params.l_min, remaining)
                reason = f"multi-cavity: mu {mu:.4g} in [mu0, mu1], sigma {st_i.sigma:.3g}"
            elif params.step9_resets_to_lmax:
                step = min(params.l_max, remaining)
                reason += " (step 9: l_max)"
        top = _no_sliver(z, step, z_max, params)                    # step 10
        sample = top if params.seed_sample == "top" else 0.5 * (z + top)
        lay = make_layer(len(layers), z, top, sample, sampler,
                         layers[-1].area if layers else a_i, reason, params)
        layers.append(lay)
        _check_count(len(layers), params)
        _, st_i = sampler.section(top)
        a_i, z = st_i.area, top
    return LayerPlan(layers, notes)


class _RangeMax:
    """Max of per-facet values over z bins: range-max painting + O(1) range queries."""

    def __init__(self, lo_bin: npt.NDArray[np.int64], hi_bin: npt.NDArray[np.int64], values: npt.NDArray[np.float64],
                 n_bins: int) -> None:
        """Facet k spans bins ``lo_bin[k]..hi_bin[k]`` (inclusive) with value ``values[k]``."""
        levels = max(1, int(np.ceil(np.log2(max(n_bins, 2)))) + 1)
        paint = np.zeros((levels, n_bins + 1))
        length = hi_bin - lo_bin + 1
        k = np.floor(np.log2(np.maximum(length, 1))).astype(int)
        np.maximum.at(paint, (k, lo_bin), values)
        np.maximum.at(paint, (k, hi_bin - (1 << k) + 1), values)
        for lev in range(levels - 1, 0, -1):
            half = 1 << (lev - 1)
            row = paint[lev, :n_bins]
            paint[lev - 1, :n_bins] = np.maximum(paint[lev - 1, :n_bins], row)
            paint[lev - 1, half:n_bins] = np.maximum(paint[lev - 1, half:n_bins],
                                                     row[:n_bins - half])
        self.table = [paint[0, :n_bins].copy()]
        lev = 1
        while (1 << lev) <= n_bins:
            prev = self.table[-1]
            half = 1 << (lev - 1)
            self.table.append(np.maximum(prev[:len(prev) - half], prev[half:]))
            lev += 1

    def query(self, i0: int, i1: int) -> float:
        """Max over bins i0..i1 inclusive."""
        k = int(math.floor(math.log2(i1 - i0 + 1)))
        t = self.table[k]
        return float(max(t[i0], t[i1 - (1 << k) + 1]))


def cusp_layers(sampler: Sampler, params: SliceParams) -> LayerPlan:
    """Cusp-height rule: t = clamp(cusp_mm / max|n_z|, l_min, l_max) over the slab's facets.

    Facets with |n_z| > 1 - ``_FLAT_NZ_SLACK`` (horizontal) are excluded and their heights become snap
    levels: a slab is cut at a flat face when that keeps it at least ``l_min`` thick.
    """
    pm = sampler.prepared
    z_min, z_max = pm.z_min, pm.z_max
    nz = np.abs(pm.normals_z)
    flat = nz > 1 - _FLAT_NZ_SLACK
    bin_mm = min(params.l_min, params.cusp_mm) / 4.0
    n_bins = max(1, int(math.ceil((z_max - z_min) / bin_mm)))
    _check_count(int((z_max - z_min) / params.l_min), params)
    lo = np.clip(((pm.face_z[~flat, 0] - z_min) / bin_mm).astype(np.int64), 0, n_bins - 1)
    hi = np.clip(((pm.face_z[~flat, 1] - z_min) / bin_mm).astype(np.int64), 0, n_bins - 1)
    rmq = _RangeMax(lo, hi, nz[~flat], n_bins)
    flats = np.unique(np.round(pm.face_z[flat, 0], 9))
    flats = flats[(flats > z_min + params.z_tol) & (flats < z_max - params.z_tol)]
    layers: list[Layer] = []
    z = z_min
    while z_max - z > params.z_tol:
        t = min(params.l_max, z_max - z)
        reason = "l_max" if t >= params.l_max - _STEP_EPS else "top: remaining height"
        while True:
            i0 = min(int((z - z_min) / bin_mm), n_bins - 1)
            i1 = min(int((z + t - z_min) / bin_mm - _BIN_ROUNDOFF), n_bins - 1)
            m = rmq.query(i0, max(i0, i1))
            t_new = t if m <= 0 else min(t, max(params.l_min, params.cusp_mm / m))
            if t_new >= t - _STEP_EPS:
                break
            t = t_new
            reason = f"cusp: max |n_z| {m:.3g}"
        slack = params.z_tol
        inside = flats[(flats >= z + params.l_min - slack) & (flats < z + t - slack)]
        ahead = flats[(flats >= z + t - slack) & (flats < z + t + params.l_min - slack)]
        if len(inside):
            t = float(inside[0] - z)
            reason = "snapped to a flat face"
        elif len(ahead) and ahead[0] - z - params.l_min >= params.l_min:
            t = float(ahead[0] - z - params.l_min)
            reason = "shortened so the next layer ends on a flat face"
        top = _no_sliver(z, t, z_max, params)
        lay = make_layer(len(layers), z, top, 0.5 * (z + top), sampler,
                         layers[-1].area if layers else None, reason, params)
        layers.append(lay)
        _check_count(len(layers), params)
        z = top
    return LayerPlan(layers, [f"cusp height {params.cusp_mm} mm; z bins of {bin_mm:.4g} mm"])
