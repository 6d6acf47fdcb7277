"""Publishers and subscriptions of a ``RosNode``: Zenoh entities plus their liveliness tokens.

A publisher puts CDR payloads on the topic's data key with the 33-byte attachment (sequence
number from 1, wall-clock source timestamp, the publisher's GID). A subscription hands the
payload and the decoded attachment to its callback; samples without a valid attachment or CDR
header are counted and dropped, as rmw_zenoh drops them. Services and clients live in
``bridge.net.ros2.services``.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import zenoh
from zenoh import ext

from bridge.errors import ConfigError, TransportError
from bridge.net.ros2.attachment import Attachment
from bridge.net.ros2.interfaces import check_cdr
from bridge.net.ros2.names import data_key, dds_type_name, split_type_name
from bridge.net.ros2.qos import History, QoS
from bridge.net.ros2.tokens import Endpoint, EntityKind, Token, gid
from bridge.net.ros2.typehash import type_hash
from bridge.net.transport import undeclare

if TYPE_CHECKING:
    from bridge.net.ros2.node import RosNode

_log = logging.getLogger(__name__)
MessageCallback = Callable[[bytes, Attachment], None]
"""Called on a Zenoh thread with the CDR payload (header included) and the sample's attachment."""
HEARTBEAT_S = 0.5  # rmw_zenoh's SAMPLE_MISS_DETECTION_HEARTBEAT_PERIOD for reliable TRANSIENT_LOCAL


class Declared(Protocol):
    def undeclare(self) -> Any: ...


class RosEndpoint:
    """What publishers, subscriptions, services and clients share: names, key, token and GID.

    Attributes:
        name: the fully qualified topic or service name (``/robot1/joint_states``).
        key: the Zenoh data key expression.
        token: the liveliness token key expression; ``gid`` is derived from it.
    """

    kind: ClassVar[EntityKind]
    interface: ClassVar[str] = "msg"

    def __init__(self, node: RosNode, name: str, type_name: str, qos: QoS) -> None:
        if split_type_name(type_name)[1] != self.interface:
            raise ConfigError(
                f"a {self.kind.name.lower()} needs a '{self.interface}' type (e.g. "
                f"{'std_srvs/srv/Trigger' if self.interface == 'srv' else 'std_msgs/msg/Float64'}), "
                f"got {type_name!r}"
            )
        self.node, self.type_name, self.qos = node, type_name, qos
        self.name = node.resolve(name)
        self.type_hash = type_hash(type_name)
        self.key = data_key(node.context.domain_id, self.name, type_name, self.type_hash)
        self.entity_id = node.context.next_entity_id()
        self.token = Token(
            domain_id=node.context.domain_id,
            zid=node.context.zid,
            node_id=node.node_id,
            entity_id=self.entity_id,
            kind=self.kind,
            namespace=node.namespace,
            node_name=node.name,
            enclave=node.context.enclave,
            endpoint=Endpoint(self.name, dds_type_name(type_name), self.type_hash, qos),
        ).key
        self.gid = gid(self.token)
        self.counters: Counter[str] = Counter()
        self._declared: list[Declared] = []
        self._closed = False

    @property
    def session(self) -> zenoh.Session:
        return self.node.context.session

    def _declare_token(self) -> None:
        self._declared.append(self.session.liveliness().declare_token(self.token))

    def close(self) -> None:
        """Undeclare the token (the entity leaves the ROS graph) and the Zenoh entity."""
        if self._closed:
            return
        self._closed = True
        for declared in reversed(self._declared):
            try:
                undeclare(declared)
            except zenoh.ZError:
                _log.debug("undeclare of %s failed (session closed?)", self.name, exc_info=True)
        self._declared.clear()
        self.node._forget(self)

    def __enter__(self) -> RosEndpoint:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name} [{self.type_name}] key={self.key}>"


