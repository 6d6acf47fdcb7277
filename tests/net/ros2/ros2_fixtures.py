"""Fixtures of the ROS 2 wire tests: two Zenoh sessions on the loopback router, and polling.

Not a conftest.py: tests/test_remote.py imports the top-level ``conftest`` by name, and a second
module of that name on sys.path would shadow it. Test modules import these fixtures explicitly
(``*_fixture``; pytest knows them as ``ros_session``, ``peer_session`` and ``eventually``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

import pytest

T = TypeVar("T")


def _session(endpoint: str) -> Any:
    from bridge.net.transport import ZenohOptions, open_session, wait_connected

    session = open_session(ZenohOptions(connect=(endpoint,)))
    assert wait_connected(session, timeout_s=30.0, settle_s=0.05), (
        f"no connection to the test router at {endpoint}"
    )
    return session


@pytest.fixture(name="ros_session")
def ros_session_fixture(loopback: Any) -> Iterator[Any]:
    """The session our RosContext runs on."""
    session = _session(loopback.endpoint)
    try:
        yield session
    finally:
        session.close()


@pytest.fixture(name="peer_session")
def peer_session_fixture(loopback: Any) -> Iterator[Any]:
    """A second session standing in for a ROS 2 machine, written from the design document alone."""
    session = _session(loopback.endpoint)
    try:
        yield session
    finally:
        session.close()


def _eventually(probe: Callable[[], T], timeout_s: float = 30.0, what: str = "condition") -> T:
    """Poll ``probe`` until it returns something truthy (declarations take a moment to propagate)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = probe()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"{what} not reached within {timeout_s} s (last value: {value!r})")
        time.sleep(0.02)


@pytest.fixture(name="eventually")
def eventually_fixture() -> Callable[..., Any]:
    """``eventually(probe, timeout_s, what)``: poll until ``probe()`` is truthy; fail naming ``what``."""
    return _eventually
