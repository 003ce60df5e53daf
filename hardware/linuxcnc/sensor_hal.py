"""The LinuxCNC simulator's laser height sensor: a userspace HAL component (``sim/sensor.hal``).

Run by LinuxCNC under the *system* Python (it has LinuxCNC's ``hal`` module and numpy,
not Conforma's packages): ``loadusr -Wn conforma-sensor python3 sensor_hal.py
conforma-sensor SEED [MAP]``.  It imports nothing of Conforma except the optics formula
(:mod:`hardware.height_sensor.optics_model`, loaded by file path), so it computes its
values exactly as the mock LK-G does.

Every ``PERIOD_S`` while ``enable`` is true it reads the carriage (pins ``x y z``, wired
to the joints' ``pos-fb``), puts the spot at carriage + ``offset-x/y``, evaluates the
simulated part there (the block of :class:`hardware.linuxcnc.sim_surface.SimBlock`,
pins ``u-*``/``v-*``: the placement, ``top-z``/``top-slope``: the top
z = top-z + top-slope * u over the footprint, ``bed-z`` elsewhere; a reference sphere
``sphere-x/y/z/r`` beside it, none when r <= 0; plus what lies on the bed: the jetted ink of
the height map file MAP, an ``.npz`` of ``heights`` (L, W) mm above the bed, ``origin``
(x, y of cell [0, 0]'s centre) and ``pitch`` mm, read again whenever the file changes, as
:class:`hardware.linuxcnc.sim_head.SimHeadBridge` writes it after each cure) at the spot's
seven lit points, and writes ``reading`` (mm from the sensor's zero at carriage z + ``offset-z``)
and ``valid`` (false: the sensor's alarm output: too steep, a random dropout, or beyond
+-``range``).  Out pin ``updates`` counts the values written.  It stands for an analog
input: the controller samples ``reading`` and ``valid`` with the joints in its servo
thread (``sampler``).  Each value is stamped ``exposed`` with the clock count (``tick``, ms
on the simulator) of the servo period whose joints the component read (checked against
``tick-started``, the count the servo thread sets before it writes the joints), and
``exposed`` is -1 while a value is written (:func:`publish`); with ``latency-ms`` > 0 the value
is computed where the carriage was that long before (the joints it read then, interpolated
over the counts): a sensor whose output lags its exposure, the time offset
``calibrate_sensor`` must find.

Units: mm, degrees.  Stops on SIGTERM (LinuxCNC's shutdown).
"""

import importlib.util
import os
import signal
import sys
import time
from pathlib import Path

import numpy as np

PERIOD_S = 0.0005
IDLE_S = 0.02

FLOAT_IN = ("x", "y", "z", "offset-x", "offset-y", "offset-z", "range", "noise", "resolution", "spot",
            "acceptance-deg", "scale-error", "slope-bias", "dropout-rate",
            "u-gain0", "u-gain1", "u-offset", "v-gain0", "v-gain1", "v-offset",
            "u-min", "u-max", "v-min", "v-max", "top-z", "top-slope", "bed-z",
            "sphere-x", "sphere-y", "sphere-z", "sphere-r", "latency-ms")
MAP_CHECK_S = 0.005  # how often the MAP file's modification time is looked at
HISTORY = 400  # joint reads kept for the latency (0.2 s at PERIOD_S)
# how long the component tries to read the three joints while no servo period writes them
# (sim/sensor.hal's sequence lock: ``tick``, the joints, then ``tick-started``, the same count),
# yielding the processor between tries so that a servo thread preempted mid-period can finish
# it; a component that misses for this long writes no value this time rather than one paired
# with the wrong period's joints (off by a period's travel: 2 um at 2 mm/s)
POSITION_WAIT_S = 0.005
YIELD_S = 0.00005  # a sleep, not sched_yield: at a real-time priority that yields to no ordinary task


