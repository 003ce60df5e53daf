"""Shared helpers for the hardware tests: fresh mock worlds with unique names."""

from __future__ import annotations

import itertools

import pytest

from hardware.mock import MockWorld, register_world, unregister_world

_names = itertools.count()


@pytest.fixture
def make_world():
    """``make_world(**kwargs) -> (url, world)``; worlds are unregistered afterwards."""
    created = []

    def make(**kwargs):
        name = f"test{next(_names)}"
        world = register_world(name, MockWorld(**kwargs))
        created.append(name)
        return f"mock://{name}", world

    yield make
    for name in created:
        unregister_world(name)
