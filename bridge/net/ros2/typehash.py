"""RIHS01 type hashes (REP-2016) for message and service types, as ROS 2 Jazzy computes them.

Messages are hashed by rosbags' Jazzy typestore, which follows rosidl's algorithm (sha256 of a
JSON type description). Two corrections make it agree with Jazzy for every type:

- a ``.msg`` ``char`` is IDL ``uint8`` in Jazzy (rosidl_adapter), but rosbags hashes it as
  ``char`` (type id 13). It matters for ``service_msgs/msg/ServiceEventInfo.client_gid`` and so
  for every service;
- services are not in rosbags' store. rosidl hashes a service ``pkg/srv/X`` as a struct of
  ``request_message: X_Request``, ``response_message: X_Response`` and ``event_message: X_Event``,
  where ``X_Event`` is ``info: service_msgs/msg/ServiceEventInfo``, ``request: X_Request[<=1]``
  and ``response: X_Response[<=1]``.

The service hash (not the ``_Request``/``_Response`` one) goes into keys and tokens.
"""

from __future__ import annotations

import threading
from functools import cache
from typing import Any

from bridge.errors import ConfigError
from bridge.net.ros2.names import split_type_name

SERVICE_DEFINITIONS: dict[str, tuple[str, str]] = {
    "std_srvs/srv/Empty": ("", ""),
    "std_srvs/srv/Trigger": ("", "bool success\nstring message\n"),
    "std_srvs/srv/SetBool": ("bool data\n", "bool success\nstring message\n"),
    "example_interfaces/srv/AddTwoInts": ("int64 a\nint64 b\n", "int64 sum\n"),
    # a node's parameter services (what ``ros2 param`` calls; bridge.net.ros2.param_services)
    "rcl_interfaces/srv/ListParameters": (
        "uint64 DEPTH_RECURSIVE=0\nstring[] prefixes\nuint64 depth\n",
        "ListParametersResult result\n",
    ),
    "rcl_interfaces/srv/GetParameters": ("string[] names\n", "ParameterValue[] values\n"),
    "rcl_interfaces/srv/GetParameterTypes": ("string[] names\n", "uint8[] types\n"),
    "rcl_interfaces/srv/DescribeParameters": ("string[] names\n", "ParameterDescriptor[] descriptors\n"),
    "rcl_interfaces/srv/SetParameters": ("Parameter[] parameters\n", "SetParametersResult[] results\n"),
    "rcl_interfaces/srv/SetParametersAtomically": (
        "Parameter[] parameters\n",
        "SetParametersResult result\n",
    ),
}
"""Request and response ``.srv`` text of the services this package knows (rosbags has none)."""

_LOCK = threading.Lock()


def jazzy_typestore() -> Any:
    """A fresh rosbags typestore for ROS 2 Jazzy (each call builds its own, so callers may extend it)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def service_fields(srv_type: str) -> dict[str, tuple[list[Any], list[Any]]]:
    """rosbags field definitions of ``<srv>_Request`` and ``<srv>_Response``."""
    from rosbags.typesys import get_types_from_msg

    if srv_type not in SERVICE_DEFINITIONS:
        raise ConfigError(
            f"service type {srv_type!r} is unknown; known: {sorted(SERVICE_DEFINITIONS)} "
            "(add its .srv text to bridge.net.ros2.typehash.SERVICE_DEFINITIONS)"
        )
    package = split_type_name(srv_type)[0]
    out: dict[str, tuple[list[Any], list[Any]]] = {}
    for suffix, text in zip(("_Request", "_Response"), SERVICE_DEFINITIONS[srv_type]):
        # Parsed under the service's package so that relative nested names resolve as rosidl does.
        ((consts, fields),) = get_types_from_msg(text, f"{package}/msg/Tmp").values()
        out[srv_type + suffix] = (consts, fields)
    return out


@cache
def type_hash(type_name: str) -> str:
    """``RIHS01_<sha256 hex>`` of a message (``pkg/msg/X``) or service (``pkg/srv/X``) type."""
    kind = split_type_name(type_name)[1]
    with _LOCK:
        store = _hash_store()
        if kind == "srv":
            _add_service(store, service_of(type_name))
        elif type_name not in store.fielddefs:
            raise ConfigError(
                f"message type {type_name!r} is not in the ROS 2 Jazzy typestore of rosbags; "
                "check the spelling (e.g. 'sensor_msgs/msg/JointState')"
            )
        return str(store.hash_rihs01(type_name))


def service_of(type_name: str) -> str:
    """``pkg/srv/X_Request`` (or ``_Response``, ``_Event``) -> ``pkg/srv/X``; a service name stays."""
    for suffix in ("_Request", "_Response", "_Event"):
        if type_name.endswith(suffix):
            return type_name[: -len(suffix)]
    return type_name


@cache
def _hash_store() -> Any:
    from rosbags.interfaces import Nodetype

    store = jazzy_typestore()
    for name, (consts, fields) in list(store.fielddefs.items()):
        store.fielddefs[name] = (consts, [(field, _char_as_uint8(desc, Nodetype)) for field, desc in fields])
    return store


def _char_as_uint8(desc: Any, nodetype: Any) -> Any:
    kind, rest = desc
    if kind == nodetype.BASE:
        return (kind, ("uint8", rest[1])) if rest[0] == "char" else desc
    if kind in (nodetype.ARRAY, nodetype.SEQUENCE):
        inner, size = rest
        return (kind, (_char_as_uint8(inner, nodetype), size))
    return desc


def _add_service(store: Any, srv_type: str) -> None:
    from rosbags.interfaces import Nodetype

    request, response, event = f"{srv_type}_Request", f"{srv_type}_Response", f"{srv_type}_Event"
    store.fielddefs.update(service_fields(srv_type))
    store.fielddefs[event] = (
        [],
        [
            ("info", (Nodetype.NAME, "service_msgs/msg/ServiceEventInfo")),
            ("request", (Nodetype.SEQUENCE, ((Nodetype.NAME, request), 1))),
            ("response", (Nodetype.SEQUENCE, ((Nodetype.NAME, response), 1))),
        ],
    )
    store.fielddefs[srv_type] = (
        [],
        [
            ("request_message", (Nodetype.NAME, request)),
            ("response_message", (Nodetype.NAME, response)),
            ("event_message", (Nodetype.NAME, event)),
        ],
    )
