"""Driving one droplet layer on a machine: print its swaths with the head, cure it with the
machine's UV-lamp output, scan it with the height sensor.

* **print**: per swath (:func:`app.jetting.machine_grid.swaths`) the bitmap goes to the head
  (``LOAD``; the head's drop count must match), the carriage goes to the swath's start at the
  print height, the head is armed there and the carriage streams along +y over every row (each nozzle row
  crossing every bitmap row; the head fires from the scan axis' position), then the head
  must report every row crossed, and is disarmed.  The streamed moves are a program: the
  operator's pause holds it (the head fires on position, so each drop still fires once).
* **cure**: ``cure_on``, a dwell of ``cure_s``, ``cure_off``, streamed after the moves.
* **scan**: a serpentine raster (:func:`~app.jetting.machine_grid.raster_waypoints`) with the
  sensor (:func:`app.jobs.sensor_runs.open_scanner`): storing on its own link, the samples'
  positions from the commanded pass; or sampled by a LinuxCNC controller with its joints,
  each sample at its measured position); samples binned into the cells.  On its own link a
  pass that stored more samples than its motion lasts (a pause or feed hold mid-pass: the
  positions of the samples are not the commanded pass) is scanned again.

Hardware errors pass through (the kind decides: a lost link interrupts the run).
"""

from __future__ import annotations

from contextlib import suppress
from dataclasses import dataclass

import numpy as np

from app.calibration.sensor import SensorCalibration
from app.gcode.writer import DEFAULT_DIALECT, DIALECTS
from app.jetting.machine_grid import Grid, cell_means, raster_waypoints, swaths
from app.jobs.sensor_runs import HalScanner, SerialScanner
from app.probing.scan_path import pass_duration
from hardware.backend import Machine
from hardware.errors import HardwareError, ProtocolError
from hardware.printhead import PrintHead

RUN_IN_MM = 1.0        # the nozzles start and end this far outside the swath's rows
MAX_RESCANS = 3        # scans of one layer that stored more samples than their motion lasted
EXTRA_SAMPLES = 0.01   # a pass storing more than (1 + this) x its expected samples (+ 5) was held
STORAGE_SAMPLES = 60_000  # samples one pass may store (an LK-G controller holds 65,536)


@dataclass(frozen=True)
class MachineSetup:
    """Where and how: head nozzle 0 at carriage + ``head_offset_mm`` (x, y); carriage heights
    while printing and scanning and for travel; speeds; the cure commands and dose; the bed
    height under the grid (the jetted heights are measured from it)."""

    head_offset_mm: tuple[float, float]
    print_z_mm: float
    travel_z_mm: float
    print_speed_mm_s: float
    scan_speed_mm_s: float
    cure_on: str
    cure_off: str
    cure_s: float
    bed_z_mm: float


@dataclass(frozen=True)
class PrintedLayer:
    """drops in the pattern and drops the head reported fired."""

    drops: int
    fired: int


def print_layer(machine: Machine, head: PrintHead, pattern: np.ndarray, grid: Grid,
                setup: MachineSetup) -> PrintedLayer:
    """Jet the (L, W) 0/1 ``pattern`` swath by swath (module docstring)."""
    info = head.info
    assert info is not None, "connect the head first"
    lag = info.row_gap_um * 1e-3 * (info.rows - 1)  # the last nozzle row trails the first by this
    y_start = float(grid.y(0)) - setup.head_offset_mm[1] - RUN_IN_MM
    y_end = float(grid.y(grid.shape[0] - 1)) - setup.head_offset_mm[1] + lag + RUN_IN_MM
    feed = setup.print_speed_mm_s * 60.0
    fired = 0
    machine.move(z=setup.travel_z_mm)
    for swath in swaths(pattern, info.nozzles):
        x = float(grid.x(swath.first_col)) - setup.head_offset_mm[0]
        head.load(swath.bits, float(grid.y(0)), 0)
        machine.move(x=x, y=y_start)
        machine.move(x=x, y=y_start, z=setup.print_z_mm)
        head.arm()  # at the swath's start: a travel move never crosses an armed row
        try:
            machine.stream(["G90", f"G1 Y{y_end:.4f} F{feed:.1f}", wait_moves(machine)])
            status = head.status()
        except HardwareError:
            with suppress(HardwareError):  # never leave the head armed: a later move would fire it
                head.disarm()
            raise
        if status.rows_done != swath.bits.shape[0]:
            head.disarm()
            raise ProtocolError(f"the head fired {status.rows_done} of {swath.bits.shape[0]} rows of the swath at "
                                f"column {swath.first_col}", field="head_port", value=status.rows_done)
        fired += head.disarm()
        machine.move(z=setup.travel_z_mm)
    return PrintedLayer(int(np.count_nonzero(pattern)), fired)


