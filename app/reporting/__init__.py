"""Run reports: one page per measurement session (a closed loop, or a probe run and the
reconstructions, compensations and prints made from it) for a lab's records."""
