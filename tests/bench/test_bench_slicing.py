"""Slicing / fill / estimator benchmarks (one run, side by side).

Run: .venv/bin/python -m pytest tests/bench/test_bench_slicing.py -s -o addopts="" -q

Reference slicers (PrusaSlicer, Slic3r, CuraEngine) are used when installed; CuraEngine
also needs Cura's definition files (``fdmprinter.def.json``): set
CURA_RESOURCES to a ``resources`` directory holding ``definitions/`` and
``extruders/`` (e.g. extracted with ``apt-get download cura; dpkg-deb -x cura_*.deb x``;
then CURA_RESOURCES=x/usr/share/cura/resources).  (CONFORMA_* variables are cleared by
tests/conftest.py, hence the name.)
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from app.gcode.estimator import MachineLimits, estimate_gcode
from app.gcode.fdm import FdmParams, write_fdm_gcode
from app.slicing import SliceParams, slice_mesh
from app.slicing.layers import Sampler
from app.slicing.mesh_prep import prepare_mesh
from app.slicing.toolpath import ToolpathParams, plan_toolpath
from tests.slicing.conftest import cavity_block, channel_block

PROFILES = {
    "marlin-default a=1000 jd=0.013": MachineLimits(accel_mm_s2=1000, travel_accel_mm_s2=1000,
                                                    junction_deviation_mm=0.013),
    "mk3-like a=1250 jd=0.02": MachineLimits(accel_mm_s2=1250, travel_accel_mm_s2=1250,
                                             junction_deviation_mm=0.02),
}


def _table(title: str, header: list[str], rows: list[list]) -> None:
    cells = [header] + [[f"{v:.4g}" if isinstance(v, float) else str(v) for v in r]
                        for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    print(f"\n== {title}")
    for k, r in enumerate(cells):
        print("  " + "  ".join(c.rjust(w) for c, w in zip(r, widths)))
        if k == 0:
            print("  " + "  ".join("-" * w for w in widths))


def test_bench_slice_large_mesh():
    mesh = trimesh.creation.icosphere(subdivisions=8, radius=20.0)       # 1,310,720 faces
    t0 = time.perf_counter()
    prepared = prepare_mesh(mesh)
    t_prep = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = slice_mesh(prepared, SliceParams(mode="uniform", layer_mm=40.0 / 500))
    t_slice = time.perf_counter() - t0
    assert len(res.layers) == 500
    k = 50                                    # trimesh reference on every 10th plane
    heights = np.array([lay.z_sample for lay in res.layers])[::10][:k]
    t0 = time.perf_counter()
    ref = trimesh.intersections.mesh_multiplane(mesh, np.zeros(3), np.array([0, 0, 1.0]),
                                                heights)
    t_ref = (time.perf_counter() - t0) * 500 / k
    # same sections: perimeter lengths agree
    for lines, lay in zip(ref[0][:10], res.layers[::10][:10]):
        ref_len = np.linalg.norm(lines[:, 1] - lines[:, 0], axis=1).sum()
        ours = sum(np.linalg.norm(np.diff(np.vstack([r, r[:1]]), axis=0), axis=1).sum()
                   for isl in lay.islands for r in isl.rings())
        assert ours == pytest.approx(ref_len, rel=1e-4)
    _table(f"slice {len(mesh.faces):,} faces into 500 layers", ["method", "s", "x ours"],
           [["ours: manifold3d slice -> nested rings", t_slice, 1.0],
            ["  (mesh checks + manifold build, once)", t_prep, t_prep / t_slice],
            [f"trimesh mesh_multiplane ({k} planes x {500 // k})", t_ref, t_ref / t_slice]])
    assert t_slice <= 2.0, f"goal: <= 2 s for 500 layers, measured {t_slice:.2f} s"


def _fill_rows(res, infill, limits):
    rows, out = [], {}
    for pattern in ("lines", "raster", "zone", "contour", "hilbert", "hilbert_merged"):
        t0 = time.perf_counter()
        tp = plan_toolpath(res, ToolpathParams(pattern=pattern, infill=infill, perimeters=1,
                                               limits=limits))
        g = write_fdm_gcode(tp, FdmParams(home=False))
        t_plan = time.perf_counter() - t0
        est = estimate_gcode(g, limits).total_s
        out[pattern] = (est, tp.totals)
        rows.append([pattern, t_plan, tp.totals.path_mm, tp.totals.travel_mm, tp.totals.turns,
                     tp.totals.jumps, est])
    for r in rows:
        r.append(r[6] / out["lines"][0])
    return rows, out


def test_bench_fractal_fills():
    res = slice_mesh(trimesh.creation.box((40.0, 40.0, 1.0)), SliceParams(layer_mm=0.2))
    failures = []
    for infill in (1.0, 0.2):
        for name, limits in PROFILES.items():
            rows, out = _fill_rows(res, infill, limits)
            _table(f"fills, 40x40 mm block, 5 layers, infill {infill:.0%}, estimator "
                   f"{limits.describe()}",
                   ["pattern", "plan+gcode s", "path mm", "travel mm", "turns", "jumps",
                    "est s", "x lines"], rows)
            merged, plain, lines = out["hilbert_merged"], out["hilbert"], out["lines"]
            gain = 1 - merged[0] / plain[0]
            print(f"  improved fractal vs plain Hilbert: {gain:.1%} less time (goal >= 15 %), "
                  f"turns {merged[1].turns} vs {plain[1].turns}; vs lines "
                  f"{merged[0] / lines[0]:.2f}x (goal <= 1.3x)")
            if gain < 0.15 or merged[1].turns >= plain[1].turns or \
                    merged[0] > 1.3 * lines[0]:
                failures.append((infill, name, gain, merged[0] / lines[0]))
    assert not failures, failures


def _volume_error(res, prepared, dz=0.005):
    """Integral of |A(z) - A_layer| dz over the part (mm^3): staircase volume deviation."""
    sampler = Sampler(prepared, 1e-6)
    err = 0.0
    for lay in res.layers:
        n = max(2, int(np.ceil(lay.thickness / dz)))
        zs = lay.z_bottom + (np.arange(n) + 0.5) * lay.thickness / n
        areas = np.array([sampler.section(z)[1].area for z in zs])
        err += float(np.abs(areas - lay.area).sum() * lay.thickness / n)
    return err


def test_bench_adaptive_vs_uniform():
    parts = {"sphere r=10": trimesh.creation.icosphere(subdivisions=5, radius=10.0),
             "6-cavity block 40x10x6": cavity_block(6, band=(2.0, 4.0), radius=1.4),
             "6 horizontal channels r=1.4": channel_block(6)}
    modes = {"uniform l_max 0.1": SliceParams(mode="uniform", layer_mm=0.1),
             "uniform l_min 0.03": SliceParams(mode="uniform", layer_mm=0.03),
             "area (seed)": SliceParams(mode="area", l_min=0.03, l_max=0.1),
             "area (seed, mid-sampled)": SliceParams(mode="area", l_min=0.03, l_max=0.1,
                                                     seed_sample="mid"),
             "cavity (seed, sigma0 .05)": SliceParams(mode="cavity", l_min=0.03, l_max=0.1,
                                                      sigma0=0.05),
             "cavity (seed, mid-sampled)": SliceParams(mode="cavity", l_min=0.03, l_max=0.1,
                                                       sigma0=0.05, seed_sample="mid"),
             "cusp 0.01 mm (ours)": SliceParams(mode="cusp", l_min=0.03, l_max=0.1,
                                                cusp_mm=0.01)}
    for pname, mesh in parts.items():
        prepared = prepare_mesh(mesh)
        rows = []
        for mname, params in modes.items():
            t0 = time.perf_counter()
            res = slice_mesh(prepared, params)
            dt = time.perf_counter() - t0
            err = _volume_error(res, prepared)
            rows.append([mname, len(res.layers), dt, err, 100 * err / prepared.volume])
        base = rows[0][1]
        for r in rows:
            r.insert(2, r[1] / base)
        _table(f"adaptive vs uniform: {pname} (volume {prepared.volume:.1f} mm^3)",
               ["mode", "layers", "x uniform", "s", "vol. dev mm^3", "vol. dev %"], rows)


def _hms(text: str) -> float:
    total = 0.0
    for val, unit in re.findall(r"(\d+)([dhms])", text):
        total += int(val) * {"d": 86400, "h": 3600, "m": 60, "s": 1}[unit]
    return total


def _run(cmd, cwd, env=None):
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=600, env=env)
    return time.perf_counter() - t0, p


def test_bench_reference_slicers(tmp_path: Path):
    mesh = trimesh.creation.box((40.0, 40.0, 10.0))
    mesh.apply_translation((50.0, 50.0, 5.0))
    stl = tmp_path / "block.stl"
    mesh.export(stl)
    limits = PROFILES["mk3-like a=1250 jd=0.02"]
    rows = []
    t0 = time.perf_counter()
    res = slice_mesh(mesh, SliceParams(layer_mm=0.2))
    ours = {}
    for pattern in ("lines", "hilbert", "hilbert_merged"):
        t1 = time.perf_counter()
        tp = plan_toolpath(res, ToolpathParams(pattern=pattern, infill=0.2, perimeters=2,
                                               angle_step_deg=90, limits=limits,
                                               perimeter_feed_mm_s=45.0,
                                               print_feed_mm_s=80.0,
                                               travel_feed_mm_s=130.0))
        g = write_fdm_gcode(tp)
        dt = (time.perf_counter() - t1) + (t1 - t0 if pattern == "lines" else 0.0)
        ours[pattern] = estimate_gcode(g, limits).total_s
        rows.append([f"conforma {pattern}", dt, "-", ours[pattern]])
    notes = []
    common = ["--layer-height", "0.2", "--fill-density", "20%", "--perimeters", "2",
              "--top-solid-layers", "0", "--bottom-solid-layers", "0", "--skirts", "0"]
    ref = {}
    if shutil.which("prusa-slicer"):
        for pat in ("rectilinear", "hilbertcurve"):
            out = tmp_path / f"prusa_{pat}.gcode"
            dt, p = _run(["prusa-slicer", "--export-gcode", *common, "--fill-pattern", pat,
                          "-o", str(out), str(stl)], tmp_path)
            if p.returncode == 0 and out.exists():
                text = out.read_text()
                m = re.search(r"estimated printing time \(normal mode\) = (.+)", text)
                own = _hms(m.group(1)) if m else float("nan")
                ref[f"prusa {pat}"] = (own, estimate_gcode(text, limits).total_s)
                rows.append([f"PrusaSlicer {pat}", dt, own, ref[f"prusa {pat}"][1]])
            else:
                notes.append(f"prusa-slicer {pat} failed: {p.stderr[-200:]}")
    else:
        notes.append("prusa-slicer not installed: skipped")
    if shutil.which("slic3r"):
        out = tmp_path / "slic3r.gcode"
        dt, p = _run(["slic3r", *common, "--fill-pattern", "rectilinear", "-o", str(out),
                      str(stl)], tmp_path)
        if p.returncode == 0 and out.exists():
            rows.append(["Slic3r rectilinear", dt, "(none)",
                         estimate_gcode(out.read_text(), limits).total_s])
        else:
            notes.append(f"slic3r failed: {p.stderr[-200:]}")
    else:
        notes.append("slic3r not installed: skipped")
    cura_res = Path(os.environ.get("CURA_RESOURCES", "/usr/share/cura/resources"))
    if shutil.which("CuraEngine") and (cura_res / "definitions/fdmprinter.def.json").exists():
        out = tmp_path / "cura.gcode"
        env = dict(os.environ, CURA_ENGINE_SEARCH_PATH=f"{cura_res}/definitions:"
                                                       f"{cura_res}/extruders")
        sets = ["layer_height=0.2", "infill_sparse_density=20", "infill_pattern=lines",
                "wall_line_count=2", "top_layers=0", "bottom_layers=0", "adhesion_type=none"]
        cmd = ["CuraEngine", "slice", "-j", str(cura_res / "definitions/fdmprinter.def.json")]
        for s in sets:
            cmd += ["-s", s]
        dt, p = _run(cmd + ["-l", str(stl), "-o", str(out)], tmp_path, env)
        if p.returncode == 0 and out.exists():
            text = out.read_text()
            el = re.findall(r";TIME_ELAPSED:([\d.]+)", text)
            own = float(el[-1]) if el else float("nan")
            rows.append(["CuraEngine lines", dt, own, estimate_gcode(text, limits).total_s])
        else:
            notes.append(f"CuraEngine failed: {p.stderr[-200:]}")
    else:
        notes.append("CuraEngine or Cura definition files (CURA_RESOURCES) absent: "
                     "skipped")
    base_wall = rows[0][1]
    for r in rows:
        r.append(r[1] / base_wall)
        r.append(r[3] / ours["lines"])
    _table(f"40x40x10 mm block, 0.2 mm layers, 20 % infill, 2 perimeters, no solid skins, "
           f"conforma feeds perimeter 45 / infill 80 / travel 130 mm/s; "
           f"'ours est' = {limits.describe()} (M201/M203/M204 in the file override)",
           ["run", "wall s", "own est s", "ours est s", "wall x conforma", "est x ours lines"],
           rows)
    for n in notes:
        print("  note:", n)
    if "prusa rectilinear" in ref and "prusa hilbertcurve" in ref:
        (o_l, e_l), (o_h, e_h) = ref["prusa rectilinear"], ref["prusa hilbertcurve"]
        print(f"  PrusaSlicer hilbert/rectilinear: its own estimator {o_h / o_l:.2f}x, ours "
              f"{e_h / e_l:.2f}x; conforma hilbert_merged/lines "
              f"{ours['hilbert_merged'] / ours['lines']:.2f}x, "
              f"plain hilbert/lines {ours['hilbert'] / ours['lines']:.2f}x")
        print(f"  estimator check on PrusaSlicer rectilinear file: ours/PrusaSlicer "
              f"{e_l / o_l:.3f}")
