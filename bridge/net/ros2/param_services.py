"""A node's ROS parameter services over the rmw_zenoh wire (the zenoh backend): what ``ros2 param``
calls, served for the FMU parameters of ``bridge.net.ros2.params``.

rclpy serves these for its nodes; a node on the zenoh backend has no rcl underneath, so this module
answers the same six services of ``rcl_interfaces`` under the node's name, with the same rules as the
rclpy backend's ``declare_fmu_parameters``:

- ``~/list_parameters``, ``~/get_parameters``, ``~/get_parameter_types``, ``~/describe_parameters``:
  the declared FMU parameters, each a double (or a bool) with the model description's range as its
  ``floating_point_range``; an undeclared name reads as ``PARAMETER_NOT_SET``, as rclpy answers;
- ``~/set_parameters`` (each parameter on its own) and ``~/set_parameters_atomically`` (all or
  none): a value of another type, outside the declared range, or for an undeclared name is refused
  with the reason; otherwise ``on_set({name: value})`` decides (inside an episode it refuses).

Not served: ``/parameter_events`` (``ros2 param`` does not need it) and parameters other than the
FMU's (an rclpy node's ``use_sim_time``, say).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from typing import Any

from bridge.net.ros2.cdr import deserialize, message_class, serialize
from bridge.net.ros2.params import FmuParameter

_log = logging.getLogger(__name__)
NOT_SET, BOOL, INTEGER, DOUBLE = 0, 1, 2, 3
TYPE_NAMES = {0: "not set", 1: "bool", 2: "integer", 3: "double", 4: "string"}
SRV = "rcl_interfaces/srv/"
MSG = "rcl_interfaces/msg/"
OnSet = Callable[[dict[str, Any]], str | None]


class ParameterServices:
    """The parameter services of ``node`` (a ``RosNode``) for ``parameters``; they go with the node."""

    def __init__(self, node: Any, parameters: Sequence[FmuParameter], on_set: OnSet) -> None:
        self._declared = {p.name: p for p in parameters}
        self._values: dict[str, float | bool] = {p.name: p.value for p in parameters}
        self._on_set = on_set
        self._lock = threading.Lock()  # one set at a time: on_set sees a consistent node
        handlers = {
            "list_parameters": ("ListParameters", self._list),
            "get_parameters": ("GetParameters", self._get),
            "get_parameter_types": ("GetParameterTypes", self._types),
            "describe_parameters": ("DescribeParameters", self._describe),
            "set_parameters": ("SetParameters", self._set),
            "set_parameters_atomically": ("SetParametersAtomically", self._set_atomically),
        }
        for service, (srv, handler) in handlers.items():
            node.create_service(f"~/{service}", SRV + srv, _cdr(SRV + srv, handler))

    # -- reading ------------------------------------------------------------------------------------
    def _list(self, request: Any) -> Any:
        names = sorted(n for n in self._declared if _listed(n, list(request.prefixes), int(request.depth)))
        prefixes = sorted({n.rpartition(".")[0] for n in names if "." in n})
        result = message_class(MSG + "ListParametersResult")(names=names, prefixes=prefixes)
        return {"result": result}

    def _get(self, request: Any) -> Any:
        with self._lock:
            return {"values": [self._value(name) for name in request.names]}

    def _types(self, request: Any) -> Any:
        import numpy as np

        types = [_type_of(self._declared[n].value) if n in self._declared else NOT_SET for n in request.names]
        return {"types": np.array(types, dtype=np.uint8)}

    def _describe(self, request: Any) -> Any:
        return {"descriptors": [self._descriptor(name) for name in request.names]}

    def _value(self, name: str) -> Any:
        if name not in self._values:
            return parameter_value(None)
        return parameter_value(self._values[name])

    def _descriptor(self, name: str) -> Any:
        descriptor = message_class(MSG + "ParameterDescriptor")
        declared = self._declared.get(name)
        if declared is None:
            return descriptor(
                name=name, type=NOT_SET, description="", additional_constraints="", read_only=False,
                dynamic_typing=False, floating_point_range=[], integer_range=[],
            )  # fmt: skip
        ranges = []
        if not isinstance(declared.value, bool):
            span = message_class(MSG + "FloatingPointRange")
            ranges = [span(from_value=declared.low, to_value=declared.high, step=0.0)]
        return descriptor(
            name=name, type=_type_of(declared.value), description=declared.description,
            additional_constraints="", read_only=False, dynamic_typing=False,
            floating_point_range=ranges, integer_range=[],
        )  # fmt: skip

    # -- setting ------------------------------------------------------------------------------------
    def _set(self, request: Any) -> Any:
        with self._lock:
            return {"results": [self._apply([p]) for p in request.parameters]}

    def _set_atomically(self, request: Any) -> Any:
        with self._lock:
            return {"result": self._apply(list(request.parameters))}

    def _apply(self, parameters: list[Any]) -> Any:
        """Check every parameter, then let ``on_set`` decide on all of them together."""
        changes: dict[str, Any] = {}
        for parameter in parameters:
            value, reason = self._checked(parameter.name, parameter.value)
            if reason is not None:
                return _result(reason)
            changes[parameter.name] = value
        reason = self._on_set(changes) if changes else None
        if reason is None:
            self._values.update(changes)
        return _result(reason)

    def _checked(self, name: str, value: Any) -> tuple[Any, str | None]:
        declared = self._declared.get(name)
        if declared is None:
            known = ", ".join(sorted(self._declared)) or "none"
            return None, f"parameter {name!r} is not declared by this node; its parameters: {known}"
        expected = _type_of(declared.value)
        if int(value.type) != expected:
            got = TYPE_NAMES.get(int(value.type), f"type {int(value.type)}")
            hint = " (write it with a decimal point: 4.0, not 4)" if expected == DOUBLE else ""
            return None, f"parameter {name!r} is a {TYPE_NAMES[expected]}, got a {got}{hint}"
        if expected == BOOL:
            return bool(value.bool_value), None
        number = float(value.double_value)
        if not declared.low <= number <= declared.high:
            return None, (
                f"parameter {name!r} = {number:g} is outside its declared range "
                f"[{declared.low:g}, {declared.high:g}] (the model description's min and max)"
            )
        return number, None


def parameter_value(value: float | bool | None) -> Any:
    """An ``rcl_interfaces/msg/ParameterValue`` for a double, a bool or nothing (not set)."""
    import numpy as np

    empty = {f"{kind}_array_value": np.array([], dtype=dtype) for kind, dtype in _ARRAYS}
    return message_class(MSG + "ParameterValue")(
        type=NOT_SET if value is None else _type_of(value),
        bool_value=bool(value) if isinstance(value, bool) else False,
        integer_value=0,
        double_value=float(value) if value is not None and not isinstance(value, bool) else 0.0,
        string_value="",
        string_array_value=[],
        **empty,
    )


_ARRAYS = (("byte", "uint8"), ("bool", "bool"), ("integer", "int64"), ("double", "float64"))


def _type_of(value: float | bool) -> int:
    return BOOL if isinstance(value, bool) else DOUBLE


def _listed(name: str, prefixes: list[str], depth: int) -> bool:
    """Whether ``ros2 param list`` with ``prefixes`` and ``depth`` (0: any) shows ``name``."""
    if prefixes and not any(name == p or name.startswith(p + ".") for p in prefixes):
        return False
    return depth == 0 or name.count(".") < depth


def _result(reason: str | None) -> Any:
    return message_class(MSG + "SetParametersResult")(successful=reason is None, reason=reason or "")


def _cdr(srv_type: str, handler: Callable[[Any], dict[str, Any]]) -> Callable[[bytes], bytes]:
    """A service handler on CDR bytes around one on decoded messages returning the response's fields."""
    response = message_class(srv_type + "_Response")

    def serve(request: bytes) -> bytes:
        fields = handler(deserialize(request, srv_type + "_Request"))
        return serialize(response(**fields), srv_type + "_Response")

    return serve
