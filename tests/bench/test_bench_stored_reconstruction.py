"""Bench: storing and reading back a board's reconstructions (what a board reconstruct job
writes per trace and a board compensate job reads per trace), beside numpy's own writer and
reader of the same arrays.

Run: .venv/bin/python -m pytest tests/bench/test_bench_stored_reconstruction.py -s -o addopts="" -q -n 0

The dome (:func:`app.reference.boards.dome_part`) with BOARD_STORED_TRACES traces (default
200), its field plan, the as-made part's touches (seed 11, 1 um noise) and each trace's
field reconstruction, as the board API bench's core builds them.  Per trace, process CPU ms
(best of 5): :func:`app.reconstruction.stored.reconstruction_npz` and
:func:`~app.reconstruction.stored.read_reconstruction`, beside ``numpy.savez_compressed`` of
the same arrays read back through ``zipfile`` member by member (the reader's fallback); the
bytes per trace of each.  Every reconstruction read back equals the one written, array by
array and dtype by dtype.
"""

from __future__ import annotations

import io
import os
import time
import zipfile

import numpy as np
import pytest

from app.probing.field import plan_field
from app.probing.selection import PlanParams
from app.reconstruction.field import trace_reconstruction
from app.reconstruction.field_trust import checked_field
from app.reconstruction.reconstruct import ReconstructParams
from app.reconstruction.stored import (
    _npy_array,
    read_reconstruction,
    reconstruction_arrays,
    reconstruction_from_arrays,
    reconstruction_npz,
)
from app.reference.boards import as_made_board, board_path, board_traces, dome_part

TRACES = int(os.environ.get("BOARD_STORED_TRACES", "200"))
PROCESS = {"deviation_amplitude_mm": 0.15, "deviation_wavelength_mm": 15.0}


def board_reconstructions(n: int, seed: int = 11) -> list:
    part, params = dome_part(), PlanParams(**PROCESS)
    paths = [board_path(part, g, 0.05) for g in board_traces(part, n)]
    made = as_made_board(part, seed)
    plan = plan_field(paths, params)
    measured = plan.points.copy()
    measured[:, 2] = made.true_height(plan.xy) + np.random.default_rng(seed).normal(0, 0.001, len(plan.xy))
    fit = checked_field(params.prior(), plan.sites, plan.z, measured, plan.center, plan.trace, plan.s_mm,
                        np.zeros(len(plan.z), dtype=bool), 3.0, 0.005, learn=True).fit
    return [trace_reconstruction(fit, path, i, ReconstructParams(prior=params.prior())) for i, path in enumerate(paths)]


def numpy_npz(rec) -> bytes:  # type: ignore[no-untyped-def]
    out = io.BytesIO()
    np.savez_compressed(out, **reconstruction_arrays(rec))  # type: ignore[arg-type]
    return out.getvalue()


def numpy_read(data: bytes, nominal):  # type: ignore[no-untyped-def]
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        arrays = {name[:-4]: _npy_array(archive.read(name)) for name in archive.namelist()}
    return reconstruction_from_arrays(arrays, nominal)


def best_ms(work, count: int, repeats: int = 5) -> float:  # type: ignore[no-untyped-def]
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        work()
        times.append(time.process_time() - t0)
    return min(times) / count * 1e3


@pytest.mark.timeout(1800)
def test_stored_reconstructions_write_and_read():
    recs = board_reconstructions(TRACES)
    ours, theirs = [reconstruction_npz(r) for r in recs], [numpy_npz(r) for r in recs]
    for rec, data in zip(recs, ours):
        back, written = reconstruction_arrays(read_reconstruction(data, rec.nominal)), reconstruction_arrays(rec)
        assert back.keys() == written.keys()
        assert all(back[k].dtype == written[k].dtype and np.array_equal(back[k], written[k]) for k in written)
    n = len(recs)
    write = best_ms(lambda: [reconstruction_npz(r) for r in recs], n)
    write_np = best_ms(lambda: [numpy_npz(r) for r in recs], n)
    read = best_ms(lambda: [read_reconstruction(d, r.nominal) for d, r in zip(ours, recs)], n)
    read_np = best_ms(lambda: [numpy_read(d, r.nominal) for d, r in zip(theirs, recs)], n)
    print(f"\n\n{n} dome-board reconstructions, process CPU ms per trace (best of 5), load {os.getloadavg()[0]:.1f}")
    print(f"write: reconstruction_npz {write:.3f}; numpy.savez_compressed {write_np:.3f} ({write_np / write:.1f}x)")
    print(f"read:  read_reconstruction {read:.3f}; zipfile member by member over the deflated archive {read_np:.3f} "
          f"({read_np / read:.1f}x)")
    print(f"bytes per trace: {sum(map(len, ours)) / n:.0f} stored; {sum(map(len, theirs)) / n:.0f} deflated")
