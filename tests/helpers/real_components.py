"""Tests that need a real component (Chromium, PostgreSQL, Redis, LinuxCNC, Printrun).

Outside CI a missing component skips the test and says why, so a developer without, say,
Chromium can still run the rest.  Under ``CI=true`` it FAILS: a green CI must mean the
component was really exercised (``.ci/run`` installs or starts every one of them).
"""

from __future__ import annotations

import os

import pytest


def in_ci() -> bool:
    """True when running under CI (``CI=true``, as ``.ci/run`` is run)."""
    return os.environ.get("CI", "").strip().lower() in ("1", "true", "yes")


def missing(component: str, reason: str) -> None:
    """Skip (developer machine) or fail (CI) because ``component`` is unavailable."""
    message = f"{component} is unavailable: {reason}"
    if in_ci():
        pytest.fail(f"{message} (CI=true: a real component must be present, see .ci/run)", pytrace=False)
    pytest.skip(message)
