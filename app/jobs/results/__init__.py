"""Job result models by family: the kinds' own (models), calibration, jetting, the closed
loop, programs."""
