"""A mock jetting machine through the API: a mock Marlin machine, the mock head on its
carriage and the mock LK-G beside it; a ``jetting_run`` job on it; the mock's truth."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hardware.height_sensor.mock import unregister_sensor
from hardware.printhead.mock import MockPrintHead, get_head, unregister_head
from tests.conftest import auth

OP = auth("operator")
HEAD_OFFSET = (20.0, -15.0)
SENSOR_OFFSET = (30.0, 5.0, -10.0)
ORIGIN = (5.0, 5.0)


@dataclass
class JettingRig:
    """The machine id, its head and sensor URLs, and the job parameters that drive them."""

    machine_id: str
    head_url: str
    sensor_url: str
    _head: MockPrintHead | None = None

    @property
    def head(self) -> MockPrintHead:
        """The mock head (kept after :meth:`close`, to read its truth)."""
        if self._head is None:
            self._head = get_head(self.machine_id)
        return self._head

    def params(self, **kwargs: Any) -> dict[str, Any]:
        return {"machine_id": self.machine_id, "head_port": self.head_url, "sensor_port": self.sensor_url,
                "calibration": {"offset_mm": list(SENSOR_OFFSET), "scale": 1.0, "time_offset_s": 0.0},
                "origin_mm": list(ORIGIN), "head_offset_mm": list(HEAD_OFFSET), **kwargs}

    def truth(self, shape: tuple[int, int], pitch_mm: float, layer: int | None = None) -> np.ndarray:
        """The true jetted heights (L, W) mm on the job's grid cells (after ``layer`` cures; now
        when None): the mock field's cells under each grid cell centre."""
        field = self.head.field
        heights = field.heights() if layer is None else np.asarray(field.history[layer - 1], dtype=float)  # type: ignore[index]
        rows = np.rint((ORIGIN[1] + np.arange(shape[0]) * pitch_mm - field.origin[1]) / field.pitch).astype(int)
        cols = np.rint((ORIGIN[0] + np.arange(shape[1]) * pitch_mm - field.origin[0]) / field.pitch).astype(int)
        return heights[np.ix_(rows, cols)]

    def close(self) -> None:
        if self._head is None:
            try:
                self._head = get_head(self.machine_id)
            except KeyError:
                pass
        unregister_head(self.machine_id)
        unregister_sensor(self.machine_id)


def jetting_rig(client: Any, head_options: str = "", sensor_options: str = "") -> JettingRig:
    """A fresh mock machine with a head (``head_options`` added to its URL) and a sensor (0.26 um
    noise per sample: 0.2 um per cell at the raster's 1.7 samples per cell, the simulation's)."""
    machine = client.post("/api/v1/machines", json={"name": "jetter", "port": "mock://", "dialect": "marlin"},
                          headers=OP).json()
    mid = machine["id"]
    assert client.post(f"/api/v1/machines/{mid}/connect", headers=OP).status_code == 200  # its world exists now
    head = f"head://{mid}?offset={HEAD_OFFSET[0]},{HEAD_OFFSET[1]}&field=0,0,200,200&history=1"
    sensor = f"lkg://{mid}?offset={','.join(map(str, SENSOR_OFFSET))}&noise_mm=0.00026&rate_hz=2000"
    rig = JettingRig(mid, f"{head}&{head_options}".rstrip("&"), f"{sensor}&{sensor_options}".rstrip("&"))
    return rig