def wait_moves(machine: Machine) -> str:
    """The dialect's wait for the planned moves (a LinuxCNC program ends only once its
    motion did: ``G4 P0`` there, as its dialect writes it)."""
    rules = getattr(machine, "rules", None)
    return str(rules.wait_moves) if rules is not None else "G4 P0"


def cure(machine: Machine, setup: MachineSetup) -> None:
    """The UV lamp on for ``cure_s`` after the moves, then off (the dwell in the dialect's
    unit: Marlin ``G4 P<ms>``, grbl and LinuxCNC ``G4 P<s>``)."""
    dwell = DIALECTS[str(getattr(machine, "dialect", DEFAULT_DIALECT))].dwell(max(setup.cure_s, 0.001))
    machine.stream([wait_moves(machine), setup.cure_on, dwell, setup.cure_off])


@dataclass(frozen=True)
class LayerScan:
    """heights (L, W) mm above the bed (NaN: no valid sample in the cell), samples per cell
    (L, W), samples stored, valid samples, and the passes it took."""

    heights: np.ndarray
    counts: np.ndarray
    samples: int
    valid: int
    scans: int


def scan_layer(machine: Machine, scanner: SerialScanner | HalScanner, grid: Grid, calibration: SensorCalibration,
               setup: MachineSetup, top_mm: float) -> LayerScan:
    """Raster the grid with the sensor, its zero ``top_mm`` above the bed (module docstring),
    in as many passes as the sensor's storage needs (one when the controller samples it)."""
    z = setup.bed_z_mm + top_mm - calibration.offset_mm[2]
    spot = (calibration.offset_mm[0], calibration.offset_mm[1])
    serial = scanner.sensor if isinstance(scanner, SerialScanner) else None
    chunk = grid.shape[1]
    if serial is not None:
        per_col = pass_duration(raster_waypoints(grid, spot, z, cols=np.array([0, 1])), setup.scan_speed_mm_s) \
            * serial.rate_hz / 2
        chunk = max(1, int(STORAGE_SAMPLES // max(per_col, 1.0)))
    xy, heights = [], []
    samples = valid = scans = 0
    for first in range(0, grid.shape[1], chunk):
        w = raster_waypoints(grid, spot, z, cols=np.arange(first, min(first + chunk, grid.shape[1])))
        for attempt in range(1, MAX_RESCANS + 1):
            data = scanner.run(w, setup.scan_speed_mm_s, setup.travel_z_mm, calibration.time_offset_s)
            machine.move(z=setup.travel_z_mm)
            scans += 1
            if serial is None or len(data.values) <= (pass_duration(w, setup.scan_speed_mm_s) * serial.rate_hz + 1) \
                    * (1 + EXTRA_SAMPLES) + 5:
                break
            if attempt == MAX_RESCANS:
                raise ProtocolError(f"{MAX_RESCANS} scans of a pass each stored more samples than their motion "
                                    "lasted (held mid-pass)", field="sensor_port", value=len(data.values))
        ok = np.isfinite(data.values)
        xy.append(calibration.spot_xy(data.carriage))
        heights.append(np.where(ok, calibration.surface_z(data.carriage, np.nan_to_num(data.values)), np.nan)
                       - setup.bed_z_mm)
        samples, valid = samples + len(data.values), valid + int(ok.sum())
    mean, counts = cell_means(np.concatenate(xy), np.concatenate(heights), grid)
    return LayerScan(mean, counts, samples, valid, scans)
