"""A held reconstruction stands for its stored bytes: the same programs as reading them back."""

from __future__ import annotations

import numpy as np
import pytest

from app.compensation.standoff import CompensationParams, compensate_trace
from app.jobs.held_reconstructions import HELD, HeldReconstructions, stored_reconstruction
from app.probing.field import plan_field
from app.probing.selection import PlanParams
from app.reconstruction.field import trace_reconstruction
from app.reconstruction.field_trust import checked_field
from app.reconstruction.preprocess import ReconstructionError
from app.reconstruction.reconstruct import ReconstructParams
from app.reconstruction.stored import read_reconstruction, reconstruction_npz
from app.reference.boards import as_made_board, board_path, board_traces, dome_part


@pytest.fixture(scope="module")
def rebuilt():
    """Eight traces of the dome board, reconstructed from a field fitted to noisy touches."""
    part = dome_part()
    params = PlanParams(deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0)
    paths = [board_path(part, g, 0.05) for g in board_traces(part, 8)]
    made = as_made_board(part, 3)
    plan = plan_field(paths, params)
    measured = plan.points.copy()
    measured[:, 2] = made.true_height(plan.xy) + np.random.default_rng(3).normal(0, 0.001, len(plan.xy))
    fit = checked_field(params.prior(), plan.sites, plan.z, measured, plan.center, plan.trace, plan.s_mm,
                        np.zeros(len(plan.z), dtype=bool), 3.0, 0.005, learn=True).fit
    return [trace_reconstruction(fit, path, i, ReconstructParams(prior=params.prior())) for i, path in enumerate(paths)]


def test_the_held_reconstruction_writes_the_programs_its_stored_bytes_write(rebuilt):
    import hashlib

    core = CompensationParams(standoff_mm=0.1)
    for rec in rebuilt:
        data = reconstruction_npz(rec)
        HELD.hold(rec, data)
        reads = []
        taken = stored_reconstruction(hashlib.sha256(data).hexdigest(), lambda d=data, r=reads: r.append(1) or d,
                                      rec.nominal)
        assert taken is rec and not reads  # held: the bytes are not read
        read = read_reconstruction(data, rec.nominal)
        a, b = compensate_trace(taken, core), compensate_trace(read, core)
        assert a.program == b.program and a.nominal_program == b.nominal_program
        # taken once: the next read parses the bytes
        again = stored_reconstruction(hashlib.sha256(data).hexdigest(), lambda d=data, r=reads: r.append(1) or d,
                                      rec.nominal)
        assert reads == [1] and again is not rec
        assert compensate_trace(again, core).program == a.program


def test_a_held_reconstruction_over_another_nominal_is_read_and_refused(rebuilt):
    import hashlib

    rec, other = rebuilt[0], rebuilt[1]
    data = reconstruction_npz(rec)
    HELD.hold(rec, data)
    with pytest.raises(ReconstructionError, match="nominal"):  # as reading the bytes over that nominal says
        stored_reconstruction(hashlib.sha256(data).hexdigest(), lambda: data, other.nominal)


def test_held_reconstructions_are_bounded_by_their_stored_bytes(rebuilt):
    import hashlib

    data = [reconstruction_npz(rec) for rec in rebuilt[:4]]
    held = HeldReconstructions(max_bytes=sum(len(d) for d in data[1:]))
    for rec, d in zip(rebuilt, data):
        held.hold(rec, d)
    assert len(held) == 3  # the oldest let go
    assert held.take(hashlib.sha256(data[0]).hexdigest()) is None
    assert held.take(hashlib.sha256(data[3]).hexdigest()) is rebuilt[3]
    assert held.take(hashlib.sha256(data[3]).hexdigest()) is None and len(held) == 2
