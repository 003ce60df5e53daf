"""Settings are strict: unknown variables and out-of-range values fail at start-up."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from app.platform.config import SettingsError, load_settings, unknown_variables
from app.runtime.engine import linuxcnc_options


def test_defaults_resolve_under_data_dir(tmp_path):
    settings = load_settings({"CONFORMA_DATA_DIR": str(tmp_path)})
    assert settings.resolved_database_url == f"sqlite:///{tmp_path / 'conforma.db'}"
    assert settings.is_sqlite and settings.max_upload_mb == 200


@pytest.mark.parametrize(
    ("env", "needle"),
    [
        ({"CONFORMA_DATABSE_URL": "x"}, "unknown setting(s): CONFORMA_DATABSE_URL"),
        ({"CONFORMA_PORT": "70000"}, "CONFORMA_PORT='70000'"),
        ({"CONFORMA_LEASE_S": "-1"}, "CONFORMA_LEASE_S"),
        ({"CONFORMA_API_KEYS": "short:admin"}, "at least 8"),
        ({"CONFORMA_API_KEYS": "longenoughkey:root"}, "role"),
    ],
)
def test_bad_settings_are_errors(env, needle):
    with pytest.raises(SettingsError) as info:
        load_settings(env)
    assert needle in str(info.value)


def test_postgres_url_gets_the_psycopg_driver():
    settings = load_settings({"CONFORMA_DATABASE_URL": "postgresql://u@h/db"})
    assert settings.resolved_database_url == "postgresql+psycopg://u@h/db"
    assert not settings.is_sqlite


DOCS = Path(__file__).resolve().parents[2] / "docs"


def _documented_configuration_names() -> list[str]:
    """Every ``CONFORMA_*`` name the manual's Configuration table documents."""
    page = (DOCS / "install.md").read_text()
    section = page.split("\n## Configuration\n", 1)[1].split("\n## ", 1)[0]
    table = [line for line in section.splitlines() if line.startswith("| `CONFORMA_")]
    return sorted({name for line in table for name in re.findall(r"CONFORMA_[A-Z0-9_]+", line.split("|")[1])})


def test_every_setting_the_manual_documents_passes_the_start_up_check():
    names = _documented_configuration_names()
    assert len(names) >= 30 and "CONFORMA_LINUXCNC_ENABLEPW" in names
    assert unknown_variables({name: "x" for name in names}) == []
    # and every name anywhere in the manual and the README (test and simulator variables included)
    text = "\n".join(p.read_text() for p in [*DOCS.glob("*.md"), DOCS.parent / "README.md"])
    assert unknown_variables({name: "x" for name in re.findall(r"CONFORMA_[A-Z0-9_]*[A-Z0-9]", text)}) == []


def test_linuxcnc_settings_are_read_and_checked(tmp_path):
    settings = load_settings({"CONFORMA_DATA_DIR": str(tmp_path), "CONFORMA_LINUXCNC_CONNECTPW": "c0nnect",
                              "CONFORMA_LINUXCNC_ENABLEPW": "en4ble", "CONFORMA_LINUXCNC_PROGRAMS": "/srv/ngc"})
    assert (settings.linuxcnc_connectpw, settings.linuxcnc_enablepw) == ("c0nnect", "en4ble")
    assert settings.linuxcnc_programs == Path("/srv/ngc")
    prefixed = load_settings({"CONFORMA_LINUXCNC_HAL_PREFIX": "docker exec 'lin cnc'"})
    assert shlex.split(prefixed.linuxcnc_hal_prefix) == ["docker", "exec", "lin cnc"]
    assert linuxcnc_options(prefixed) == {"hal_prefix": "docker exec 'lin cnc'"}
    for env, needle in (({"CONFORMA_LINUXCNC_PROGRAMS": "ngc"}, "absolute"),
                        ({"CONFORMA_LINUXCNC_HAL_PREFIX": "docker exec 'open"}, "not shell words"),
                        ({"CONFORMA_LINUXCNC_HAL_PREFIX": "''"}, "names no command"),
                        ({"CONFORMA_LINUXCNC_ENABLEPW": "two words"}, "CONFORMA_LINUXCNC_ENABLEPW")):
        with pytest.raises(SettingsError) as info:
            load_settings(env)
        assert needle in str(info.value)


def test_serve_starts_with_the_documented_linuxcnc_settings(tmp_path, monkeypatch, capsys):
    """``conforma serve`` up to the web server's start: the settings are accepted and reach
    the LinuxCNC machines it builds."""
    import uvicorn

    from app.cli import main
    from app.platform.models import Machine
    from app.runtime.engine import Runtime

    served = []
    monkeypatch.setattr(uvicorn, "run", lambda app, **kwargs: served.append(app))
    for name, value in (("CONFORMA_LINUXCNC_CONNECTPW", "c0nnect"), ("CONFORMA_LINUXCNC_ENABLEPW", "en4ble"),
                        ("CONFORMA_LINUXCNC_PROGRAMS", str(tmp_path / "ngc")), ("CONFORMA_VIEWER", "false")):
        monkeypatch.setenv(name, value)
    assert main(["serve", "--data-dir", str(tmp_path / "data")]) == 0, capsys.readouterr().err
    assert len(served) == 1
    runtime = Runtime(served[0].state.settings)  # what the served app's start-up makes
    row = Machine(id="mach_lcnc", name="mill", port="linuxcnc://127.0.0.1:5007?joints=3", dialect="linuxcnc")
    machine = runtime.machines.build(row)
    runtime.engine.dispose()
    assert (machine._connect_pw, machine._enable_pw) == ("c0nnect", "en4ble")
    assert machine.address.program_dir == str(tmp_path / "ngc")
