"""An upload's peak memory on a real server stays within 4 x the file (binary STL)."""

from __future__ import annotations

import trimesh

from tests.upload_memory import measure_upload


def test_upload_peak_memory_is_at_most_four_times_the_file(tmp_path):
    stl = tmp_path / "sphere.stl"
    stl.write_bytes(trimesh.creation.icosphere(subdivisions=7, radius=20.0).export(file_type="stl"))  # 16 MB
    peak = measure_upload(stl, tmp_path / "data")
    assert peak.part["faces"] == 327_680 and peak.part["watertight"] is True
    assert peak.ratio <= 4.0, f"peak growth {peak.growth_bytes / 2**20:.1f} MiB = {peak.ratio:.2f} x the file"
