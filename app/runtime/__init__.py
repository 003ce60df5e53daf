"""The job engine: submission and dispatch, the store's conditional state changes, the
registry of kinds, the context a kind runs with, compute pool and child processes, the
machine queue, cost estimates.  Imports no kind except through the registry."""
