"""The migrations build the schema the models declare, and step down and up again."""

from __future__ import annotations

from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import create_engine, inspect
from sqlmodel import SQLModel

import app.platform.models  # noqa: F401  (the tables, registered on SQLModel.metadata)
from app.platform.db import alembic_config, migrate


def _column_diffs(url: str) -> list:
    """The column additions / removals autogenerate finds between the database and the models."""
    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            diffs = compare_metadata(MigrationContext.configure(conn), SQLModel.metadata)
    finally:
        engine.dispose()
    return [d for d in diffs if isinstance(d, tuple) and d[0] in ("add_column", "remove_column",
                                                                     "add_table", "remove_table")]


def test_head_has_every_column_of_the_models(settings_factory):
    settings = settings_factory()
    migrate(settings)
    assert _column_diffs(settings.resolved_database_url) == []


def test_the_earlier_attempts_migration_steps_down_and_up(settings_factory):
    settings = settings_factory()
    migrate(settings)
    config = alembic_config(settings.resolved_database_url)
    command.downgrade(config, "-1")
    engine = create_engine(settings.resolved_database_url)
    try:
        below = {c["name"] for c in inspect(engine).get_columns("jobs")}
    finally:
        engine.dispose()
    assert "earlier_attempts" not in below
    migrate(settings)
    assert _column_diffs(settings.resolved_database_url) == []
