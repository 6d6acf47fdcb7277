"""Liveliness tokens: how rmw_zenoh makes nodes and endpoints visible to ``ros2 node/topic list``.

A node declares
``@ros2_lv/<domain>/<zid>/<node id>/<node id>/NN/<enclave>/<namespace>/<node name>``
and every publisher (MP), subscription (MS), service server (SS) and client (SC) declares
``@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node name>/``
``<name>/<DDS type>/<hash>/<qos>``
with ``/`` mangled to ``%`` in enclave, namespace and name (the root ``/`` becomes ``%``). The
entity's 16-byte GID is the XXH3-128 hash of its token string (low 64 bits first, little-endian).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from bridge.errors import ConfigError, DependencyMissing, TransportError
from bridge.net.ros2.names import demangle, mangle, ros_type_name
from bridge.net.ros2.qos import QoS

ADMIN_SPACE = "@ros2_lv"
_NODE_PARTS = 9
_ENTITY_PARTS = 13


class EntityKind(str, Enum):
    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"
    SERVICE = "SS"
    CLIENT = "SC"


@dataclass(frozen=True)
class Endpoint:
    """What a non-node token adds: the topic or service, its type and its QoS."""

    name: str  # fully qualified, e.g. /robot1/chatter
    dds_type: str  # e.g. std_msgs::msg::dds_::String_
    type_hash: str  # RIHS01_...
    qos: QoS

    @property
    def type_name(self) -> str:
        """``std_msgs/msg/String``: the type as ``ros2 topic list -t`` shows it."""
        return ros_type_name(self.dds_type)


@dataclass(frozen=True)
class Token:
    """One entity of the ROS graph as its liveliness token describes it.

    ``namespace`` and ``enclave`` are ROS names (``/`` for the root); ``endpoint`` is ``None``
    for nodes. For a node, ``entity_id`` equals ``node_id``.
    """

    domain_id: int
    zid: str
    node_id: int
    entity_id: int
    kind: EntityKind
    namespace: str
    node_name: str
    enclave: str = "/"
    endpoint: Endpoint | None = None

    @property
    def key(self) -> str:
        """The token's key expression."""
        parts = [
            ADMIN_SPACE,
            str(self.domain_id),
            self.zid,
            str(self.node_id),
            str(self.entity_id),
            self.kind.value,
            mangle(self.enclave or "/"),
            mangle(self.namespace or "/"),
            self.node_name,
        ]
        if (self.kind == EntityKind.NODE) != (self.endpoint is None):
            raise ConfigError(
                f"a {self.kind.name} token {'must not' if self.endpoint else 'needs'} an endpoint"
            )
        if self.endpoint is not None:
            end = self.endpoint
            parts += [mangle(end.name), mangle(end.dds_type), mangle(end.type_hash), end.qos.to_keyexpr()]
        return "/".join(parts)

    @property
    def gid(self) -> bytes:
        return gid(self.key)

    @classmethod
    def parse(cls, key: str) -> Token:
        """Read a token the way rmw_zenoh's graph cache does; a foreign key raises ``TransportError``."""
        parts = key.split("/")
        if len(parts) < _NODE_PARTS or parts[0] != ADMIN_SPACE or not all(parts):
            raise TransportError(f"{key!r} is not an rmw_zenoh liveliness token ({ADMIN_SPACE}/...)")
        try:
            kind = EntityKind(parts[5])
            domain_id, node_id, entity_id = int(parts[1]), int(parts[3]), int(parts[4])
        except ValueError as exc:
            raise TransportError(f"liveliness token {key!r} is malformed: {exc}") from None
        endpoint = None
        if kind != EntityKind.NODE:
            if len(parts) < _ENTITY_PARTS:
                raise TransportError(f"liveliness token {key!r} of a {kind.name} lacks name, type or QoS")
            try:
                qos = QoS.from_keyexpr(parts[12])
            except ConfigError as exc:
                raise TransportError(f"liveliness token {key!r}: {exc}") from None
            endpoint = Endpoint(demangle(parts[9]), demangle(parts[10]), demangle(parts[11]), qos)
        return cls(
            domain_id=domain_id,
            zid=parts[2],
            node_id=node_id,
            entity_id=entity_id,
            kind=kind,
            namespace=demangle(parts[7]),
            node_name=demangle(parts[8]),
            enclave=demangle(parts[6]),
            endpoint=endpoint,
        )


def gid(token_key: str) -> bytes:
    """The 16-byte GID rmw_zenoh derives from a token: XXH3-128 as low64 LE followed by high64 LE."""
    try:
        import xxhash
    except ImportError:
        raise DependencyMissing("xxhash", "ROS 2 GIDs (rmw_zenoh)", "pip install xxhash") from None
    return int(xxhash.xxh3_128_intdigest(token_key.encode())).to_bytes(16, "little")


def graph_key(domain_id: int) -> str:
    """The key expression that matches every token of a ROS domain (what rmw_zenoh subscribes to)."""
    return f"{ADMIN_SPACE}/{domain_id}/**"
