"""A point laser triangulation height sensor on the head, read over its own serial link.

* :mod:`.lkg`: the Keyence LK-G series RS-232C command format (the subset Conforma uses);
* :mod:`.client`: :class:`HeightSensor`, the host side (single values, data storage);
* :mod:`.mock` + :mod:`.optics` + :mod:`.protocol_lkg`: a mock LK-G controller behind
  ``lkg://NAME`` URLs, coupled to the mock machine's world (true part, artifacts, the
  carriage's position stream on the machine clock).

Importing this package registers ``lkg://`` with pyserial.
"""

from __future__ import annotations

from .client import HeightSensor, SensorRejected, register_scheme

register_scheme()

__all__ = ["HeightSensor", "SensorRejected", "register_scheme"]
