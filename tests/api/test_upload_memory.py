"""An upload's peak memory on a real server stays within 4 x the file (binary STL)."""

from __future__ import annotations

import trimesh

from tests.helpers.upload_memory import measure_upload


def test_upload_peak_memory_is_at_most_four_times_the_file(tmp_path):
    stl = tmp_path / "sphere.stl"
    stl.write_bytes(trimesh.creation.icosphere(subdivisions=7, radius=20.0).export(file_type="stl"))  # 16 MB
    peak = measure_upload(stl, tmp_path / "data")
    assert peak.part["faces"] == 327_680 and peak.part["watertight"] is True
    assert peak.ratio <= 4.0, f"peak growth {peak.growth_bytes / 2**20:.1f} MiB = {peak.ratio:.2f} x the file"


def test_a_300k_line_program_uploads_within_100_mb_and_6_s_of_server_cpu(tmp_path):
    """The default suite's share of the 3M-line bench: memory growth independent of the lines,
    and a CPU budget (the server's own time) that a loaded box cannot fail."""
    from tests.helpers.upload_memory import measure_program_upload, write_program

    path = tmp_path / "long.gcode"
    write_program(path, 300_000)
    upload = measure_program_upload(path, tmp_path / "data")
    assert (upload.program["lines"], upload.program["commands"]) == (300_000, 300_000)
    assert upload.program["bounds"] == [[0.0, 0.5, 0.2], [99.6, 36.5, 0.2]]
    assert upload.growth_bytes <= 100 * 2**20, f"{upload.growth_bytes / 2**20:.0f} MiB"
    assert upload.cpu_s <= 6.0, f"{upload.cpu_s:.1f} s of server CPU for 300k lines"
