"""A machine's default dispenser commands, for a profile that names none.

A serial machine's are its dialect's own, from the one table the G-code writer keeps
(:func:`app.gcode.writer.own_dispense`: Marlin ``M106 S255``/``M107``, grbl ``M8``/``M9``).
LinuxCNC numbers its outputs, so the dialect has none of its own; a LinuxCNC machine's
default is the output its backend drives the dispenser with
(:data:`hardware.dialects.LINUXCNC_DISPENSE`, ``M64``/``M65 P0``).  The service hands every
machine it builds its profile's commands.  ``hardware`` may not import ``app``: its own table
(``hardware.dialects.Dialect.dispense``, what a ``Machine`` made without a profile sends and
the output the mock firmware's dispenser is wired to) repeats the pair, and
``tests/hardware/mock/test_dispenser_defaults.py`` holds the two equal.
"""

from __future__ import annotations

from app.gcode.writer import DIALECT_NAMES, own_dispense
from hardware.dialects import LINUXCNC_DISPENSE

#: the dialects whose dispenser is a numbered output their backend drives, not a command of their own
OUTPUT_DISPENSE: dict[str, tuple[str, str]] = {"linuxcnc": LINUXCNC_DISPENSE}


def machine_dispense(dialect: str) -> tuple[str, str]:
    """The (on, off) dispenser commands a ``dialect`` machine gets when its profile names
    none; GcodeError (field ``dialect``) for an unknown dialect."""
    return OUTPUT_DISPENSE.get(dialect) or own_dispense(dialect)


def described(index: int) -> str:
    """The machines' default on (``index`` 0) or off (1) commands as text for an API
    description, e.g. ``"marlin M106 S255, grbl M8, linuxcnc M64 P0"``."""
    return ", ".join(f"{name} {machine_dispense(name)[index]}" for name in DIALECT_NAMES)
