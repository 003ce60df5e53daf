"""Typed, strict settings (environment prefix ``CONFORMA_``).

Settings are made by :func:`load_settings` and injected (``create_app(settings)``);
nothing reads the environment at import time.  Unknown ``CONFORMA_*`` variables and
out-of-range values are errors at start-up, not surprises later.
"""

from __future__ import annotations

import os
import shlex
from pathlib import Path
from typing import Literal

from pydantic import Field, ValidationError, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

ROLES = ("viewer", "operator", "admin")
Role = Literal["viewer", "operator", "admin"]

# Variables with the prefix that are read elsewhere (the tests, the hardware contract suite,
# the LinuxCNC simulator): accepted at start-up, not settings of the service.
_FOREIGN_VARIABLES = {"CONFORMA_TEST_PORT", "CONFORMA_TEST_DIALECT", "CONFORMA_TEST_BAUD", "CONFORMA_TEST_MOTION",
                      "CONFORMA_TEST_DATABASE_URL", "CONFORMA_TEST_QUEUE_URL", "CONFORMA_RTAPI_UID",
                      "CONFORMA_SIM_SHARED_NAMESPACES"}


class SettingsError(Exception):
    """The configuration cannot be used; the message names the variable and the value."""


class Settings(BaseSettings):
    """Everything the service can be told.  Paths are resolved; sizes in MiB; times in s."""

    model_config = SettingsConfigDict(env_prefix="CONFORMA_", extra="forbid", frozen=True)

    data_dir: Path = Path("./data")
    database_url: str | None = Field(None, description="SQLAlchemy URL; default SQLite under data_dir")
    queue_url: str | None = Field(None, description="redis://... for RedisHuey; default SqliteHuey under data_dir")
    api_keys: str = Field("", description='static keys, "key1:operator,key2:admin"')
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=1, le=65535)
    viewer: bool = True
    viewer_host: str = "127.0.0.1"
    viewer_port: int = Field(8080, ge=1, le=65535)
    viewer_token_ttl_s: float = Field(120.0, ge=5, le=86_400, description="life of a view token (checked at connect)")
    viewer_origins: str = Field("", description="extra Origins allowed to open the view, comma-separated")
    viewer_secret: str | None = Field(None, min_length=16,
                                      description="view token key; default <data_dir>/viewer.secret")
    embedded_worker: bool = True
    worker_threads: int = Field(2, ge=1, le=64)
    compute_isolation: Literal["process", "thread"] = Field(
        "process", description="process: each compute job in a child process with memory/time limits and a "
        "hard cancel (the default); thread: in a worker thread, without limits (debugging only)")
    job_memory_mb: float = Field(1024.0, ge=64, le=1_000_000,
                                 description="memory a compute job may use (address space above the worker's)")
    job_time_s: float = Field(3600.0, gt=0, le=7 * 86400, description="wall-clock limit of a compute job")
    import_time_s: float = Field(120.0, gt=0, le=3600, description="wall-clock limit of reading and mapping one "
                                 "circuit import (in its own process, with CONFORMA_JOB_MEMORY_MB of memory)")
    blas_threads: int = Field(1, ge=1, le=64, description="BLAS/OpenMP threads of a process that runs compute jobs, "
                              "set once when it starts (the planners' many small solves run fastest on one)")
    cache_mb: float = Field(512.0, ge=0, le=1_000_000,
                            description="disk bound of the per-part cache (<data_dir>/part-cache: parsed meshes, "
                            "edge grids, fitted fields) shared by compute processes, least recently used out; "
                            "0 turns it off")
    compute_cache_mb: float = Field(1024.0, ge=0, le=1_000_000,
                                    description="in-memory cache of each long-lived compute process (parsed meshes "
                                    "with their ray-casting structure and edge grid), least recently used out")
    compute_recycle_jobs: int = Field(200, ge=1, le=1_000_000,
                                      description="a compute process is replaced after this many jobs "
                                      "(1: a fresh process for every job)")
    compute_recycle_mb: float = Field(3072.0, ge=64, le=1_000_000,
                                      description="a compute process is replaced after a job that leaves its resident "
                                      "memory (or its address space's growth) above this")
    compute_warm_up: bool = Field(True, description="start the compute processes (and the fork server that imports "
                                  "the compute core) when the server starts, not at the first compute job")
    compute_idle_processes: int = Field(1, ge=1, le=64,
                                        description="compute processes kept while no job needs them (the ones the "
                                        "warm-up starts); more start while jobs run at once (up to worker_threads) "
                                        "and end after 30 s without a job")
    lease_s: float = Field(30.0, gt=0.5, le=3600)
    max_attempts: int = Field(3, ge=1, le=100)
    reaper_interval_s: float = Field(1.0, gt=0.01, le=600)
    queue_poll_s: float = Field(1.0, gt=0.0, le=60,
                                description="an idle queue consumer's fallback poll: a job submitted in the same "
                                "process wakes it at once; one submitted by another process (SQLite queue) "
                                "waits at most this long (a Redis queue wakes it at once)")
    max_upload_mb: float = Field(200.0, gt=0, le=100_000)
    max_json_mb: float = Field(20.0, gt=0, le=10_000)
    max_unzipped_mb: float = Field(1000.0, gt=0, le=100_000)
    job_plugins: str = Field("", description="comma-separated modules that register extra job kinds")
    socket_hosts: str = Field("127.0.0.1,localhost,::1",
                              description="hosts a machine's socket://host:port may name (comma-separated)")
    sse_streams_per_key: int = Field(64, ge=1, le=10_000, description="open progress streams one API key may hold")
    db_pool_size: int = Field(40, ge=1, le=1000)
    max_active_requests: int = Field(24, ge=1, le=1000, description="API requests served at once (admission)")
    max_waiting_requests: int = Field(2000, ge=0, le=100_000, description="requests queued beyond; more get 503")
    request_wait_s: float = Field(30.0, gt=0, le=600, description="longest wait for a request slot before 503")
    log_level: Literal["debug", "info", "warning", "error"] = "info"
    linuxcnc_connectpw: str | None = Field(None, min_length=1, pattern=r"^\S+$",
                                           description="linuxcncrsh connect password; default LinuxCNC's EMC")
    linuxcnc_enablepw: str | None = Field(None, min_length=1, pattern=r"^\S+$",
                                          description="linuxcncrsh enable password; default LinuxCNC's EMCTOO")
    linuxcnc_programs: Path | None = Field(None, description="absolute directory LinuxCNC reads program files from "
                                           "(same path on the controller); default <tmp>/conforma-linuxcnc")
    linuxcnc_hal_prefix: str | None = Field(None, min_length=1,
                                            description="command (shell words) that enters the LinuxCNC "
                                            "controller's IPC namespace for halcmd / halsampler (e.g. "
                                            "'docker exec linuxcnc'); default this host's HAL")

    @field_validator("linuxcnc_hal_prefix")
    @classmethod
    def _check_hal_prefix(cls, value: str | None) -> str | None:
        if value is not None:
            try:
                words = shlex.split(value)
            except ValueError as exc:
                raise ValueError(f"not shell words: {exc}") from exc
            if not words or not words[0]:
                raise ValueError("names no command")
        return value

    @field_validator("linuxcnc_programs")
    @classmethod
    def _check_programs(cls, value: Path | None) -> Path | None:
        if value is not None and not value.is_absolute():
            raise ValueError("must be an absolute directory (the controller opens programs by this path)")
        return value

    @field_validator("api_keys")
    @classmethod
    def _check_keys(cls, value: str) -> str:
        for item in filter(None, (part.strip() for part in value.split(","))):
            key, sep, role = item.rpartition(":")
            if not sep or not key or role not in ROLES:
                raise ValueError(f"expected 'key:role' with role in {ROLES}, got {item!r}")
            if len(key) < 8:
                raise ValueError("API keys must have at least 8 characters")
        return value

    @property
    def resolved_database_url(self) -> str:
        """The SQLAlchemy URL in use (SQLite file under ``data_dir`` by default)."""
        if self.database_url:
            url = self.database_url
            if url.startswith("postgresql://") or url.startswith("postgres://"):
                url = "postgresql+psycopg://" + url.split("://", 1)[1]
            return url
        return f"sqlite:///{(self.data_dir / 'conforma.db').resolve()}"

    @property
    def is_sqlite(self) -> bool:
        return self.resolved_database_url.startswith("sqlite")

    @property
    def blob_dir(self) -> Path:
        return self.data_dir / "blobs"

    @property
    def socket_host_list(self) -> tuple[str, ...]:
        return tuple(h.strip() for h in self.socket_hosts.split(",") if h.strip())

    def static_keys(self) -> dict[str, str]:
        """``{key: role}`` from ``api_keys``."""
        out: dict[str, str] = {}
        for item in filter(None, (part.strip() for part in self.api_keys.split(","))):
            key, _, role = item.rpartition(":")
            out[key] = role
        return out