class Publisher(RosEndpoint):
    """Publishes CDR payloads on a topic. TRANSIENT_LOCAL keeps the last ``depth`` samples in a cache."""

    kind = EntityKind.PUBLISHER

    def __init__(self, node: RosNode, topic: str, type_name: str, qos: QoS) -> None:
        super().__init__(node, topic, type_name, qos)
        self._lock = threading.Lock()
        self._sequence = 0
        self._publisher = self._declare_publisher(qos.adapted())
        self._declared.append(self._publisher)
        self._declare_token()

    def _declare_publisher(self, qos: QoS) -> zenoh.Publisher | ext.AdvancedPublisher:
        reliable = qos.reliable
        options: dict[str, Any] = {
            "reliability": zenoh.Reliability.RELIABLE if reliable else zenoh.Reliability.BEST_EFFORT,
            # As rmw_zenoh: drop under congestion, except a reliable KEEP_ALL publisher blocks.
            "congestion_control": zenoh.CongestionControl.BLOCK
            if reliable and qos.history == History.KEEP_ALL
            else zenoh.CongestionControl.DROP,
        }
        if not qos.transient_local:
            return self.session.declare_publisher(self.key, **options)
        heartbeat = (
            ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=HEARTBEAT_S) if reliable else None
        )
        return ext.declare_advanced_publisher(
            self.session,
            self.key,
            cache=ext.CacheConfig(max_samples=qos.depth),
            publisher_detection=True,
            sample_miss_detection=heartbeat,
            **options,
        )

    def publish(self, payload: bytes) -> Attachment:
        """Send one CDR payload (header included); returns the attachment that went with it."""
        check_cdr(payload)
        with self._lock:
            if self._closed:
                raise TransportError(f"publisher {self.name} is closed; create a new one to publish")
            self._sequence += 1
            attachment = Attachment.now(self._sequence, self.gid)
            try:
                self._publisher.put(payload, attachment=attachment.encode())
            except zenoh.ZError as exc:
                raise TransportError(f"publishing on {self.name} failed: {exc} (key {self.key})") from exc
        self.counters["published"] += 1
        return attachment


class Subscription(RosEndpoint):
    """Receives a topic. ``counters``: received, lost (sequence gaps per publisher GID), dropped, errors."""

    kind = EntityKind.SUBSCRIPTION

    def __init__(
        self, node: RosNode, topic: str, type_name: str, callback: MessageCallback, qos: QoS
    ) -> None:
        super().__init__(node, topic, type_name, qos)
        self._callback = callback
        self._last_sequence: dict[bytes, int] = {}
        self._declared.append(self._declare_subscriber(qos.adapted()))
        self._declare_token()

    def _declare_subscriber(self, qos: QoS) -> Declared:
        if not qos.transient_local:
            return self.session.declare_subscriber(self.key, self._on_sample)
        return ext.declare_advanced_subscriber(
            self.session,
            self.key,
            self._on_sample,
            history=ext.HistoryConfig(detect_late_publishers=True, max_samples=qos.depth),
            recovery=ext.RecoveryConfig(periodic_queries=None, heartbeat=True) if qos.reliable else None,
            subscriber_detection=True,
        )

    def _on_sample(self, sample: zenoh.Sample) -> None:
        raw = sample.attachment.to_bytes() if sample.attachment is not None else None
        payload = sample.payload.to_bytes()
        try:
            attachment = Attachment.decode(raw)
            check_cdr(payload)
        except TransportError as exc:
            self._drop(str(exc))
            return
        self._count(attachment)
        try:
            self._callback(payload, attachment)
        except Exception:
            self.counters["errors"] += 1
            _log.exception(
                "subscription %s: the callback failed on sample %d", self.name, attachment.sequence_number
            )

    def _count(self, attachment: Attachment) -> None:
        self.counters["received"] += 1
        last = self._last_sequence.get(attachment.gid)
        if last is not None and attachment.sequence_number > last + 1:
            self.counters["lost"] += attachment.sequence_number - last - 1
        self._last_sequence[attachment.gid] = attachment.sequence_number

    def _drop(self, reason: str) -> None:
        self.counters["dropped"] += 1
        dropped = self.counters["dropped"]
        if dropped <= 5 or dropped % 1000 == 0:
            _log.warning("subscription %s dropped a sample (%d so far): %s", self.name, dropped, reason)