def realtime_if_allowed() -> bool:
    """Run at the lowest SCHED_FIFO priority where permitted (root or CAP_SYS_NICE): the
    component stands for an analog input, whose values do not wait for a busy host's
    scheduler (at ordinary priority a loaded host left it one value in several servo
    periods).  It sleeps PERIOD_S after every value, so ordinary tasks keep most of a core.
    False (ordinary scheduling) where not permitted."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except (OSError, AttributeError):
        return False
    return True


def _optics_model():
    path = Path(__file__).resolve().parents[1] / "height_sensor" / "optics_model.py"
    spec = importlib.util.spec_from_file_location("conforma_optics_model", path)
    if spec is None or spec.loader is None:  # a file path always has a source loader
        raise ImportError(f"cannot load {path}")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def block_heights(p: dict, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The block's top (or the bed) at points (n, k, 2) -> heights (n, k), and |cos| of the
    tilt at each spot centre (n,)."""
    x, y = points[..., 0], points[..., 1]
    u = p["u-gain0"] * x + p["u-gain1"] * y + p["u-offset"]
    v = p["v-gain0"] * x + p["v-gain1"] * y + p["v-offset"]
    inside = (u > p["u-min"]) & (u < p["u-max"]) & (v > p["v-min"]) & (v < p["v-max"])
    heights = np.where(inside, p["top-z"] + p["top-slope"] * u, p["bed-z"])
    cos_top = 1.0 / np.sqrt(1.0 + p["top-slope"] ** 2)
    cos_tilt = np.where(inside[:, 0], cos_top, 1.0)
    r = p["sphere-r"]
    if r > 0:
        under = r * r - (x - p["sphere-x"]) ** 2 - (y - p["sphere-y"]) ** 2
        cap = np.where(under > 0, p["sphere-z"] + np.sqrt(np.maximum(under, 0.0)), -np.inf)
        on_sphere = cap[:, 0] > heights[:, 0]
        heights = np.maximum(heights, cap)
        cos_tilt = np.where(on_sphere, np.sqrt(np.maximum(under[:, 0], 0.0)) / r, cos_tilt)
    return heights, cos_tilt


class InkMap:
    """The MAP file's heights, read again when its modification time changes."""

    def __init__(self, path):
        self.path = Path(path) if path else None
        self.stamp = None
        self.heights = None
        self.checked = 0.0

    def refresh(self, now: float) -> None:
        if self.path is None or now - self.checked < MAP_CHECK_S:
            return
        self.checked = now
        try:
            stamp = self.path.stat().st_mtime_ns
        except OSError:
            self.stamp, self.heights = None, None
            return
        if stamp != self.stamp:
            with np.load(self.path) as data:
                self.heights = np.asarray(data["heights"], dtype=float)
                self.origin = np.asarray(data["origin"], dtype=float)
                self.pitch = float(data["pitch"])
            self.stamp = stamp

    def at(self, points: np.ndarray) -> np.ndarray:
        """The ink's height (n, k) mm at points (n, k, 2) (nearest cell; 0 off the map)."""
        if self.heights is None:
            return np.zeros(points.shape[:-1])
        col = np.rint((points[..., 0] - self.origin[0]) / self.pitch).astype(int)
        row = np.rint((points[..., 1] - self.origin[1]) / self.pitch).astype(int)
        on = (row >= 0) & (row < self.heights.shape[0]) & (col >= 0) & (col < self.heights.shape[1])
        return np.where(on, self.heights[np.clip(row, 0, self.heights.shape[0] - 1),
                                         np.clip(col, 0, self.heights.shape[1] - 1)], 0.0)


def position_at(history: list, when: float) -> tuple[float, float, float]:
    """The carriage (x, y, z) at clock count ``when`` from ``history`` [(count, x, y, z), ...]
    (increasing counts), interpolated; held at its ends."""
    rows = np.asarray(history, dtype=float)
    x, y, z = (float(np.interp(when, rows[:, 0], rows[:, k])) for k in (1, 2, 3))
    return x, y, z