def unknown_variables(environ: dict[str, str]) -> list[str]:
    """The ``CONFORMA_*`` names in ``environ`` that are neither a setting nor a variable read
    elsewhere (sorted): the start-up check refuses them."""
    known = {f"CONFORMA_{name.upper()}" for name in Settings.model_fields} | _FOREIGN_VARIABLES
    return sorted(k for k in environ if k.startswith("CONFORMA_") and k not in known)


def load_settings(environ: dict[str, str] | None = None, **overrides: object) -> Settings:
    """Build settings from ``environ`` (default ``os.environ``) plus explicit overrides.

    Raises :class:`SettingsError` for unknown ``CONFORMA_*`` variables or bad values.
    """
    env = dict(os.environ if environ is None else environ)
    unknown = unknown_variables(env)
    if unknown:
        raise SettingsError(f"unknown setting(s): {', '.join(unknown)}")
    values: dict[str, object] = {
        name: env[f"CONFORMA_{name.upper()}"]
        for name in Settings.model_fields
        if f"CONFORMA_{name.upper()}" in env
    }
    values.update({k: v for k, v in overrides.items() if v is not None})
    try:
        # model_validate does not read the environment again: errors name our keys only.
        settings = Settings.model_validate(values)
    except ValidationError as exc:
        problems = "; ".join(
            f"CONFORMA_{'.'.join(str(p) for p in err['loc']).upper()}={err.get('input')!r}: {err['msg']}"
            for err in exc.errors()
        )
        raise SettingsError(problems) from None
    return settings.model_copy(update={"data_dir": settings.data_dir.expanduser().resolve()})

