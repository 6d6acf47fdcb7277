"""CDR payloads of ROS 2 messages and services, with rosbags' Jazzy typestore.

rmw_zenoh sends Fast-CDR ``DDS_CDR`` little-endian data: the 4-byte encapsulation header
``00 01 00 00`` and then the message, aligned relative to the byte after the header; an empty
struct (a Trigger request) is one dummy byte, so the request is ``00 01 00 00 00``. rosbags writes
the same bytes. Service requests and responses are registered as ``pkg/srv/X_Request`` and
``pkg/srv/X_Response``.
"""

from __future__ import annotations

import threading
from functools import cache
from typing import Any

from bridge.errors import ConfigError, TransportError
from bridge.net.ros2.typehash import SERVICE_DEFINITIONS, jazzy_typestore, service_fields

CDR_HEADERS = (b"\x00\x00", b"\x00\x01")  # CDR_BE, CDR_LE; two option bytes follow
TRIGGER = "std_srvs/srv/Trigger"
EMPTY = "std_srvs/srv/Empty"
_LOCK = threading.Lock()


@cache
def typestore() -> Any:
    """The Jazzy typestore with the request and response types of ``SERVICE_DEFINITIONS`` added."""
    with _LOCK:
        store = jazzy_typestore()
        for srv_type in SERVICE_DEFINITIONS:
            store.register(service_fields(srv_type))
        return store


def message_class(type_name: str) -> Any:
    """The rosbags dataclass of a type, e.g. ``message_class('std_msgs/msg/Float64')(data=1.5)``."""
    store = typestore()
    try:
        return store.types[type_name]
    except KeyError:
        raise ConfigError(
            f"ROS type {type_name!r} is not in the Jazzy typestore; services are used as "
            "'pkg/srv/X_Request' and 'pkg/srv/X_Response'"
        ) from None


def serialize(message: Any, type_name: str) -> bytes:
    """CDR little-endian with the encapsulation header, exactly what rmw_zenoh publishes."""
    try:
        return bytes(typestore().serialize_cdr(message, type_name, little_endian=True))
    except Exception as exc:
        raise ConfigError(f"cannot serialize {message!r} as {type_name}: {exc}") from exc


def deserialize(data: bytes, type_name: str) -> Any:
    """Decode a CDR payload; a payload that does not fit the type raises ``TransportError``."""
    check_cdr(data)
    try:
        return typestore().deserialize_cdr(data, type_name)
    except Exception as exc:
        raise TransportError(f"cannot decode a {len(data)}-byte CDR payload as {type_name}: {exc}") from exc


def encode(type_name: str, **fields: Any) -> bytes:
    """Build and serialize a message in one call: ``encode('std_msgs/msg/Float64', data=1.5)``."""
    try:
        message = message_class(type_name)(**fields)
    except TypeError as exc:
        raise ConfigError(f"fields {sorted(fields)} do not fit {type_name}: {exc}") from None
    return serialize(message, type_name)


def check_cdr(data: bytes) -> bytes:
    """Raise ``TransportError`` unless ``data`` starts with a plain CDR encapsulation header."""
    if len(data) < 4 or data[:2] not in CDR_HEADERS:
        raise TransportError(
            f"payload {data[:8].hex(' ')!r} ({len(data)} bytes) does not start with a CDR encapsulation "
            "header (00 01 00 00 little-endian, 00 00 00 00 big-endian); serialize with "
            "bridge.net.ros2.interfaces.serialize or rosbags' serialize_cdr"
        )
    return data


def trigger_response(success: bool, message: str = "") -> bytes:
    """The CDR response of ``std_srvs/srv/Trigger`` (what a reset handler returns)."""
    return encode(f"{TRIGGER}_Response", success=success, message=message)


def empty_request(srv_type: str) -> bytes:
    """The CDR request of a service whose request has no fields (Trigger, Empty): ``00 01 00 00 00``."""
    return encode(f"{srv_type}_Request")
