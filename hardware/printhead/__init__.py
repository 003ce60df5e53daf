"""A piezo print head on the carriage, driven over its own serial link.

* :mod:`.hdp`: the head-driver line protocol (bitmap swaths fired from the scan axis);
* :mod:`.client`: :class:`PrintHead`, the host side;
* :mod:`.mock` + :mod:`.ink` + :mod:`.protocol_head`: a mock driver behind ``head://NAME``
  URLs, riding on a mock machine's carriage, depositing drops (per-nozzle volume spread,
  drop noise, dead nozzles) on a true height field the mock height sensor reads, cured by
  the machine's UV-lamp output.

Importing this package registers ``head://`` with pyserial.
"""

from __future__ import annotations

from .client import HeadInfo, HeadRejected, HeadStatus, PrintHead, register_scheme

register_scheme()

__all__ = ["HeadInfo", "HeadRejected", "HeadStatus", "PrintHead", "register_scheme"]