def read_joints(comp, p: dict, deadline: float):
    """Read the joints of one servo period into ``p`` (keys x y z) -> that period's count, or
    None when no read before ``deadline`` (``time.monotonic``) saw a whole period."""
    while True:
        tick = comp["tick"]  # the last period that finished writing the joints
        p["x"], p["y"], p["z"] = comp["x"], comp["y"], comp["z"]
        if comp["tick-started"] == tick:  # no later period began writing them meanwhile
            return tick
        if time.monotonic() > deadline:
            return None
        time.sleep(YIELD_S)


def publish(comp, value: float, tick: float, range_mm: float) -> None:
    """Write one value (mm; NaN: none) exposed at count ``tick`` to ``comp``'s pins: ``exposed``
    -1 first, then ``reading`` and ``valid`` (false beyond +-``range_mm`` or without a value),
    then ``exposed``.  The servo thread's sampler reads ``exposed`` before and after the value,
    so a row it samples while this writes shows two different counts (or -1) and is dropped,
    not paired with the wrong count (``hardware/linuxcnc/hal_scan.py``)."""
    ok = bool(np.isfinite(value) and abs(value) <= range_mm)
    comp["exposed"] = -1.0
    comp["reading"] = value if ok else 0.0
    comp["valid"] = ok
    comp["exposed"] = tick


def main(argv):
    name, seed = argv[1], int(argv[2]) if len(argv) > 2 else 0
    ink = InkMap(argv[3] if len(argv) > 3 else None)
    import hal  # LinuxCNC's, system Python only
    model = _optics_model()
    rng = np.random.default_rng(seed)
    comp = hal.component(name)
    for pin in FLOAT_IN:
        comp.newpin(pin, hal.HAL_FLOAT, hal.HAL_IN)
    comp.newpin("enable", hal.HAL_BIT, hal.HAL_IN)
    comp.newpin("reading", hal.HAL_FLOAT, hal.HAL_OUT)
    comp.newpin("valid", hal.HAL_BIT, hal.HAL_OUT)
    comp.newpin("updates", hal.HAL_U32, hal.HAL_OUT)
    comp.newpin("tick", hal.HAL_FLOAT, hal.HAL_IN)
    comp.newpin("tick-started", hal.HAL_FLOAT, hal.HAL_IN)
    comp.newpin("exposed", hal.HAL_FLOAT, hal.HAL_OUT)
    comp.ready()
    realtime_if_allowed()
    running = [True]
    signal.signal(signal.SIGTERM, lambda *_: running.__setitem__(0, False))
    updates = 0
    history: list = []
    try:
        while running[0]:
            ink.refresh(time.monotonic())
            if not comp["enable"]:
                history.clear()
                time.sleep(IDLE_S)
                continue
            p = {pin: comp[pin] for pin in FLOAT_IN}  # the settings and the part: they change slowly
            tick = read_joints(comp, p, time.monotonic() + POSITION_WAIT_S)
            if tick is None:
                time.sleep(PERIOD_S)
                continue
            if not history or tick > history[-1][0]:
                history.append((tick, p["x"], p["y"], p["z"]))
                del history[:-HISTORY]
            x, y, z = position_at(history, tick - p["latency-ms"]) if p["latency-ms"] > 0 else (p["x"], p["y"], p["z"])
            points = model.spot_points(np.array([[x + p["offset-x"], y + p["offset-y"]]]), p["spot"])
            heights, cos_tilt = block_heights(p, points)
            heights = heights + ink.at(points)
            value = model.optical_values(heights, cos_tilt, np.array([z + p["offset-z"]]), rng,
                                         noise_mm=p["noise"], resolution_mm=p["resolution"],
                                         scale_error=p["scale-error"], slope_bias_mm=p["slope-bias"],
                                         acceptance_deg=p["acceptance-deg"], dropout_rate=p["dropout-rate"])[0]
            publish(comp, float(value), tick, p["range"])
            updates = (updates + 1) & 0xFFFFFFFF
            comp["updates"] = updates
            time.sleep(PERIOD_S)
    except KeyboardInterrupt:
        pass
    finally:
        comp.exit()


if __name__ == "__main__":
    main(sys.argv)
