"""Health, job kinds and API key management."""

from __future__ import annotations

import functools
from typing import Annotated, Any

from fastapi import APIRouter, Depends
from pydantic import BaseModel
from sqlalchemy import text
from sqlmodel import col, select

import app
from app.api.deps import Admin, RuntimeDep, SessionDep, Viewer, get_keyring
from app.api.schemas import JobKindOut, KeyCreate, KeyCreated, KeyOut, MaterialOut, Page
from app.domain.errors import NotFound
from app.machines.materials import DEFAULT_MATERIAL, MATERIALS
from app.platform.auth import KeyRing
from app.platform.models import ApiKey
from app.runtime.registry import kinds

router = APIRouter(prefix="/api/v1", tags=["system"])


@router.get("/health")
def health(runtime: RuntimeDep) -> dict:
    """Liveness and database reachability (no key needed)."""
    with runtime.engine.connect() as conn:
        conn.execute(text("SELECT 1"))
    return {"status": "ok", "version": app.__version__,
            "database": runtime.engine.dialect.name, "queue": "redis" if runtime.settings.queue_url else "sqlite"}


@router.get("/job-kinds", dependencies=[Viewer])
def job_kinds() -> list[JobKindOut]:
    """Every job kind with the JSON schema of its parameters."""
    return [JobKindOut(name=k.name, queue=k.queue, description=k.description, params_schema=_params_schema(k.params))
            for k in sorted(kinds().values(), key=lambda k: k.name)]


@router.get("/materials", dependencies=[Viewer])
def materials() -> list[MaterialOut]:
    """The material presets: conductive pastes, dielectric inks and a printed substrate's
    plastics, each with the job parameters a form fills in for it and, for pastes and inks,
    the dispense profile a machine takes (``PATCH /machines/{id}`` ``dispense``)."""
    return [MaterialOut(**m.as_dict(), default=m.name == DEFAULT_MATERIAL) for m in MATERIALS]


@functools.cache
def _params_schema(params: type[BaseModel]) -> dict[str, Any]:
    """A kind's parameter schema, built once per parameter model (building all of them took
    most of the 160 ms that GET /job-kinds cost on every page load of jobs.html)."""
    return params.model_json_schema()


@router.post("/keys", status_code=201, dependencies=[Admin])
def create_key(body: KeyCreate, keyring: Annotated[KeyRing, Depends(get_keyring)]) -> KeyCreated:
    """Create an API key; the key is in this response only."""
    record, key = keyring.create(body.role, body.name)
    return KeyCreated(**record.model_dump(), key=key)


@router.get("/keys", dependencies=[Admin])
def list_keys(session: SessionDep) -> Page[KeyOut]:
    rows = session.exec(select(ApiKey).order_by(col(ApiKey.created_at))).all()
    return Page(items=[KeyOut(**r.model_dump()) for r in rows], total=len(rows))


@router.delete("/keys/{key_id}", status_code=204, dependencies=[Admin])
def revoke_key(key_id: str, keyring: Annotated[KeyRing, Depends(get_keyring)]) -> None:
    """Revoke a stored key (404 if unknown or already revoked)."""
    if not keyring.revoke(key_id):
        raise NotFound(f"key {key_id!r} does not exist or is already revoked", field="key_id", value=key_id)
