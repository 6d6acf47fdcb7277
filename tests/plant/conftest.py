"""Fixtures of the plant tests: a Zenoh router on loopback for system components in nodes."""

from __future__ import annotations

import uuid
from collections.abc import Iterator

import pytest

from tests.conftest import Loopback, free_port


@pytest.fixture(scope="module")
def net() -> Iterator[Loopback]:
    """A router session on 127.0.0.1 (a free port) and a key prefix unique to the module."""
    from bridge.net.transport import ZenohOptions, open_session

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(ZenohOptions(mode="router", listen=(endpoint,)))
    try:
        yield Loopback(endpoint, f"test_{uuid.uuid4().hex[:10]}", session)
    finally:
        session.close()
