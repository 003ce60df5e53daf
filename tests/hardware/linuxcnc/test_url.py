"""linuxcnc:// addresses and passwords (no controller needed)."""

from __future__ import annotations

import pytest

from hardware.errors import InvalidConfig
from hardware.linuxcnc.url import parse_url, passwords


def test_parse_url_reads_host_port_and_options():
    address = parse_url("linuxcnc://10.0.0.5:5007?programs=/srv/ngc&joints=5")
    assert (address.host, address.port, address.program_dir, address.joints) == ("10.0.0.5", 5007, "/srv/ngc", 5)
    assert parse_url("linuxcnc://localhost:5007").joints is None


@pytest.mark.parametrize("url", ["linuxcnc://host", "linuxcnc://:5007", "socket://h:1", "linuxcnc://h:99999",
                                 "linuxcnc://h:5007?programs=relative", "linuxcnc://h:5007?joints=0",
                                 "linuxcnc://h:5007?password=x"])
def test_parse_url_names_the_bad_address(url):
    with pytest.raises(InvalidConfig) as info:
        parse_url(url)
    assert info.value.field == "port" and info.value.value == url


def test_passwords_come_from_arguments_then_environment_then_defaults(monkeypatch):
    monkeypatch.delenv("CONFORMA_LINUXCNC_CONNECTPW", raising=False)
    monkeypatch.delenv("CONFORMA_LINUXCNC_ENABLEPW", raising=False)
    assert passwords(None, None) == ("EMC", "EMCTOO")
    monkeypatch.setenv("CONFORMA_LINUXCNC_CONNECTPW", "c1")
    assert passwords(None, "e2") == ("c1", "e2")
    with pytest.raises(InvalidConfig):
        passwords("has space", None)
