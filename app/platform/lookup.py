"""Looking records up by id for the routers and the job kinds: a missing one is a
:class:`app.domain.errors.NotFound` that names it."""

from __future__ import annotations

from typing import TypeVar

from sqlmodel import Session, SQLModel

from app.domain.errors import NotFound
from app.platform.models import Job, Machine, Part, Trace

T = TypeVar("T", bound=SQLModel)
_LABELS = {Part: "part", Trace: "trace", Job: "job", Machine: "machine"}


def get_or_404(session: Session, model: type[T], record_id: str, *, field: str | None = None) -> T:
    """The record with ``record_id`` or a NotFound that names it."""
    record = session.get(model, record_id)
    if record is None:
        label = _LABELS.get(model, model.__name__.lower())
        raise NotFound(f"{label} {record_id!r} does not exist", field=field or f"{label}_id", value=record_id)
    return record
