"""A device is opened exclusively; a second opener is refused."""

from __future__ import annotations

import os

import pytest

from hardware.errors import LinkError
from hardware.link import Link


def test_a_device_already_open_is_refused_to_a_second_link():
    controller, device = os.openpty()  # a pseudo-terminal stands in for a USB serial device
    path = os.ttyname(device)
    try:
        first = Link.open(path, dialect="grbl")
        with pytest.raises(LinkError) as info:
            Link.open(path, dialect="grbl")
        assert info.value.field == "port" and "exclusive" in str(info.value)
        first.close()
        Link.open(path, dialect="grbl").close()  # released on close: the next opener gets it
    finally:
        os.close(controller)
        os.close(device)
