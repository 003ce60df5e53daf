"""Alembic environment: batch mode for SQLite, a naming convention, transactional DDL.

SQLite's driver normally commits implicitly around DDL, which can leave a failed
migration half-applied; here the driver is put in autocommit and SQLAlchemy emits an
explicit ``BEGIN`` so each migration is one transaction (the SQLAlchemy recipe).
"""

from __future__ import annotations

from alembic import context
from sqlalchemy import create_engine, event, pool
from sqlmodel import SQLModel

import app.platform.models  # noqa: F401  (registers the tables)

target_metadata = SQLModel.metadata
# (the naming convention is set on the metadata in app.platform.models, before the tables)


def run_migrations_online() -> None:
    url = context.config.get_main_option("sqlalchemy.url")
    is_sqlite = url.startswith("sqlite")
    connectable = create_engine(url, poolclass=pool.NullPool)
    if is_sqlite:
        @event.listens_for(connectable, "connect")
        def _connect(dbapi_connection, _record):  # type: ignore[no-untyped-def]
            dbapi_connection.isolation_level = None
            dbapi_connection.execute("PRAGMA journal_mode=WAL")
            dbapi_connection.execute("PRAGMA busy_timeout=10000")

        @event.listens_for(connectable, "begin")
        def _begin(conn):  # type: ignore[no-untyped-def]
            conn.exec_driver_sql("BEGIN")

    with connectable.connect() as connection:
        context.configure(
            connection=connection,
            target_metadata=target_metadata,
            render_as_batch=is_sqlite,
            transactional_ddl=True,
            transaction_per_migration=True,
            compare_type=True,
        )
        with context.begin_transaction():
            context.run_migrations()
    connectable.dispose()


if context.is_offline_mode():
    raise SystemExit("offline migrations are not supported; run `conforma migrate`")
run_migrations_online()
