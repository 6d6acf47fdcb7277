"""ROS 2 names and the rmw_zenoh data key expressions built from them.

rmw_zenoh (Jazzy) maps a topic or service onto the Zenoh key
``<domain_id>/<fully qualified name without its leading '/'>/<DDS type name>/<type hash>``,
for example ``0/robot1/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...``. Slashes inside the
name stay slashes here; only liveliness tokens mangle them to ``%`` (see ``bridge.net.ros2.tokens``).
"""

from __future__ import annotations

import os
import re

from bridge.errors import ConfigError

_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_TYPE = re.compile(r"([A-Za-z][A-Za-z0-9_]*)/(msg|srv)/([A-Za-z][A-Za-z0-9_]*)\Z")
_DDS_TYPE = re.compile(r"([A-Za-z][A-Za-z0-9_]*)::(msg|srv)::dds_::([A-Za-z][A-Za-z0-9_]*)_\Z")
_NAME_RULES = (
    "tokens of letters, digits and '_' that do not start with a digit, separated by single '/', "
    "no trailing '/'"
)
SLASH_REPLACEMENT = "%"


def mangle(name: str) -> str:
    """``/robot1/chatter`` -> ``%robot1%chatter``: how names appear inside liveliness tokens."""
    return name.replace("/", SLASH_REPLACEMENT)


def demangle(name: str) -> str:
    """The inverse of ``mangle``."""
    return name.replace(SLASH_REPLACEMENT, "/")


def validate_node_name(name: str) -> str:
    """A node name is a single ROS name token (``cartpole``, ``agent_0``)."""
    if not _TOKEN.match(name):
        raise ConfigError(
            f"ROS node name {name!r} is invalid: expected letters, digits and '_', not starting with a "
            "digit (for example 'cartpole_node')"
        )
    return name


def name_token(text: str) -> str:
    """A valid ROS name token from any label: ``body.position`` -> ``body_position``, ``3d`` -> ``_3d``.

    For deriving topic names from FMU variable names; distinct labels may map to the same token.
    """
    token = re.sub(r"[^A-Za-z0-9_]", "_", text)
    if not token or token[0].isdigit():
        token = "_" + token
    return token


def normalize_namespace(namespace: str) -> str:
    """``''`` and ``'/'`` are the root namespace ``/``; otherwise ``/a/b`` (a leading ``/`` is added)."""
    if namespace in ("", "/"):
        return "/"
    full = namespace if namespace.startswith("/") else "/" + namespace
    if not all(_TOKEN.match(token) for token in full[1:].split("/")):
        raise ConfigError(f"ROS namespace {namespace!r} is invalid: expected {_NAME_RULES} (e.g. '/robot1')")
    return full


def resolve_name(name: str, namespace: str, node_name: str) -> str:
    """The fully qualified name of a topic or service, as rcl expands it.

    ``chatter`` in namespace ``/robot1`` is ``/robot1/chatter``; ``/clock`` stays ``/clock``;
    ``~/status`` of node ``sim`` is ``/robot1/sim/status``. Substitutions (``{node}``) are not supported.
    """
    namespace = normalize_namespace(namespace)
    base = namespace.rstrip("/")
    if name == "~" or name.startswith("~/"):
        full = f"{base}/{validate_node_name(node_name)}{name[1:]}"
    elif name.startswith("/"):
        full = name
    else:
        full = f"{base}/{name}"
    if full == "/" or not all(_TOKEN.match(token) for token in full[1:].split("/")):
        raise ConfigError(
            f"ROS topic or service name {name!r} is invalid: expected {_NAME_RULES} (e.g. 'joint_states', "
            "'/clock' or '~/reset')"
        )
    return full


def split_type_name(type_name: str) -> tuple[str, str, str]:
    """``sensor_msgs/msg/JointState`` -> ``('sensor_msgs', 'msg', 'JointState')``."""
    match = _TYPE.match(type_name)
    if match is None:
        raise ConfigError(
            f"ROS interface type {type_name!r} is invalid: expected 'package/msg/Name' or 'package/srv/Name' "
            "(for example 'sensor_msgs/msg/JointState' or 'std_srvs/srv/Trigger')"
        )
    package, kind, name = match.groups()
    return package, kind, name


def dds_type_name(type_name: str) -> str:
    """``std_srvs/srv/Trigger`` -> ``std_srvs::srv::dds_::Trigger_`` (the name rmw_zenoh puts on the wire).

    Services use the service name itself, never ``..._Request_`` or ``..._Response_``.
    """
    package, kind, name = split_type_name(type_name)
    return f"{package}::{kind}::dds_::{name}_"


def ros_type_name(dds_name: str) -> str:
    """The inverse of ``dds_type_name`` (``std_msgs::msg::dds_::String_`` -> ``std_msgs/msg/String``)."""
    match = _DDS_TYPE.match(dds_name)
    if match is None:
        raise ConfigError(f"{dds_name!r} is not a DDS type name of the form 'pkg::msg::dds_::Name_'")
    package, kind, name = match.groups()
    return f"{package}/{kind}/{name}"


def data_key(domain_id: int, fully_qualified_name: str, type_name: str, type_hash: str) -> str:
    """The Zenoh key expression a topic's samples or a service's queries travel on.

    Args:
        domain_id: the ROS domain (``ROS_DOMAIN_ID``).
        fully_qualified_name: ``/robot1/chatter`` (see ``resolve_name``).
        type_name: ``std_msgs/msg/String``.
        type_hash: ``RIHS01_<64 hex digits>``.
    """
    # rmw_zenoh strips exactly one leading and one trailing '/'; resolved names have no trailing one.
    name = fully_qualified_name[1:] if fully_qualified_name.startswith("/") else fully_qualified_name
    return f"{check_domain_id(domain_id)}/{name}/{dds_type_name(type_name)}/{type_hash}"


def check_domain_id(domain_id: int) -> int:
    if isinstance(domain_id, bool) or not isinstance(domain_id, int) or domain_id < 0:
        raise ConfigError(f"ROS domain id must be an integer >= 0 (ROS_DOMAIN_ID), got {domain_id!r}")
    return domain_id


def domain_id_from_env(default: int = 0) -> int:
    """``ROS_DOMAIN_ID`` from the environment, as ROS reads it (unset or empty: ``default``)."""
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return default
    try:
        return check_domain_id(int(text))
    except ValueError:
        raise ConfigError(
            f"ROS_DOMAIN_ID={text!r} is not an integer; unset it or set it to the robot's domain (e.g. 0)"
        ) from None
