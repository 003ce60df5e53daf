"""A reconstruction written to an NPZ and read back is the same reconstruction: the height
along the trace bit for bit (compensate reads it instead of rebuilding it), every method."""

from __future__ import annotations

import numpy as np
import pytest

from app.probing.deviation_prior import DeviationPrior
from app.probing.field import plan_field
from app.probing.selection import PlanParams
from app.reconstruction import ReconstructionError, ReconstructParams, reconstruct
from app.reconstruction.field import fit_field, trace_reconstruction
from app.reconstruction.stored import read_reconstruction, reconstruction_arrays, reconstruction_npz
from app.reference.s1 import nominal_path, s1_traces

PRIOR = PlanParams(deviation_amplitude_mm=0.1, deviation_wavelength_mm=20.0).prior()


@pytest.fixture(scope="module")
def path():
    return nominal_path(s1_traces()[7], 0.1)


def _measured(path, count=9, seed=3):
    s = np.linspace(0.5, path.length_mm - 0.5, count)
    pts = path.at(s)
    rng = np.random.default_rng(seed)
    pts[:, 2] += 0.03 * np.sin(s / 4.0) + rng.normal(0.0, 0.001, count)
    return pts


def _assert_same(rec, back, path):
    q = np.linspace(-1.0, path.length_mm + 1.0, 997)  # beyond the ends too (clipped to the trace)
    assert np.array_equal(back.height_at_s(q), rec.height_at_s(q))
    assert back.method == rec.method and back.span_mm == rec.span_mm
    assert back.max_mm == rec.max_mm and back.rms_mm == rec.rms_mm
    assert np.array_equal(back.samples, rec.samples)
    assert np.array_equal(back.curve.control_points, rec.curve.control_points)
    assert np.array_equal(back.curve.knots, rec.curve.knots)
    assert np.array_equal(back.clean.points, rec.clean.points) and back.clean.outliers == rec.clean.outliers
    assert back.to_result() == rec.to_result()


@pytest.mark.parametrize("method", ["interpolate", "approximate", "deviation", "kriging"])
def test_every_method_reads_back_bit_for_bit(path, method):
    rec = reconstruct(path, _measured(path), method, sigma_mm=0.001, params=ReconstructParams(prior=PRIOR))
    back = read_reconstruction(reconstruction_npz(rec), path)
    assert back.height_model.kind == rec.height_model.kind
    _assert_same(rec, back, path)


def test_kriging_with_other_traces_as_context_reads_back(path):
    other = nominal_path(s1_traces()[6], 0.1)
    rec = reconstruct(path, _measured(path), "kriging", sigma_mm=0.001, params=ReconstructParams(prior=PRIOR),
                      context=[(other, _measured(other, 7, seed=4))])
    _assert_same(rec, read_reconstruction(reconstruction_npz(rec), path), path)


def test_a_field_trace_reads_back():
    paths = [nominal_path(s1_traces()[i], 0.1) for i in (0, 3, 6)]
    plan = plan_field(paths, PlanParams(deviation_amplitude_mm=0.1, deviation_wavelength_mm=20.0), "on_traces", None)
    prior = DeviationPrior(**{**PRIOR.__dict__, "sigma_mm": 1e-3})
    dz = 0.02 * np.sin(plan.xy[:, 0] / 5.0) + 0.003 * plan.xy[:, 1]
    fit = fit_field(prior, plan.sites, plan.z, np.column_stack([plan.xy, plan.z + dz]), plan.center,
                    plan.trace, plan.s_mm)
    rec = trace_reconstruction(fit, paths[1], 1)
    back = read_reconstruction(reconstruction_npz(rec), paths[1])
    assert back.height_model.kind == "field"
    _assert_same(rec, back, paths[1])


def test_a_different_nominal_or_a_missing_array_is_refused(path):
    rec = reconstruct(path, _measured(path), "deviation", sigma_mm=0.001)
    with pytest.raises(ReconstructionError, match="nominal"):
        read_reconstruction(reconstruction_npz(rec), nominal_path(s1_traces()[6], 0.1))
    arrays = reconstruction_arrays(rec)
    del arrays["height.dz_t"]
    import io
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    with pytest.raises(ReconstructionError, match="incomplete"):
        read_reconstruction(buf.getvalue(), path)


