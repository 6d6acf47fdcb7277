"""The ROS graph as rmw_zenoh publishes it: read every liveliness token of a domain.

This is what ``ros2 node list`` and ``ros2 topic list -t`` see, without a ROS install:
``discover(session, 0)`` returns the parsed tokens of domain 0.
"""

from __future__ import annotations

import logging

import zenoh

from bridge.errors import TransportError
from bridge.net.ros2.tokens import EntityKind, Token, graph_key

_log = logging.getLogger(__name__)


def discover(session: zenoh.Session, domain_id: int, timeout_s: float = 1.0) -> list[Token]:
    """Every entity token of ``domain_id`` currently alive; foreign or malformed keys are skipped."""
    tokens = []
    for reply in session.liveliness().get(graph_key(domain_id), timeout=timeout_s):
        if reply.ok is None:
            continue
        key = str(reply.ok.key_expr)
        try:
            tokens.append(Token.parse(key))
        except TransportError as exc:
            _log.debug("skipped a liveliness token: %s", exc)
    return tokens


def node_names(tokens: list[Token]) -> list[str]:
    """Fully qualified node names, sorted (``ros2 node list``)."""
    names = {f"{t.namespace.rstrip('/')}/{t.node_name}" for t in tokens}
    return sorted(names)


def topic_names_and_types(tokens: list[Token]) -> dict[str, set[str]]:
    """Topic name -> ROS type names of its publishers and subscriptions (``ros2 topic list -t``)."""
    return _names_and_types(tokens, (EntityKind.PUBLISHER, EntityKind.SUBSCRIPTION))


def service_names_and_types(tokens: list[Token]) -> dict[str, set[str]]:
    """Service name -> service type names of its servers and clients (``ros2 service list -t``)."""
    return _names_and_types(tokens, (EntityKind.SERVICE, EntityKind.CLIENT))


def _names_and_types(tokens: list[Token], kinds: tuple[EntityKind, ...]) -> dict[str, set[str]]:
    out: dict[str, set[str]] = {}
    for token in tokens:
        if token.kind in kinds and token.endpoint is not None:
            out.setdefault(token.endpoint.name, set()).add(token.endpoint.type_name)
    return out
