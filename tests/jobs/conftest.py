"""Fixtures the job tests share."""

from __future__ import annotations

import pytest

from app.platform.db import migrate
from app.runtime.engine import Runtime


@pytest.fixture
def runtime(settings_factory):  # type: ignore[no-untyped-def]
    """A migrated job runtime with a 1 s lease and up to 5 attempts, stopped afterwards (a
    module may override it with its own)."""
    settings = settings_factory(lease_s=1.0, max_attempts=5)
    migrate(settings)
    runtime = Runtime(settings)
    yield runtime
    runtime.stop()
