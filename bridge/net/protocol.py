"""The native wire protocol of an FMU node: key expressions and compact binary payloads.

Key expressions (``<prefix>`` defaults to ``fmu_bridge``, ``<node>`` is the node's name):

====================================  =========  ===============================================
key expression                        kind       payload
====================================  =========  ===============================================
``<prefix>/<node>/outputs``           put        ``Frame`` kind OUTPUTS, ERROR or REJECT
``<prefix>/<node>/actions``           put        ``Frame`` kind ACTION (FMU input values)
``<prefix>/<node>/reset``             query      request: JSON; reply: ``Frame`` kind OUTPUTS (step 0)
``<prefix>/<node>/info``              query      reply: JSON (model, variables, spaces, counters)
``<prefix>/<node>/clock``             put        int64 LE simulation time in ns (real-time mode)
``<prefix>/<node>/alive``             liveliness token while the node serves
====================================  =========  ===============================================

A frame is little-endian: a 24-byte header ``<BBHIqq`` (version, kind, flags, episode,
step, sim_time_ns) then either ``n`` float64 values (``<I`` count + ``n*8`` bytes) or, for
ERROR/REJECT, a UTF-8 message. One frame per sample: outputs of a step travel together with
the step index and simulation time, so consumers can lock step, detect loss and record.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import TransportError

VERSION = 1
OUTPUTS, ACTION, ERROR, REJECT = 1, 2, 3, 4
KIND_NAMES = {OUTPUTS: "outputs", ACTION: "action", ERROR: "error", REJECT: "reject"}

# flags
TERMINATED = 1  # the FMU requested termination at this step
FAILED = 2  # the step failed (ERROR frames): the episode is over

HEADER = struct.Struct("<BBHIqq")
COUNT = struct.Struct("<I")
DEFAULT_PREFIX = "fmu_bridge"


@dataclass(frozen=True)
class Keys:
    """The key expressions of one node."""

    prefix: str
    node: str

    def __post_init__(self) -> None:
        for part, what in ((self.prefix, "prefix"), (self.node, "node name")):
            if not part or any(c in part for c in "*$?#") or part.startswith("/") or part.endswith("/"):
                raise TransportError(
                    f"{what} {part!r} is not usable in a key expression: use letters, digits, '_', '-', '/' "
                    "inside, and no wildcards"
                )

    @property
    def base(self) -> str:
        return f"{self.prefix}/{self.node}"

    @property
    def outputs(self) -> str:
        return f"{self.base}/outputs"

    @property
    def actions(self) -> str:
        return f"{self.base}/actions"

    @property
    def reset(self) -> str:
        return f"{self.base}/reset"

    @property
    def info(self) -> str:
        return f"{self.base}/info"

    @property
    def clock(self) -> str:
        return f"{self.base}/clock"

    @property
    def alive(self) -> str:
        return f"{self.base}/alive"


@dataclass
class Frame:
    """One decoded message."""

    kind: int
    episode: int
    step: int
    sim_time_ns: int
    flags: int = 0
    values: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    message: str = ""

    @property
    def terminated(self) -> bool:
        return bool(self.flags & TERMINATED)


def encode_values(
    kind: int, episode: int, step: int, sim_time_ns: int, values: Any, *, flags: int = 0
) -> bytes:
    """A frame carrying float64 values (OUTPUTS or ACTION)."""
    array = np.ascontiguousarray(values, dtype="<f8")
    return (
        HEADER.pack(VERSION, kind, flags, episode, step, sim_time_ns)
        + COUNT.pack(array.size)
        + array.tobytes()
    )


def encode_message(
    kind: int, episode: int, step: int, sim_time_ns: int, message: str, *, flags: int = 0
) -> bytes:
    """A frame carrying a text message (ERROR or REJECT)."""
    return HEADER.pack(VERSION, kind, flags, episode, step, sim_time_ns) + message.encode("utf-8", "replace")


def decode(payload: bytes, *, expected_values: int | None = None) -> Frame:
    """Decode a frame; a malformed or foreign payload raises TransportError saying why."""
    if len(payload) < HEADER.size:
        raise TransportError(f"payload of {len(payload)} bytes is shorter than the {HEADER.size}-byte header")
    version, kind, flags, episode, step, sim_time_ns = HEADER.unpack_from(payload)
    if version != VERSION:
        raise TransportError(f"protocol version {version} is not supported (expected {VERSION})")
    if kind not in KIND_NAMES:
        raise TransportError(f"unknown frame kind {kind}")
    if kind in (ERROR, REJECT):
        text = payload[HEADER.size :].decode("utf-8", "replace")
        return Frame(kind, episode, step, sim_time_ns, flags, message=text)
    if len(payload) < HEADER.size + COUNT.size:
        raise TransportError("values frame without a value count")
    (count,) = COUNT.unpack_from(payload, HEADER.size)
    body = len(payload) - HEADER.size - COUNT.size
    if body != 8 * count:
        raise TransportError(f"values frame announces {count} values but carries {body} bytes")
    if expected_values is not None and count != expected_values:
        raise TransportError(f"expected {expected_values} values, got {count}")
    values = np.frombuffer(payload, dtype="<f8", count=count, offset=HEADER.size + COUNT.size)
    return Frame(kind, episode, step, sim_time_ns, flags, values=values.astype(np.float64))


def encode_json(data: dict[str, Any]) -> bytes:
    return json.dumps(data, separators=(",", ":"), default=_jsonable).encode()


def decode_json(payload: bytes, what: str) -> dict[str, Any]:
    try:
        data = json.loads(payload.decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise TransportError(f"{what}: not JSON ({exc})") from None
    if not isinstance(data, dict):
        raise TransportError(f"{what}: expected a JSON object, got {type(data).__name__}")
    return data


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")
