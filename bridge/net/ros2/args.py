"""ROS 2 command-line arguments (``--ros-args ... [--]``), as ``ros2 launch`` passes them.

``launch_ros``'s ``Node`` action appends ``--ros-args -r __node:=NAME -r __ns:=/NS -r from:=to
--params-file FILE -p name:=value`` to the command it starts. ``fmu-bridge`` takes them out of
its argument list before parsing (``split_ros_args``) and applies them to the ROS view of nodes
and agents: the namespace and node name, topic and service remappings, and parameters that name
keys of the ``ros:`` section (``domain_id``, ``per_variable``, ``clock``, ...).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from bridge.errors import ConfigError


@dataclass(frozen=True)
class RosArgs:
    """What ``--ros-args`` said: namespace, node name, remappings, parameters."""

    namespace: str | None = None
    node_name: str | None = None
    remaps: dict[str, str] = field(default_factory=dict)
    parameters: dict[str, Any] = field(default_factory=dict)

    def __bool__(self) -> bool:
        return bool(self.namespace or self.node_name or self.remaps or self.parameters)

    def apply(self, section: dict[str, Any]) -> dict[str, Any]:
        """The ``ros:`` section with these arguments applied (they win over the file)."""
        out = {**section, **self.parameters}
        if self.namespace is not None:
            out["namespace"] = self.namespace
        if self.node_name is not None:
            out["node_name"] = self.node_name
        for key in ("outputs_topic", "actions_topic", "reset_service"):
            current = out.get(key, _DEFAULT_NAMES[key])
            for source in (current, current.removeprefix("~/")):
                if source in self.remaps:
                    out[key] = self.remaps[source]
        return out


_DEFAULT_NAMES = {"outputs_topic": "~/outputs", "actions_topic": "~/actions", "reset_service": "~/reset"}
_CURRENT: list[RosArgs] = [RosArgs()]  # set once by split_ros_args at start-up


def current() -> RosArgs:
    """The ROS arguments this process was started with (empty if none)."""
    return _CURRENT[0]


def split_ros_args(argv: Sequence[str]) -> tuple[list[str], RosArgs]:
    """``argv`` without its ``--ros-args ... [--]`` blocks, and what those blocks said."""
    rest: list[str] = []
    ros: list[str] = []
    inside = False
    for arg in argv:
        if arg == "--ros-args":
            inside = True
        elif inside and arg == "--":
            inside = False
        elif inside:
            ros.append(arg)
        else:
            rest.append(arg)
    _CURRENT[0] = _parse(ros)
    return rest, _CURRENT[0]


def _parse(args: list[str]) -> RosArgs:
    remaps: dict[str, str] = {}
    parameters: dict[str, Any] = {}
    it = iter(args)
    for flag in it:
        value = next(it, None)
        if value is None:
            raise ConfigError(f"--ros-args: {flag} needs a value; see `ros2 run --help`")
        if flag in ("-r", "--remap"):
            source, sep, target = value.partition(":=")
            if not sep:
                raise ConfigError(f"--ros-args: remapping {value!r} must read FROM:=TO")
            remaps[source] = target
        elif flag in ("-p", "--param"):
            name, sep, text = value.partition(":=")
            if not sep:
                raise ConfigError(f"--ros-args: parameter {value!r} must read NAME:=VALUE")
            parameters[name] = yaml.safe_load(text)
        elif flag == "--params-file":
            parameters.update(_params_file(Path(value)))
        elif flag in ("--log-level", "--enclave"):
            continue  # accepted; logging follows fmu-bridge's -v, the enclave needs SROS2
        else:
            raise ConfigError(f"--ros-args: {flag!r} is not supported; use -r, -p or --params-file")
    return RosArgs(
        namespace=remaps.pop("__ns", None),
        node_name=remaps.pop("__node", None) or remaps.pop("__name", None),
        remaps=remaps,
        parameters=parameters,
    )


def _params_file(path: Path) -> dict[str, Any]:
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"--ros-args --params-file {path}: cannot read it ({exc})") from exc
    found: dict[str, Any] = {}
    for entry in (data or {}).values():  # "/**:" or a node name, then "ros__parameters:"
        if isinstance(entry, dict) and isinstance(entry.get("ros__parameters"), dict):
            found.update(entry["ros__parameters"])
    return found
