"""``hardware.port_url.PortUrl``: each field of the port spellings in use, read once."""

from __future__ import annotations

import pytest

from hardware.port_url import PortUrl


@pytest.mark.parametrize(("text", "scheme", "host", "port", "name", "query"), [
    ("linuxcnc://127.0.0.1:5007?joints=5", "linuxcnc", "127.0.0.1", 5007, "127.0.0.1:5007", "joints=5"),
    ("socket://Bridge.LAN:23", "socket", "bridge.lan", 23, "Bridge.LAN:23", ""),
    ("mock://Bench?dialect=grbl&seed=3", "mock", "bench", None, "Bench", "dialect=grbl&seed=3"),
    ("mock://", "mock", "", None, "default", ""),
    ("lkg://s1?offset=1,2,3", "lkg", "s1", None, "s1", "offset=1,2,3"),
    ("/dev/ttyUSB0", "", "", None, "dev/ttyUSB0", ""),
    ("COM3", "", "", None, "COM3", ""),
])
def test_fields(text: str, scheme: str, host: str, port: int | None, name: str, query: str) -> None:
    url = PortUrl.parse(text)
    assert (url.scheme, url.host, url.port, url.name, url.query, str(url)) == (scheme, host, port, name, query, text)
    assert url.is_mock == (scheme == "mock")
    assert url.is_tcp == (scheme in ("socket", "linuxcnc"))


def test_a_port_that_is_no_number_is_none_not_an_error() -> None:
    assert PortUrl.parse("socket://host:notaport").port is None
    assert PortUrl.parse("socket://host:70000").port is None  # beyond 65535
    assert PortUrl.parse("linuxcnc://h:1").port == 1


def test_options_keep_every_value_and_blanks() -> None:
    assert PortUrl.parse("linuxcnc://h:1?joints=5&programs=/a&joints=6&x=").options == {
        "joints": ["5", "6"], "programs": ["/a"], "x": [""]}
