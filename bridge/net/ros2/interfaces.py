"""ROS 2 service payloads (Trigger, Empty) and the generic CDR calls services and endpoints use.

The CDR encoding itself lives in :mod:`bridge.net.ros2.cdr`; rmw_zenoh sends Fast-CDR
``DDS_CDR`` little-endian data, and an empty struct (a Trigger request) is one dummy byte, so
the request is ``00 01 00 00 00``. Service requests and responses are registered as
``pkg/srv/X_Request`` and ``pkg/srv/X_Response``.
"""

from __future__ import annotations

from bridge.net.ros2.cdr import (
    CDR_HEADERS,
    check_cdr,
    deserialize,
    encode,
    message_class,
    serialize,
    typestore,
)

__all__ = [
    "CDR_HEADERS",
    "EMPTY",
    "TRIGGER",
    "check_cdr",
    "deserialize",
    "empty_request",
    "encode",
    "message_class",
    "serialize",
    "trigger_response",
    "typestore",
]
TRIGGER = "std_srvs/srv/Trigger"
EMPTY = "std_srvs/srv/Empty"


def trigger_response(success: bool, message: str = "") -> bytes:
    """The CDR response of ``std_srvs/srv/Trigger`` (what a reset handler returns)."""
    return encode(f"{TRIGGER}_Response", success=success, message=message)


def empty_request(srv_type: str) -> bytes:
    """The CDR request of a service whose request has no fields (Trigger, Empty): ``00 01 00 00 00``."""
    return encode(f"{srv_type}_Request")
