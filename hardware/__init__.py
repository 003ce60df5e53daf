"""Printer side of Conforma: G-code host protocol, serial link, machine, mock firmware.

Usable without the ``app`` package.  Layers (each usable alone):

* ``hardware.protocol`` (pure) — framing ``frame``/``checksum``, ``normalize_command``,
  ``commands_sha256`` (API.md digest), ``validate_program``, ``parse_reply`` -> typed
  events of ``hardware.events``.
* ``hardware.dialects`` (pure) — one frozen record per firmware dialect (``marlin``,
  ``grbl``): identify, home, wait, probe, position requests, e-stop bytes, line numbers,
  flow-control accounting, resend and error rules; ``dialect(name)``.
* ``hardware.session.ReplySession`` (pure) — the reply handling: ``feed(line, now)``,
  ``submit``, ``timeout(now)`` return actions (``hardware.session_types``).
* ``hardware.link.Link`` — one serial connection by URL (device, ``socket://``,
  ``mock://``, registered lazily by ``hardware.transport``): the port, the reader thread and the lock
  applying the session's actions, per-command ``CommandResult``, ping-pong or windowed flow
  control, resends, keepalive-aware stall detection, out-of-band emergency stop.
* ``hardware.port_url.PortUrl`` (pure) — a port URL parsed once: scheme, host, port, the
  mock device's name, its options.
* ``hardware.backend.Machine`` — the protocol every machine backend implements (what the
  service drives): the serial ``hardware.machine.Machine`` and ``hardware.linuxcnc.LinuxCNCMachine``.
* ``hardware.machine.Machine`` — connect/identify, home, move, position, probe,
  stream with pause/resume/cancel, stop, resume after a disconnect (``resume_line``);
  composed of collaborators built with what they use (``machine_host.SerialCommands``,
  ``machine_grbl``, ``machine_outputs``, ``machine_probe``, ``machine_resume``,
  ``machine_stream``) around the ``machine_state.MachineState`` every backend keeps.
* ``hardware.mock`` — firmware-like Marlin/grbl mock behind ``mock://NAME?options`` with
  a true part to probe, a deposition log, fault injection and an executed-command
  transcript (``MockWorld``, ``register_world``, ``get_world``).
* ``hardware.errors`` — the exception family (``HardwareError`` and subclasses).
"""
