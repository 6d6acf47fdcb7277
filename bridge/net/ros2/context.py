"""``RosContext``: a Zenoh session seen as one rmw_zenoh context (domain, enclave, id counter).

rmw_zenoh gives each context one Zenoh session and one counter, starting at 0, from which nodes
and all their endpoints draw their ids; the session's Zenoh id (``str(session.zid())``) is part of
every token. Here the counter belongs to the session, so two contexts over one session never hand
out the same id.
"""

from __future__ import annotations

import itertools
import logging
import threading
from typing import Any

import zenoh

from bridge.errors import TransportError
from bridge.net.ros2.names import check_domain_id, domain_id_from_env, normalize_namespace
from bridge.net.ros2.node import RosNode
from bridge.net.transport import ZenohOptions, open_session

_log = logging.getLogger(__name__)
ROUTER_ENDPOINT = "tcp/localhost:7447"
"""Where ``ros2 run rmw_zenoh_cpp rmw_zenohd`` (or ``fmu-bridge router``) listens by default."""

_COUNTERS_LOCK = threading.Lock()
_COUNTERS: dict[str, itertools.count[int]] = {}


def session_id(session: zenoh.Session) -> str:
    """The Zenoh id as rmw_zenoh writes it into tokens: lowercase hex of the session's ``zid``."""
    return str(session.zid())


def _next_id(zid: str) -> int:
    with _COUNTERS_LOCK:
        counter = _COUNTERS.setdefault(zid, itertools.count())
        return next(counter)


def _close(session: Any) -> None:
    session.close()  # untyped in zenoh's stub


class RosContext:
    """ROS 2 (rmw_zenoh, Jazzy) over an open Zenoh session.

    Args:
        session: an open Zenoh session, connected to the same router as the ROS machines.
        domain_id: the ROS domain; ``None`` reads ``ROS_DOMAIN_ID`` (0 when unset).
        namespace: the default namespace of nodes created here (``/`` is the root).
        enclave: the SROS enclave name written into tokens (``/``, shown as ``%``).
        own_session: close the session in ``close()`` (``RosContext.open`` sets it).
    """

    def __init__(
        self,
        session: zenoh.Session,
        *,
        domain_id: int | None = None,
        namespace: str = "/",
        enclave: str = "/",
        own_session: bool = False,
    ) -> None:
        if session.is_closed():
            raise TransportError(
                "the Zenoh session is closed; open one with bridge.net.transport.open_session"
            )
        self.session = session
        self.domain_id = domain_id_from_env() if domain_id is None else check_domain_id(domain_id)
        self.namespace = normalize_namespace(namespace)
        self.enclave = normalize_namespace(enclave)
        self.zid = session_id(session)
        self._own_session = own_session
        self._lock = threading.Lock()
        self._nodes: list[RosNode] = []

    @classmethod
    def open(cls, options: ZenohOptions | None = None, **kwargs: Any) -> RosContext:
        """Open a session (default: peer connected to ``tcp/localhost:7447``, as rmw_zenoh does)."""
        session = open_session(options or ZenohOptions(mode="peer", connect=(ROUTER_ENDPOINT,)))
        return cls(session, own_session=True, **kwargs)

    def next_entity_id(self) -> int:
        """The next node or entity id of this session (0, 1, 2, ...)."""
        return _next_id(self.zid)

    def create_node(self, name: str, namespace: str | None = None) -> RosNode:
        """A node named ``name`` in ``namespace`` (default: the context's); it shows in ``ros2 node list``."""
        node = RosNode(self, name, self.namespace if namespace is None else namespace)
        with self._lock:
            self._nodes.append(node)
        return node

    @property
    def nodes(self) -> list[RosNode]:
        with self._lock:
            return list(self._nodes)

    def _forget(self, node: RosNode) -> None:
        with self._lock:
            if node in self._nodes:
                self._nodes.remove(node)

    def close(self) -> None:
        """Close every node; close the session too if this context opened it."""
        for node in reversed(self.nodes):
            node.close()
        if self._own_session and not self.session.is_closed():
            _close(self.session)

    def __enter__(self) -> RosContext:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<RosContext domain={self.domain_id} zid={self.zid} nodes={len(self.nodes)}>"
