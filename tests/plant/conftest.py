"""Fixtures of the plant tests: a Zenoh router on loopback for system components in nodes."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.conftest import Loopback, router_on_loopback


@pytest.fixture(scope="module")
def net() -> Iterator[Loopback]:
    """A router session on 127.0.0.1 (a free port) and a key prefix unique to the module."""
    with router_on_loopback() as loopback:
        yield loopback
