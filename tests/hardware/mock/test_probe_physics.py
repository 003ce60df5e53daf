"""Probe physics of the mock against analytic truth (``hardware.mock.physics``).

Readings are carriage (ball-centre) positions at the trigger, in commanded coordinates."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import trimesh

from hardware.mock import MockPad, MockSphere, MockTool, MockWorld, TruePlacement
from hardware.mock.physics import ProbePhysics
from hardware.mock.surface import PlacedSurface

R_BALL = 0.5
PRE = 0.015


def _physics(seed: int = 0, **kwargs) -> tuple[MockWorld, ProbePhysics]:
    world = MockWorld(**kwargs)
    surface = PlacedSurface(world.true_part, world.placement, world.bed_z)
    return world, ProbePhysics(world, surface, np.random.default_rng(seed))


def test_flat_pad_reads_top_plus_radius_minus_pretravel():
    world, physics = _physics(stylus_radius_mm=R_BALL, pretravel_mm=PRE,
                              pad=MockPad((50.0, 10.0, 5.0), 20.0))
    touch = physics.touch((53.0, 12.0, 10.0), (53.0, 12.0, 0.0), tool=0)
    assert touch.status == "hit" and touch.what == "pad"
    assert touch.reading == pytest.approx((53.0, 12.0, 5.0 + R_BALL - PRE), abs=1e-12)
    # beside the pad the bed is met instead (ball radius above it)
    touch = physics.touch((75.0, 12.0, 10.0), (75.0, 12.0, -1.0), tool=0)
    assert touch.what == "bed" and touch.reading[2] == pytest.approx(R_BALL - PRE, abs=1e-12)
    # the ball's rim catches the pad's edge before its centre is over the pad
    x = 60.0 + 0.3  # 0.3 mm outside the pad's +x edge: contact on the edge line
    touch = physics.touch((x, 12.0, 10.0), (x, 12.0, 0.0), tool=0)
    assert touch.what == "pad"
    assert touch.reading[2] == pytest.approx(5.0 + math.sqrt(R_BALL**2 - 0.3**2) - PRE, abs=1e-12)


def test_sphere_top_and_radial_touches():
    c = np.array([100.0, 5.0, 12.0])
    big = 10.0
    world, physics = _physics(stylus_radius_mm=R_BALL, pretravel_mm=PRE,
                              sphere=MockSphere(tuple(c), 2 * big))
    touch = physics.touch((100.0, 5.0, 30.0), (100.0, 5.0, 0.0), tool=0)
    assert touch.what == "sphere"
    assert touch.reading[2] == pytest.approx(c[2] + big + R_BALL - PRE, abs=1e-12)
    for angle in np.radians([0.0, 37.0, 145.0, 260.0]):
        u = np.array([math.cos(angle), math.sin(angle), 0.0])
        start = c + (big + R_BALL + 3.0) * u
        touch = physics.touch(tuple(start), tuple(c), tool=0)
        reading = np.array(touch.reading)
        assert np.linalg.norm(reading - c) == pytest.approx(big + R_BALL - PRE, abs=1e-12)
        assert np.cross(reading - c, u) == pytest.approx(np.zeros(3), abs=1e-12)  # radial


def test_lobing_has_the_right_sign_and_period():
    c = np.array([0.0, 0.0, 20.0])
    big, lobe = 10.0, 0.004
    world, physics = _physics(stylus_radius_mm=R_BALL, pretravel_mm=PRE,
                              pretravel_lobing_mm=lobe, sphere=MockSphere(tuple(c), 2 * big))

    def radial(phi_deg: float, elevation_deg: float = 0.0) -> float:
        phi, el = math.radians(phi_deg), math.radians(elevation_deg)
        u = np.array([math.cos(el) * math.cos(phi), math.cos(el) * math.sin(phi), math.sin(el)])
        touch = physics.touch(tuple(c + 15.0 * u), tuple(c), tool=0)
        return big + R_BALL - float(np.linalg.norm(np.array(touch.reading) - c))  # = delta

    assert radial(0.0) == pytest.approx(PRE + lobe, abs=1e-12)      # cos(0) = 1
    assert radial(60.0) == pytest.approx(PRE - lobe, abs=1e-12)     # cos(180 deg) = -1
    assert radial(120.0) == pytest.approx(PRE + lobe, abs=1e-12)    # period 120 deg
    assert radial(30.0) == pytest.approx(PRE, abs=1e-12)            # cos(90 deg) = 0
    assert radial(0.0, 90.0) == pytest.approx(PRE, abs=1e-12)       # theta = 0: no lobing
    assert radial(0.0, 30.0) == pytest.approx(PRE + lobe * math.sin(math.radians(60)), abs=1e-12)


def _tilted_plane(theta_deg: float) -> trimesh.Trimesh:
    """A finely triangulated plane z = 3 + tan(theta) x, 60 x 40 mm (many faces/edges)."""
    xs, ys = np.linspace(-30, 30, 41), np.linspace(-20, 20, 27)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    vertices = np.column_stack([gx.ravel(), gy.ravel(), 3.0 + math.tan(math.radians(theta_deg)) * gx.ravel()])
    faces = []
    ny = len(ys)
    for i in range(len(xs) - 1):
        for j in range(ny - 1):
            a, b, c, d = i * ny + j, (i + 1) * ny + j, (i + 1) * ny + j + 1, i * ny + j + 1
            faces += [(a, b, c), (a, c, d)]
    return trimesh.Trimesh(vertices, np.array(faces), process=False)


@pytest.mark.parametrize("theta_deg", [0.0, 20.0, 35.0])
def test_vertical_touch_on_a_slope_reads_r_over_cos(theta_deg):
    world, physics = _physics(stylus_radius_mm=R_BALL, pretravel_mm=PRE,
                              true_part=_tilted_plane(theta_deg), bed_z=-50.0)
    slope = math.tan(math.radians(theta_deg))
    for x0, y0 in [(0.0, 0.0), (1.23, -4.56), (-7.5, 8.25), (0.75, 0.5)]:  # grid nodes/edges too
        h = 3.0 + slope * x0
        touch = physics.touch((x0, y0, 30.0), (x0, y0, -10.0), tool=0)
        expected = h + R_BALL / math.cos(math.radians(theta_deg)) - PRE
        assert touch.reading[2] == pytest.approx(expected, abs=1e-9)
    if theta_deg == 20.0:  # the number: 32 um above the ball-centre-on-flat value
        assert (R_BALL / math.cos(math.radians(20)) - R_BALL) * 1000 == pytest.approx(32.1, abs=0.1)


def test_sideways_touch_on_the_mesh_is_exact():
    """A horizontal move (+x) into a 20-degree slope rising with x: the ball touches the
    plane when its centre is r/sin(theta) short of the plane horizontally."""
    theta = math.radians(20.0)
    world, physics = _physics(stylus_radius_mm=R_BALL, true_part=_tilted_plane(20.0), bed_z=-50.0)
    z = 2.0  # the plane is at z=2 where x = -1/tan(theta)
    touch = physics.touch((-25.0, 1.0, z), (25.0, 1.0, z), tool=0)
    x_plane = (z - 3.0) / math.tan(theta)
    assert touch.status == "hit"
    assert touch.reading[0] == pytest.approx(x_plane - R_BALL / math.sin(theta), abs=1e-9)


def test_ideal_probe_reads_exactly_as_before():
    dome = trimesh.creation.icosphere(subdivisions=4, radius=20.0)
    dome.apply_translation((0.0, 0.0, -12.0))
    world, physics = _physics(true_part=dome, placement=TruePlacement(dx=0.5, rz_deg=7.0))
    rng = np.random.default_rng(3)
    for x, y in rng.uniform(-25, 25, size=(40, 2)):
        old = physics.surface.probe(float(x), float(y), 15.0, -5.0)
        touch = physics.touch((float(x), float(y), 15.0), (float(x), float(y), -5.0), tool=0)
        if old.z is None:
            assert touch.status == "miss"
        else:
            assert touch.status == "hit" and touch.reading[2] == old.z  # bit for bit
    inside = physics.touch((0.0, 0.0, 0.0), (0.0, 0.0, -5.0), tool=0)
    assert inside.status == "inside"


def test_ball_touch_on_the_s1_mesh_is_exact_and_fast():
    from app.reference.s1 import s1_mesh

    mesh = s1_mesh()
    world, physics = _physics(stylus_radius_mm=R_BALL, true_part=mesh)
    assert physics.index is not None  # built once per firmware
    rng = np.random.default_rng(5)
    for x, y in rng.uniform((8, 8), (52, 32), size=(12, 2)):
        touch = physics.touch((x, y, 30.0), (x, y, 0.0), tool=0)
        centre = np.array(touch.reading)
        near = np.linalg.norm(mesh.triangles_center[:, :2] - (x, y), axis=1) < 1.5
        local = mesh.submesh([np.flatnonzero(near)], append=True)  # trimesh's own distance
        _, distance, _ = trimesh.proximity.closest_point(local, centre[None, :])
        assert abs(distance[0] - R_BALL) < 1e-7  # touching the faceted mesh (< 0.1 um)
        above = centre + np.outer(np.linspace(1e-4, 1.0, 8), (0, 0, 1))
        _, clear, _ = trimesh.proximity.closest_point(local, above)
        assert (clear > R_BALL).all()  # and nothing touched earlier on the way down


def test_vertical_ball_touch_on_a_million_faces_is_fast():
    mesh = trimesh.creation.icosphere(subdivisions=8, radius=40.0)  # 1.3 M faces
    mesh.apply_translation((0.0, 0.0, -30.0))
    assert len(mesh.faces) > 1_000_000
    world, physics = _physics(stylus_radius_mm=R_BALL, true_part=mesh)
    assert physics.index is not None
    # CPU seconds of this thread (the touch is numpy on one thread, BLAS limited to one): on a
    # loaded host a touch's wall time also counts the time the scheduler gave other processes
    times = []
    for x, y in np.random.default_rng(1).uniform(-15, 15, size=(20, 2)):
        t0 = time.thread_time()
        touch = physics.touch((x, y, 20.0), (x, y, -5.0), tool=0)
        times.append(time.thread_time() - t0)
        ball = np.linalg.norm(np.array(touch.reading) - (0.0, 0.0, -30.0))
        assert 40.0 + R_BALL - 0.002 < ball <= 40.0 + R_BALL + 1e-9  # the facets sit inside the sphere
    print(f"\n{len(mesh.faces)} faces: vertical ball touch median {np.median(times) * 1e3:.1f} ms CPU, "
          f"max {max(times) * 1e3:.1f} ms")
    assert np.median(times) < 0.05, times


def test_drift_lowers_readings_with_the_machine_clock():
    world, physics = _physics(drift_mm_per_min=0.002, pad=MockPad((0.0, 0.0, 4.0), 10.0))
    first = physics.touch((0.0, 0.0, 8.0), (0.0, 0.0, 0.0), tool=0).reading[2]
    world.stats.machine_time_s += 900.0
    later = physics.touch((0.0, 0.0, 8.0), (0.0, 0.0, 0.0), tool=0).reading[2]
    assert first == pytest.approx(4.0, abs=1e-12)
    assert first - later == pytest.approx(0.002 * 900 / 60, abs=1e-12)


def test_pretravel_scatter_and_miss_past_the_end():
    world, physics = _physics(pretravel_mm=PRE, pretravel_sd_mm=0.002, seed=9,
                              pad=MockPad((0.0, 0.0, 4.0), 10.0))
    readings = [physics.touch((0.0, 0.0, 8.0), (0.0, 0.0, 0.0), tool=0).reading[2] for _ in range(400)]
    assert np.mean(readings) == pytest.approx(4.0 - PRE, abs=0.0004)
    assert np.std(readings) == pytest.approx(0.002, rel=0.15)
    # contact at the very end of the move: the pre-travel would pass the target -> no trigger
    assert physics.touch((0.0, 0.0, 8.0), (0.0, 0.0, 3.995), tool=0).status == "miss"


def test_nozzle_touches_only_the_artifacts():
    offset = (12.3, -4.1, -8.7)
    c = np.array([100.0, 0.0, 10.0])
    world, physics = _physics(stylus_radius_mm=R_BALL, pretravel_mm=PRE,
                              tools=(MockTool(offset, 0.8),), pad=MockPad((50.0, 0.0, 5.0), 20.0),
                              sphere=MockSphere(tuple(c), 20.0),
                              true_part=trimesh.creation.box((10, 10, 6)))
    o = np.array(offset)
    # flat end on the pad: tip at the pad top (no pre-travel for a nozzle)
    carriage = np.array([52.0, 1.0, 12.0]) - o
    touch = physics.touch(tuple(carriage), tuple(carriage - (0, 0, 10)), tool=1)
    assert touch.what == "pad" and touch.reading[2] + o[2] == pytest.approx(5.0, abs=1e-9)
    # side touches below the equator from -x and +x: midpoint = c_x - offset_x
    readings = []
    for side in (-1.0, 1.0):
        tip = c + (side * (10.0 + 0.4 + 2.0), 0.0, -3.0)
        start = tip - o
        touch = physics.touch(tuple(start), tuple(start - (side * 5.0, 0.0, 0.0)), tool=1)
        assert touch.what == "sphere"
        assert abs(touch.reading[0] + o[0] - c[0]) == pytest.approx(10.0 + 0.4, abs=1e-9)
        readings.append(touch.reading[0])
    assert sum(readings) / 2 == pytest.approx(c[0] - o[0], abs=1e-9)
    # rim on the sphere above the equator: horizontal distance D/2 + sqrt(R^2 - h^2)
    tip = c + (-15.0, 0.0, 6.0)
    touch = physics.touch(tuple(tip - o), tuple(tip - o + (10, 0, 0)), tool=1)
    assert c[0] - (touch.reading[0] + o[0]) == pytest.approx(0.4 + 8.0, abs=1e-9)
    # driven into the (non-conductive) part: no trigger, one collision
    assert world.stats.collisions == 0
    tip = np.array([0.0, 0.0, 6.0])
    touch = physics.touch(tuple(tip - o), tuple(tip - o - (0, 0, 5)), tool=1)
    assert touch.status == "miss" and world.stats.collisions == 1


def test_touchoff_scatter():
    world, physics = _physics(touchoff_sd_mm=0.001, seed=2, tools=(MockTool((0, 0, -5), 1.0),),
                              pad=MockPad((0.0, 0.0, 4.0), 10.0))
    z = [physics.touch((0.0, 0.0, 12.0), (0.0, 0.0, 5.0), tool=1).reading[2] for _ in range(300)]
    assert np.mean(z) == pytest.approx(9.0, abs=0.0003) and np.std(z) == pytest.approx(0.001, rel=0.15)


def test_starting_beside_a_face_plane_is_not_inside():
    """A ball whose start overlaps the plane of a face but not the face itself moves on."""
    world, physics = _physics(stylus_radius_mm=R_BALL, pad=MockPad((0.0, 0.0, 5.0), 10.0))
    # centre 0.2 mm above the top plane, 3 mm beyond the pad's +x side, moving -x: it meets
    # the pad's top edge where the centre is sqrt(r^2 - 0.2^2) beyond the side
    touch = physics.touch((8.0, 0.0, 5.2), (0.0, 0.0, 5.2), tool=0)
    assert touch.status == "hit"
    assert touch.reading[0] == pytest.approx(5.0 + math.sqrt(R_BALL**2 - 0.2**2), abs=1e-12)
    # really overlapping at the start: inside
    assert physics.touch((4.0, 0.0, 5.2), (4.0, 0.0, 0.0), tool=0).status == "inside"


def test_dust_reads_high_once_then_the_part_is_read():
    """A speck of dust (x, y, dz): the first touch within 0.5 mm reads dz high, a touch again
    reads the bed; a touch farther away never meets it."""
    world, physics = _physics(probe_dust=((20.0, 10.0, 0.08),))
    far = physics.touch((20.6, 10.0, 5.0), (20.6, 10.0, -1.0), tool=0)
    assert far.reading[2] == pytest.approx(0.0, abs=1e-12)
    first = physics.touch((20.2, 10.1, 5.0), (20.2, 10.1, -1.0), tool=0)
    assert first.reading[2] == pytest.approx(0.08, abs=1e-12)
    again = physics.touch((20.2, 10.1, 5.0), (20.2, 10.1, -1.0), tool=0)
    assert again.reading[2] == pytest.approx(0.0, abs=1e-12) and world.dust_gone == {0}
