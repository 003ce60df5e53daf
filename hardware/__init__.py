"""Printer side of Conforma: G-code host protocol, serial link, machine, mock firmware.

Usable without the ``app`` package."""
