"""Settings are strict: unknown variables and out-of-range values fail at start-up."""

from __future__ import annotations

import pytest

from app.config import SettingsError, load_settings


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
