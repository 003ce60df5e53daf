"""Engine, sessions and migrations.

SQLite runs in WAL mode with ``synchronous=NORMAL``, a busy timeout and foreign keys on
every connection (FIELD_NOTES); the pool is sized so that 64 concurrent synchronous
requests cannot deadlock it.  PostgreSQL is used when ``CONFORMA_DATABASE_URL`` names it.
State changes are single conditional statements (see ``app.runtime.store``), never
read-modify-write through the ORM.
"""

from __future__ import annotations

import fcntl
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sqlalchemy import Engine, create_engine, event, select, text, update
from sqlalchemy.pool import NullPool
from sqlmodel import Session

from app.platform.config import Settings

if TYPE_CHECKING:
    from alembic.config import Config

MIGRATIONS_DIR = Path(__file__).resolve().parents[2] / "migrations"
_PG_MIGRATION_LOCK = 0x436F6E66  # "Conf"
SQLITE_PRAGMAS = (
    "PRAGMA journal_mode=WAL",
    "PRAGMA synchronous=NORMAL",
    "PRAGMA busy_timeout=10000",
    "PRAGMA foreign_keys=ON",
)


def _apply_sqlite_pragmas(dbapi_connection, _record) -> None:
    cursor = dbapi_connection.cursor()
    for pragma in SQLITE_PRAGMAS:
        cursor.execute(pragma)
    cursor.close()


def make_engine(settings: Settings) -> Engine:
    """The engine for ``settings``; the data directory is created for SQLite."""
    url = settings.resolved_database_url
    if settings.is_sqlite:
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        engine = create_engine(
            url,
            connect_args={"check_same_thread": False, "timeout": 10},
            pool_size=settings.db_pool_size,
            max_overflow=settings.db_pool_size,
            pool_timeout=10,  # then a 503 with Retry-After (app.api.errors), never a 30 s hang
            pool_pre_ping=False,
        )
        event.listen(engine, "connect", _apply_sqlite_pragmas)
        return engine
    return create_engine(url, pool_size=settings.db_pool_size // 2, max_overflow=settings.db_pool_size,
                         pool_pre_ping=True)


@contextmanager
def session_scope(engine: Engine) -> Iterator[Session]:
    """A session that commits on success and rolls back on any error."""
    with Session(engine, expire_on_commit=False) as session:
        try:
            yield session
            session.commit()
        except BaseException:
            session.rollback()
            raise


def alembic_config(url: str) -> Config:
    from alembic.config import Config  # here, not at the top: a compute process never migrates (~10 MiB resident)

    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS_DIR))
    config.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return config


def migrate(settings: Settings, revision: str = "head") -> None:
    """Apply migrations up to ``revision`` (each in one transaction, also on SQLite).

    Processes starting together (API and workers) take turns: a file lock on SQLite, an
    advisory lock on PostgreSQL.
    """
    from alembic import command

    config = alembic_config(settings.resolved_database_url)
    if settings.is_sqlite:
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        with open(settings.data_dir / ".migrate.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            command.upgrade(config, revision)
        return
    engine = create_engine(settings.resolved_database_url, poolclass=NullPool)
    try:
        with engine.connect() as conn:
            conn.execute(text("SELECT pg_advisory_lock(:key)"), {"key": _PG_MIGRATION_LOCK})
            try:
                command.upgrade(config, revision)
            finally:
                conn.execute(text("SELECT pg_advisory_unlock(:key)"), {"key": _PG_MIGRATION_LOCK})
    finally:
        engine.dispose()


def lock_for_delete(session: Session, table: Any, ids: list[str]) -> int:
    """Lock rows of ``table`` (a SQLModel class with an ``id``) against concurrent readers that
    lock with :func:`existing_locked`, inside the session's transaction; returns how many exist.

    SQLite: the no-op UPDATE takes the database's write lock, so what this transaction reads
    next is current and no other writer commits until it ends.  PostgreSQL: ``FOR UPDATE``
    row locks, which conflict with the ``FOR SHARE`` of :func:`existing_locked`.
    """
    if not ids:
        return 0
    session.execute(update(table).where(table.id.in_(ids)).values(id=table.id))
    return len(session.execute(select(table.id).where(table.id.in_(ids)).with_for_update()).all())


def existing_locked(session: Session, table: Any, ids: list[str]) -> set[str]:
    """The ids of ``table`` that exist, read under a lock that keeps them from being deleted
    before the transaction ends.  Call after the transaction's first write (on SQLite that
    write holds the database lock, so the answer is current)."""
    if not ids:
        return set()
    return set(session.execute(select(table.id).where(table.id.in_(ids)).with_for_update(read=True)).scalars())
