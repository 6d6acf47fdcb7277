"""Service servers and clients of a ``RosNode``, the way rmw_zenoh (Jazzy) maps them onto queries.

A server is a queryable declared *complete* on the service key (ROS clients query with target
ALL_COMPLETE and never reach an incomplete one) plus an ``SS`` token, without which
``ros2 service call`` waits forever. A request carries the client's attachment; the reply carries
the request's sequence number, a fresh timestamp and the client's GID, and ``ros2 service call``
matches it by that sequence number. A client sends ``get`` with its own attachment (sequence
numbers from 1) and declares an ``SC`` token.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import zenoh

from bridge.errors import StepTimeout, TransportError
from bridge.net.ros2.attachment import Attachment
from bridge.net.ros2.endpoints import RosEndpoint
from bridge.net.ros2.interfaces import check_cdr, deserialize, serialize
from bridge.net.ros2.names import dds_type_name, mangle
from bridge.net.ros2.qos import QoS
from bridge.net.ros2.tokens import ADMIN_SPACE, EntityKind

if TYPE_CHECKING:
    from bridge.net.ros2.node import RosNode

_log = logging.getLogger(__name__)
ServiceHandler = Callable[[bytes], bytes]
"""Gets the request CDR (header included) on a Zenoh thread and returns the response CDR."""


class Service(RosEndpoint):
    """Answers requests with ``handler``. ``counters``: served, rejected (malformed), errors."""

    kind = EntityKind.SERVICE
    interface = "srv"

    def __init__(self, node: RosNode, name: str, srv_type: str, handler: ServiceHandler, qos: QoS) -> None:
        super().__init__(node, name, srv_type, qos)
        self._handler = handler
        self._declared.append(self.session.declare_queryable(self.key, self._on_query, complete=True))
        self._declare_token()

    def _on_query(self, query: zenoh.Query) -> None:
        with query:  # finalises the query, so the caller is not left waiting for its timeout
            try:
                raw = query.attachment.to_bytes() if query.attachment is not None else None
                request_attachment = Attachment.decode(raw)
                request = check_cdr(query.payload.to_bytes() if query.payload is not None else b"")
            except TransportError as exc:
                self.counters["rejected"] += 1
                _log.warning("service %s rejected a request: %s", self.name, exc)
                query.reply_err(f"service {self.name} rejected the request: {exc}".encode())
                return
            try:
                response = check_cdr(bytes(self._handler(request)))
            except Exception as exc:
                self.counters["errors"] += 1
                _log.exception("service %s: the handler failed", self.name)
                query.reply_err(f"service {self.name} failed: {exc}".encode())
                return
            reply = Attachment.now(request_attachment.sequence_number, request_attachment.gid)
            self.counters["served"] += 1
            query.reply(self.key, response, attachment=reply.encode())


class Client(RosEndpoint):
    """Calls a service: ``call(request_cdr)`` blocks until the response or ``timeout_s``."""

    kind = EntityKind.CLIENT
    interface = "srv"

    def __init__(self, node: RosNode, name: str, srv_type: str, qos: QoS) -> None:
        super().__init__(node, name, srv_type, qos)
        self._lock = threading.Lock()
        self._sequence = 0
        self._declare_token()

    def call(self, request: bytes, timeout_s: float = 10.0) -> bytes:
        """Send one CDR request; returns the response CDR.

        Raises:
            StepTimeout: no response within ``timeout_s``.
            TransportError: no server, an error reply, or a reply that is not rmw_zenoh's.
        """
        check_cdr(request)
        with self._lock:
            if self._closed:
                raise TransportError(f"client of {self.name} is closed; create a new one to call")
            self._sequence += 1
            sequence = self._sequence
        attachment = Attachment.now(sequence, self.gid)
        try:
            replies = self.session.get(
                self.key,
                payload=request,
                attachment=attachment.encode(),
                target=zenoh.QueryTarget.ALL_COMPLETE,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=timeout_s,
            )
            for reply in replies:  # the first reply that answers this request wins
                response = self._response(reply, sequence, timeout_s)
                if response is not None:
                    return response
        except zenoh.ZError as exc:
            raise TransportError(f"calling {self.name} failed: {exc} (key {self.key})") from exc
        raise TransportError(
            f"no server answered {self.name} ({self.type_name}) in ROS domain {self.node.context.domain_id}; "
            f"start the server or check ROS_DOMAIN_ID and the Zenoh router (key {self.key})"
        )

    def _response(self, reply: zenoh.Reply, sequence: int, timeout_s: float) -> bytes | None:
        if reply.ok is None:
            error = reply.err.payload.to_bytes() if reply.err is not None else b""
            if error == b"Timeout":
                raise StepTimeout(f"service {self.name} did not answer within {timeout_s} s (key {self.key})")
            raise TransportError(
                f"service {self.name} answered with an error: {error.decode(errors='replace')}"
            )
        raw = reply.ok.attachment.to_bytes() if reply.ok.attachment is not None else None
        try:
            attachment = Attachment.decode(raw)
        except TransportError as exc:
            raise TransportError(f"the reply of service {self.name} is not rmw_zenoh's: {exc}") from None
        if attachment.sequence_number != sequence:
            _log.warning("client %s ignored a reply to request %d", self.name, attachment.sequence_number)
            return None
        return check_cdr(reply.ok.payload.to_bytes())

    def call_message(self, request: Any, timeout_s: float = 10.0) -> Any:
        """Serialize a rosbags ``<srv>_Request``, call, and decode the ``<srv>_Response``."""
        payload = serialize(request, f"{self.type_name}_Request")
        return deserialize(self.call(payload, timeout_s), f"{self.type_name}_Response")

    def service_is_ready(self, timeout_s: float = 0.5) -> bool:
        """Whether a server's ``SS`` token for this name, type and hash is in the graph."""
        domain = self.node.context.domain_id
        pattern = (
            f"{ADMIN_SPACE}/{domain}/*/*/*/{EntityKind.SERVICE.value}/*/*/*/"
            f"{mangle(self.name)}/{dds_type_name(self.type_name)}/{self.type_hash}/*"
        )
        return any(
            reply.ok is not None for reply in self.session.liveliness().get(pattern, timeout=timeout_s)
        )

    def wait_for_service(self, timeout_s: float = 5.0) -> bool:
        """Poll ``service_is_ready`` until it is true or ``timeout_s`` has passed."""
        deadline = time.monotonic() + timeout_s
        while True:
            if self.service_is_ready(timeout_s=min(0.5, max(deadline - time.monotonic(), 0.05))):
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.05)
