"""What a client may ask of a node: requests parsed into typed, range-checked forms.

A node is a network service: every request is checked before anything touches the FMU.

- A reset may set only the values the experiment declares (``model.parameters`` and
  ``start_values``, scenario values and randomised names; any settable variable when a
  ``hooks.episode`` may choose them), each with the variable's type, finite, inside the
  variable's declared min/max, strings at most ``MAX_STRING`` characters.
- Input values (actions, reset inputs, ROS actions) must be finite and inside the input's
  declared range: the hull of the FMU's min/max and the experiment's action bounds (levels or
  table for discrete actions). Values outside are **rejected**, never clipped: a client that
  sends them has a bug, and a silently changed action would hide it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from bridge.errors import BridgeError, TransportError
from bridge.experiment.validate import with_elements
from bridge.fmu.vocab import Variable
from bridge.net import protocol as proto
from bridge.net.served import Served

MAX_STRING = 1024
MAX_VALUES = 1000
_HEX64 = re.compile(r"[0-9a-f]{64}")
REQUEST_KEYS = {"episode", "values", "inputs", "client", "zid", "take_over", "pub", "seq"}


class BadRequest(TransportError):
    """A request that is not what the protocol allows (the reply says what was wrong)."""


@dataclass(frozen=True)
class ResetRequest:
    """A reset request after parsing: every field typed and in range."""

    episode: int
    values: dict[str, float | int | bool | str]
    inputs: list[float] | None
    client: int
    zid: str
    take_over: bool
    pub: bytes = b""  # the client's key-agreement key (``bridge.net.handshake``)
    seq: int = 0  # the holder's request number (its signature travels as the query's attachment)


def parse_reset(payload: bytes) -> ResetRequest:
    """The typed form of a reset request's JSON payload, or :class:`BadRequest` saying why."""
    try:
        data = proto.decode_json(payload or b"{}", "reset request", limit=proto.MAX_REQUEST_BYTES)
    except TransportError as exc:
        raise BadRequest(str(exc)) from None
    unknown = sorted(set(data) - REQUEST_KEYS)
    if unknown:
        raise BadRequest(f"reset request: unknown keys {unknown[:5]}; allowed: {sorted(REQUEST_KEYS)}")
    values = data.get("values", {})
    if not isinstance(values, dict) or len(values) > MAX_VALUES:
        raise BadRequest(f"reset request: 'values' must be an object of at most {MAX_VALUES} entries")
    inputs = data.get("inputs")
    if inputs is not None and (not isinstance(inputs, list) or len(inputs) > MAX_VALUES):
        raise BadRequest("reset request: 'inputs' must be a list of numbers or null")
    zid = data.get("zid", "")
    if not isinstance(zid, str) or len(zid) > 64:
        raise BadRequest("reset request: 'zid' must be a string of at most 64 characters")
    pub = data.get("pub", "")
    if not isinstance(pub, str) or not _HEX64.fullmatch(pub or "0" * 64):
        raise BadRequest(
            f"reset request: 'pub' must be 64 hex digits (an X25519 public key), got {_show(pub)}"
        )
    take_over = data.get("take_over", False)
    if not isinstance(take_over, bool):
        raise BadRequest(f"reset request: 'take_over' must be true or false, got {_show(take_over)}")
    return ResetRequest(
        episode=_int_in(data.get("episode", 0), "episode", 0, proto.EPISODE_MAX),
        values=values,
        inputs=None if inputs is None else [_number(v, f"inputs[{i}]") for i, v in enumerate(inputs)],
        client=_int_in(data.get("client", 0), "client", 0, proto.CLIENT_MAX),
        zid=zid,
        take_over=take_over,
        pub=bytes.fromhex(pub),
        seq=_int_in(data.get("seq", 0), "seq", 0, proto.CLIENT_MAX),
    )


def check_empty(payload: bytes | None, what: str) -> None:
    """Requests that take no payload (info, ROS Trigger) refuse one of more than a few bytes."""
    if payload is not None and len(payload) > 64:
        raise BadRequest(f"{what} takes no payload; got {len(payload)} bytes")


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _int_in(value: Any, key: str, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise BadRequest(f"reset request: {key!r} must be an integer in [{low}, {high}], got {_show(value)}")
    return value


def _number(value: Any, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise BadRequest(f"reset request: {key} must be a number, got {_show(value)}")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        raise BadRequest(f"reset request: {key} must be finite, got {_show(value)}")
    return number


class RequestRules:
    """What a node allows a client to set and send (``bridge.net.served``)."""

    def __init__(self, served: Served, variables: Mapping[str, Variable]) -> None:
        self.variables = with_elements(variables)  # FMI 3.0 array elements are set by name too
        self.input_names = served.input_names
        self.settable = served.settable
        self.ranges = served.ranges
        self.low, self.high = list(served.low), list(served.high)

    def values(self, values: Mapping[str, Any]) -> dict[str, float | int | bool | str]:
        """Reset values, checked name by name against the experiment and the model."""
        checked: dict[str, float | int | bool | str] = {}
        for name, value in values.items():
            if name not in self.settable:
                allowed = sorted(self.settable)
                shown = allowed[:20] + (["..."] if len(allowed) > 20 else [])
                raise BadRequest(
                    f"reset request: {_show(name)} is not a value the experiment declares; a reset may set "
                    f"{shown or 'nothing'}"
                )
            checked[name] = self._value(self.variables[name], value)
        return checked

    def _value(self, var: Variable, value: Any) -> float | int | bool | str:
        where = f"reset request: {var.name!r} ({var.type})"
        if var.type == "String":
            if not isinstance(value, str) or len(value) > MAX_STRING:
                raise BadRequest(f"{where} takes a string of at most {MAX_STRING} characters")
            return value
        if var.type == "Boolean":
            if not isinstance(value, bool | int) or value not in (0, 1):
                raise BadRequest(f"{where} takes true or false, got {_show(value)}")
            return bool(value)
        number = _number(value, repr(var.name))
        is_float = var.type in ("Float64", "Float32")
        if not is_float and not (number.is_integer() and abs(number) < 2**31):
            raise BadRequest(f"{where} takes an integer in [-2^31, 2^31), got {_show(value)}")
        if (var.min is not None and number < var.min) or (var.max is not None and number > var.max):
            raise BadRequest(f"{where} = {number:g} is outside its declared range [{var.min}, {var.max}]")
        low, high = self.ranges.get(var.name, (-math.inf, math.inf))
        if not low <= number <= high:
            raise BadRequest(
                f"{where} = {number:g} is outside the experiment's range [{low:g}, {high:g}] (the values "
                "its model, scenarios and randomisation can give)"
            )
        return number if is_float else int(number)

    def inputs(self, values: Sequence[float]) -> str | None:
        """None if every input value is finite and in range, else the reason (for a REJECT)."""
        low, high = self.low, self.high
        for i, v in enumerate(values):
            if not low[i] <= v <= high[i]:  # False for NaN too
                return (
                    f"input {self.input_names[i]!r} = {v!r} is outside its declared range "
                    f"[{low[i]:g}, {high[i]:g}]"
                )
        return None


class Refused(BridgeError):
    """A request the node will not serve now; ``code`` starts the error reply (busy, unhealthy)."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


_PATH = re.compile(r"(?:file://)?(?:/[\w.~+@-]+)+/([\w.~+@-]+)")


def redact(text: str) -> str:
    """``text`` without local paths (``/home/me/plant.fmu`` -> ``.../plant.fmu``): replies leave the host."""
    return _PATH.sub(r".../\1", text)
