"""Printer side of Conforma: G-code host protocol, serial link, machine, mock firmware.

Usable without the ``app`` package.  Layers (each usable alone):

* ``hardware.protocol`` (pure) — framing ``frame``/``checksum``, ``normalize_command``,
  ``commands_sha256`` (API.md digest), ``validate_program``, ``parse_reply`` -> typed
  events of ``hardware.events``.
* ``hardware.link.Link`` — one serial connection by URL (device, ``socket://``,
  ``mock://``): reader thread, per-command ``CommandResult``, ping-pong or windowed flow
  control, resends, keepalive-aware stall detection, out-of-band emergency stop.
* ``hardware.machine.Machine`` — connect/identify, home, move, position, probe,
  stream with pause/resume/cancel, stop, resume after a disconnect (``resume_line``).
* ``hardware.mock`` — firmware-like Marlin/grbl mock behind ``mock://NAME?options`` with
  a true part to probe, a deposition log, fault injection and an executed-command
  transcript (``MockWorld``, ``register_world``, ``get_world``).
* ``hardware.errors`` — the exception family (``HardwareError`` and subclasses).
"""
