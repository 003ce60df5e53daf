"""Conforma: plan, measure and compensate toolpaths for printing electronics onto curved parts."""

__version__ = "0.1.0"
