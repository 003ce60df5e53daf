"""Hardware benchmarks: million-line fault soak, ping-pong vs windowed throughput, and
planner underruns with dense 0.1 mm segments in real time.

Run: .venv/bin/python -m pytest tests/bench/test_bench_hardware.py -s -o addopts="" -q
(``CONFORMA_BENCH_SOAK_LINES`` overrides the soak length, default 1,000,000)."""

from __future__ import annotations

import math
import os
import time

from hardware.link import Link
from hardware.mock import FaultConfig, MockWorld, register_world, unregister_world
from hardware.protocol import commands_sha256

SOAK_LINES = int(os.environ.get("CONFORMA_BENCH_SOAK_LINES", "1000000"))
GRBL_WINDOWED_FAULTS = ("drop_ok_rate", "garbage_rate", "slow_rate")


def _program(count: int) -> list[str]:
    return [f"G1 X{i % 500 * 0.1:.3f} Y{i // 500 % 500 * 0.1:.3f} F6000" for i in range(count)]


def _stream(name: str, world: MockWorld, window: str, program: list[str], baudrate: int = 115200,
            poke_s: float = 0.02) -> tuple[float, Link]:
    register_world(name, world)
    link = Link.open(f"mock://{name}", dialect=world.dialect, window=window, baudrate=baudrate,
                     timeout_s=30, poke_s=poke_s, history=4096)
    try:
        time.sleep(0.2 if world.time_scale else 0.0)
        if world.dialect == "marlin":
            link.reset_line_numbers()
        world.transcript.reset()
        start = time.perf_counter()
        for line in program:
            link.send_async(line)
        link.wait_idle(600)
        return time.perf_counter() - start, link
    finally:
        link.close()
        unregister_world(name)


def _faults(dialect: str, window: str, rate: float, seed: int) -> FaultConfig:
    if dialect == "grbl" and window == "windowed":  # see test_link: grbl cannot resend
        return FaultConfig(**{k: rate for k in GRBL_WINDOWED_FAULTS}, seed=seed)
    return FaultConfig.uniform(rate, seed=seed)


def test_bench_soak_million_lines_exactly_once():
    program = _program(SOAK_LINES)
    world = MockWorld(dialect="marlin", faults=FaultConfig.uniform(0.01, seed=1),
                      keep_transcript=False)
    elapsed, link = _stream("bench-soak", world, "windowed", program)
    expected = commands_sha256(program)
    got = world.transcript.digest()
    print(f"\nSoak: {SOAK_LINES:,} lines, Marlin windowed, 1 % faults of every class")
    print(f"{'class':<14}{'injected':>10}")
    for name, count in sorted(world.stats.faults.items()):
        print(f"{name:<14}{count:>10,}")
    print(f"resends {link.stats['resends']:,}  ignored resend requests "
          f"{link.stats['ignored_resends']:,}  pokes {link.stats['pokes']:,}  "
          f"rx overflows {world.stats.rx_overflows}")
    print(f"executed {got.count:,} / {expected.count:,}  sha256 equal: {got == expected}  "
          f"{elapsed:.1f} s  {SOAK_LINES / elapsed:,.0f} lines/s")
    assert got == expected
    assert len(world.stats.faults) == 7


def test_bench_throughput_pingpong_vs_windowed():
    count = 100_000
    program = _program(count)
    rows = []
    for dialect in ("marlin", "grbl"):
        for rate in (0.0, 0.01):
            speeds = {}
            for window in ("pingpong", "windowed"):
                world = MockWorld(dialect=dialect, faults=_faults(dialect, window, rate, 7),
                                  keep_transcript=False)
                elapsed, _ = _stream(f"bench-{dialect}-{window}", world, window, program)
                assert world.transcript.digest() == commands_sha256(program)
                speeds[window] = count / elapsed
            rows.append((dialect, rate, speeds["pingpong"], speeds["windowed"]))
    print(f"\nThroughput, time_scale=0, {count:,} lines, exactly-once verified by sha256")
    print(f"{'dialect':<8}{'faults':>7}{'ping-pong l/s':>15}{'windowed l/s':>14}{'ratio':>7}")
    for dialect, rate, pingpong, windowed in rows:
        print(f"{dialect:<8}{rate:>7.0%}{pingpong:>15,.0f}{windowed:>14,.0f}"
              f"{windowed / pingpong:>7.2f}")


def _dense(dialect: str, window: str, baud: int, segments: int, feed: float) -> tuple[float, int, float]:
    world = MockWorld(dialect=dialect, time_scale=1.0, latency_ms=1.0, keep_transcript=False)
    radius = 20.0
    step = 0.1 / radius  # 0.1 mm chords on a 20 mm circle
    program = [f"G1 X{radius * math.cos(i * step):.3f} Y{radius * math.sin(i * step):.3f} F{feed:.0f}"
               for i in range(1, segments + 1)]
    register_world("bench-rt", world)
    link = Link.open("mock://bench-rt", dialect=dialect, window=window, baudrate=baud,
                     timeout_s=30)
    try:
        time.sleep(0.2)
        link.send(f"G1 X{radius} Y0 F{feed:.0f}")
        time.sleep(0.3)
        world.stats.underruns, world.stats.starved_s = 0, 0.0
        start = time.perf_counter()
        for line in program:
            link.send_async(line)
        link.wait_idle(120)
        elapsed = time.perf_counter() - start
    finally:
        link.close()
        unregister_world("bench-rt")
    return segments / elapsed, world.stats.underruns, world.stats.starved_s


def test_bench_dense_segments_real_time():
    feed = 2520.0  # 42 mm/s over 0.1 mm chords = 420 segments/s of motion
    segments = 2100
    rows = []
    for dialect, baud in (("marlin", 250000), ("marlin", 115200), ("grbl", 115200)):
        for window in ("pingpong", "windowed"):
            rate, underruns, starved = _dense(dialect, window, baud, segments, feed)
            rows.append((dialect, baud, window, rate, underruns, starved))
    print(f"\nDense 0.1 mm segments, time_scale=1, 1 ms link latency each way, motion allows "
          f"{feed / 60 / 0.1:.0f} seg/s")
    print(f"{'dialect':<8}{'baud':>8}{'window':>10}{'seg/s':>8}{'underruns':>11}{'starved s':>11}")
    for dialect, baud, window, rate, underruns, starved in rows:
        print(f"{dialect:<8}{baud:>8}{window:>10}{rate:>8.0f}{underruns:>11}{starved:>11.3f}")
    best = {(d, b, w): (r, u) for d, b, w, r, u, _ in rows}
    rate, underruns = best[("marlin", 250000, "windowed")]
    assert rate >= 400 and underruns == 0, (rate, underruns)
