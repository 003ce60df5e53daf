"""Plant simulator: the process model plus what the controller does not know.

Per-nozzle volume spread, per-drop noise, a mean-volume bias, flow mismatch (mobility
and threshold factors), dead nozzles and height-sensor noise, all drawn from one
``numpy.random.Generator`` seeded by ``PlantParams.seed`` (same seed, same run).
Grid rows are the scan direction; column j is printed by nozzle ``j % n_nozzles``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from .errors import JettingError
from .flow import flow_layer, mobility_map
from .kernel import DropKernel, deposit
from .params import MM_PER_UM, FlowParams, PlantParams


class Plant:
    """A simulated jetting printer holding the true height map (L, W), mm."""

    def __init__(self, shape: tuple[int, int], kernel: DropKernel, flow: FlowParams,
                 plant: PlantParams, tilt_rad: npt.NDArray[np.float64] | None = None) -> None:
        if plant.nozzle_spread < 0 or plant.drop_noise < 0 or plant.sensor_noise_um < 0:
            raise JettingError("noise levels must be >= 0", field="plant",
                               value=[plant.nozzle_spread, plant.drop_noise, plant.sensor_noise_um])
        if plant.n_nozzles < 1:
            raise JettingError("need at least one nozzle", field="plant.n_nozzles",
                               value=plant.n_nozzles)
        self.kernel, self.flow, self.params = kernel, flow, plant
        self.rng = np.random.default_rng(plant.seed)
        spread = plant.nozzle_spread * self.rng.standard_normal(plant.n_nozzles)
        nozzle = np.maximum(1.0 + spread, 0.0)
        for dead in plant.dead_nozzles:
            if not 0 <= dead < plant.n_nozzles:
                raise JettingError("dead nozzle index out of range",
                                   field="plant.dead_nozzles", value=dead)
            nozzle[dead] = 0.0
        self.column_volume = plant.volume_bias * nozzle[np.arange(shape[1]) % plant.n_nozzles]
        tilt = np.zeros(shape) if tilt_rad is None else tilt_rad
        self.mobility = mobility_map(tilt, flow, plant.mobility_factor)
        self.heights = np.zeros(shape)

    def print_layer(self, pattern: npt.NDArray[np.bool_]) -> npt.NDArray[np.float64]:
        """Jet the 0/1 ``pattern`` (L, W), let the ink flow, cure; returns true heights, mm."""
        drops = np.asarray(pattern, dtype=float)
        noise = 1.0 + self.params.drop_noise * self.rng.standard_normal(drops.shape)
        volumes = drops * self.column_volume[None, :] * np.maximum(noise, 0.0)
        liquid = deposit(volumes, self.kernel)
        result = flow_layer(self.heights + liquid, liquid, self.mobility, self.flow,
                            self.params.threshold_factor)
        self.heights = result.surface
        return self.heights

    def measure(self) -> npt.NDArray[np.float64]:
        """The height sensor's reading of the whole grid (true heights + noise), mm."""
        sigma = self.params.sensor_noise_um * MM_PER_UM
        return self.heights + sigma * self.rng.standard_normal(self.heights.shape)