def test_the_members_read_as_numpy_reads_them_and_pickles_are_refused(path):
    """The header numpy writes is read directly; every member equals numpy's own reading of
    it (dtype, shape, values), a Fortran-ordered member goes through numpy's reader, and an
    object array (a pickle) or a cut archive is refused."""
    import io
    import zipfile

    from app.reconstruction.stored import _npy_array

    rec = reconstruct(path, _measured(path), "deviation", sigma_mm=0.001)
    data = reconstruction_npz(rec)
    with np.load(io.BytesIO(data), allow_pickle=False) as archive, zipfile.ZipFile(io.BytesIO(data)) as z:
        for name in archive.files:
            mine, theirs = _npy_array(z.read(name + ".npy")), archive[name]
            assert mine.dtype == theirs.dtype and mine.shape == theirs.shape and np.array_equal(mine, theirs), name
    odd = {**reconstruction_arrays(rec), "curve_control_points": np.asfortranarray(rec.curve.control_points)}
    buf = io.BytesIO()
    np.savez(buf, **odd)
    assert np.array_equal(read_reconstruction(buf.getvalue(), path).curve.control_points, rec.curve.control_points)
    pickled = io.BytesIO()
    np.savez(pickled, **{**reconstruction_arrays(rec), "method": np.asarray([{"a": 1}], dtype=object)})
    with pytest.raises(ReconstructionError, match="readable NPZ"):
        read_reconstruction(pickled.getvalue(), path)
    with pytest.raises(ReconstructionError, match="readable NPZ"):
        read_reconstruction(data[: len(data) // 2], path)


def test_members_are_what_numpy_writes_stored_and_an_older_deflated_archive_still_reads(path):
    """Every member is stored (not deflated), dated as numpy dates them (the same
    reconstruction is the same bytes whenever it is written: a retried board job's are a clean
    run's) and byte for byte what ``numpy.lib.format`` writes for its array; a reconstruction
    stored deflated (``numpy.savez_compressed``, how they were stored before) reads back the
    same; a stored member whose bytes changed fails its CRC-32 and is refused."""
    import io
    import zipfile

    rec = reconstruct(path, _measured(path), "kriging", sigma_mm=0.001, params=ReconstructParams(prior=PRIOR))
    data = reconstruction_npz(rec)
    arrays = reconstruction_arrays(rec)
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        assert sorted(z.namelist()) == sorted(name + ".npy" for name in arrays)
        for info in z.infolist():
            assert info.compress_type == zipfile.ZIP_STORED, info.filename
            assert info.date_time == (1980, 1, 1, 0, 0, 0), info.filename  # not the time it was written
            numpy_own = io.BytesIO()
            np.lib.format.write_array(numpy_own, np.asarray(arrays[info.filename[:-4]]), allow_pickle=False)
            assert z.read(info) == numpy_own.getvalue(), info.filename
    deflated = io.BytesIO()
    np.savez_compressed(deflated, **arrays)
    _assert_same(rec, read_reconstruction(deflated.getvalue(), path), path)
    _assert_same(rec, read_reconstruction(data, path), path)
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        info = z.getinfo("curve_control_points.npy")
    at = info.header_offset + 30 + len(info.filename) + len(info.extra) + 200  # inside the array's data
    altered = data[:at] + bytes([data[at] ^ 0xFF]) + data[at + 1:]
    with pytest.raises(ReconstructionError, match="readable NPZ"):
        read_reconstruction(altered, path)


def _zipfile_archive(members):
    """The archive ``zipfile`` writes for ``members`` (name, bytes): each a ``ZipInfo(name)``, stored."""
    import io
    import zipfile

    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as archive:
        for name, data in members:
            archive.writestr(zipfile.ZipInfo(name), data)
    return out.getvalue()


def test_the_archive_is_byte_for_byte_what_zipfile_and_numpy_write(path):
    """A stored reconstruction is exactly the archive ``zipfile`` makes of the members
    ``numpy.lib.format.write_array`` writes (the packing here only saves their bookkeeping);
    so is any list of members, empty ones and none at all included, and a name beyond ASCII
    (left to ``zipfile``)."""
    import io

    from app.reconstruction.stored import stored_archive

    rec = reconstruct(path, _measured(path), "deviation", sigma_mm=0.001)
    members = []
    for name, array in reconstruction_arrays(rec).items():
        member = io.BytesIO()
        np.lib.format.write_array(member, np.asarray(array), allow_pickle=False)
        members.append((name + ".npy", member.getvalue()))
    assert reconstruction_npz(rec) == _zipfile_archive(members)
    rng = np.random.default_rng(7)
    for trial in range(40):
        some = [(f"m{i}.{trial}.npy", rng.bytes(int(rng.integers(0, 2000)))) for i in range(int(rng.integers(0, 12)))]
        assert stored_archive(some) == _zipfile_archive(some), trial
    assert stored_archive([("höhe.npy", b"\x01\x02")]) == _zipfile_archive([("höhe.npy", b"\x01\x02")])
