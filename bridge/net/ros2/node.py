"""``RosNode``: a ROS 2 node as rmw_zenoh shows it, with publishers, subscriptions, services, clients.

The node's ``NN`` token makes it appear in ``ros2 node list`` while it lives; each endpoint adds
its own token and Zenoh entity. Names resolve as in rcl: ``joint_states`` in namespace ``/robot1``
is ``/robot1/joint_states``, ``~/reset`` is ``/robot1/<node>/reset``, ``/clock`` stays ``/clock``.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, TypeVar

import zenoh

from bridge.errors import TransportError
from bridge.net.ros2 import qos as profiles
from bridge.net.ros2.endpoints import Declared, MessageCallback, Publisher, RosEndpoint, Subscription
from bridge.net.ros2.names import normalize_namespace, resolve_name, validate_node_name
from bridge.net.ros2.services import Client, Service, ServiceHandler
from bridge.net.ros2.tokens import EntityKind, Token

if TYPE_CHECKING:
    from bridge.net.ros2.context import RosContext

_log = logging.getLogger(__name__)
E = TypeVar("E", bound=RosEndpoint)


class RosNode:
    """One ROS 2 node inside a ``RosContext``; ``close()`` removes it and its endpoints from the graph."""

    def __init__(self, context: RosContext, name: str, namespace: str) -> None:
        self.context = context
        self.name = validate_node_name(name)
        self.namespace = normalize_namespace(namespace)
        self.node_id = context.next_entity_id()
        self.token = Token(
            domain_id=context.domain_id,
            zid=context.zid,
            node_id=self.node_id,
            entity_id=self.node_id,
            kind=EntityKind.NODE,
            namespace=self.namespace,
            node_name=self.name,
            enclave=context.enclave,
        ).key
        self._lock = threading.Lock()
        self._endpoints: list[RosEndpoint] = []
        self._closed = False
        self._token: Declared = context.session.liveliness().declare_token(self.token)
        _log.info("ROS node %s (domain %d) declared", self.fully_qualified_name, context.domain_id)

    @property
    def fully_qualified_name(self) -> str:
        """``/robot1/cartpole``: how ``ros2 node list`` prints the node."""
        return f"{self.namespace.rstrip('/')}/{self.name}"

    @property
    def endpoints(self) -> list[RosEndpoint]:
        with self._lock:
            return list(self._endpoints)

    def resolve(self, name: str) -> str:
        """The fully qualified name of a topic or service of this node."""
        return resolve_name(name, self.namespace, self.name)

    def create_publisher(self, topic: str, type_name: str, qos: profiles.QoS = profiles.DEFAULT) -> Publisher:
        """A publisher of ``type_name`` (``sensor_msgs/msg/JointState``) on ``topic``."""
        return self._add(lambda: Publisher(self, topic, type_name, qos))

    def create_subscription(
        self,
        topic: str,
        type_name: str,
        callback: MessageCallback,
        qos: profiles.QoS = profiles.DEFAULT,
    ) -> Subscription:
        """A subscription; ``callback(cdr_payload, attachment)`` runs on a Zenoh thread."""
        return self._add(lambda: Subscription(self, topic, type_name, callback, qos))

    def create_service(
        self,
        name: str,
        srv_type: str,
        handler: ServiceHandler,
        qos: profiles.QoS = profiles.SERVICES_DEFAULT,
    ) -> Service:
        """A service server of ``srv_type`` (``std_srvs/srv/Trigger``).

        ``handler(request)`` runs on a Zenoh thread and returns the response; both are CDR bytes.
        """
        return self._add(lambda: Service(self, name, srv_type, handler, qos))

    def create_client(
        self, name: str, srv_type: str, qos: profiles.QoS = profiles.SERVICES_DEFAULT
    ) -> Client:
        """A service client; ``client.call(request_cdr, timeout_s)`` returns the response CDR."""
        return self._add(lambda: Client(self, name, srv_type, qos))

    def _add(self, make: Callable[[], E]) -> E:
        with self._lock:
            if self._closed:
                raise TransportError(f"ROS node {self.fully_qualified_name} is closed; create a new node")
        endpoint = make()
        with self._lock:
            self._endpoints.append(endpoint)
        return endpoint

    def _forget(self, endpoint: RosEndpoint) -> None:
        with self._lock:
            if endpoint in self._endpoints:
                self._endpoints.remove(endpoint)

    def close(self) -> None:
        """Close every endpoint, then withdraw the node's token."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            endpoints = list(self._endpoints)
        for endpoint in reversed(endpoints):
            endpoint.close()
        try:
            self._token.undeclare()
        except zenoh.ZError:
            _log.debug("undeclare of node %s failed (session closed?)", self.name, exc_info=True)
        self.context._forget(self)

    def __enter__(self) -> RosNode:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<RosNode {self.fully_qualified_name} id={self.node_id} domain={self.context.domain_id}>"
